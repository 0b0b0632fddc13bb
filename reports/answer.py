"""The study's answer first: ``analysis.json`` (factorial effects with partial eta^2, per-level
means with 95 % CIs, the lag sentence; schema ``uwval.analysis/1``, docs/analysis.md) and the
Gazebo-model ``sensitivity.json`` (schema ``uwval-sensitivity/1``, docs/simulator.md), each
rendered when it lies beside the results and said to be absent otherwise."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uwval.reports.content import Section, Table, Text
from uwval.reports.numbers import Quantity, fmt, fmt_level, fmt_unit
from uwval.results import AXES, AXIS_UNITS

ANALYSIS_FILE = "analysis.json"
SENSITIVITY_FILE = "sensitivity.json"
ANALYSIS_SCHEMA = "uwval.analysis/1"
SENSITIVITY_SCHEMA = "uwval-sensitivity/1"


@dataclass(frozen=True)
class Found:
    """A study file beside the results: its path and parsed content, or why it is unusable."""

    path: Path | None
    doc: dict[str, Any] | None
    problem: str = ""


def search_dirs(source: Path) -> list[Path]:
    """Where files beside the results are looked for: the results location, its results/
    folder and its parent (an experiment directory holds results/ and the study files)."""
    base = source if source.is_dir() else source.parent
    return list(dict.fromkeys([base, base / "results", base.parent]))


def find_study_file(source: Path, name: str, schema: str) -> Found:
    """``name`` beside ``source``, parsed; a damaged or foreign file is reported, not read."""
    for d in search_dirs(source):
        path = d / name
        if not path.is_file():
            continue
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as exc:
            return Found(path, None, f"{path}: cannot be read ({exc}): not shown")
        except json.JSONDecodeError as exc:
            return Found(
                path,
                None,
                f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}): not shown",
            )
        if not isinstance(doc, dict) or doc.get("schema") != schema:
            got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
            return Found(path, None, f"{path}: schema {got!r}, expected {schema!r}: not shown")
        return Found(path, doc)
    return Found(None, None)


def _quantity(axis: str, metric: str) -> Quantity:
    if metric == "pearson_r":
        return Quantity.CORRELATION
    return Quantity.LENGTH if AXIS_UNITS.get(axis) == "m" else Quantity.ANGLE


def _effects_table(topic: str, axes_doc: Mapping[str, Any], factors: Sequence[str]) -> Table:
    """Per axis: partial eta^2 (%) and p of each main effect, and the largest interaction."""
    cols = ["axis"]
    for f in factors:
        cols += [f"{f} η² (η²p) %", f"{f} p"]
    cols.append("largest interaction (η²p)")
    t = Table(
        f"What moves the MAE ({topic}): factorial model, η² and partial η²",
        cols,
        [],
        caption="Ordinary least squares with every main effect and two-way interaction "
        "(Type II sums of squares). η²: the factor's share of the variation of the MAE "
        "across runs; η²p (partial) = SS_term / (SS_term + SS_residual): the share of the "
        "variance left after the other terms. Bold: η² of 50 % or more.",
    )
    for axis in AXES:
        m = (axes_doc.get(axis) or {}).get("mae")
        if not isinstance(m, Mapping):
            continue
        terms = {str(x.get("term")): x for x in m.get("terms") or [] if isinstance(x, Mapping)}
        row = [axis]
        r = len(t.rows)
        for k, f in enumerate(factors):
            term = terms.get(f, {})
            share, partial = term.get("eta_sq"), term.get("partial_eta_sq")
            text = fmt(partial, Quantity.FRACTION)
            if isinstance(share, (int, float)):
                text = f"{fmt(share, Quantity.FRACTION)} ({text})"
            row += [text, fmt(term.get("p"), Quantity.P_VALUE)]
            strong = share if isinstance(share, (int, float)) else partial
            if isinstance(strong, (int, float)) and strong >= 0.5:
                t.flags[(r, 1 + 2 * k)] = "strong"
        inter = [x for name, x in terms.items() if ":" in name]
        best = max(inter, key=lambda x: x.get("partial_eta_sq") or 0.0, default=None)
        if best is not None:
            row.append(
                f"{best.get('term')}: {fmt_unit(best.get('partial_eta_sq'), Quantity.FRACTION)}"
            )
        else:
            row.append(str(m.get("note") or "n/a"))
        t.rows.append(row)
    return t


def _interval(level: Mapping[str, Any], q: Quantity) -> str:
    ci = level.get("ci95")
    mean = fmt(level.get("mean"), q)
    if isinstance(ci, (list, tuple)) and len(ci) == 2:
        return f"{mean} [{fmt(ci[0], q)}, {fmt(ci[1], q)}]"
    return mean


def _levels_table(topic: str, axes_doc: Mapping[str, Any], factors: Sequence[str]) -> Table:
    """Per factor level: mean MAE with its 95 % CI over the runs at that level, per axis."""
    cols = ["factor = level", "runs"] + [
        f"MAE {a} ({'mm' if AXIS_UNITS[a] == 'm' else 'deg'})" for a in AXES
    ]
    t = Table(
        f"Mean MAE per factor level with 95 % CI ({topic})",
        cols,
        [],
        caption="Mean over the runs at the level [t-interval of the mean, 95 %].",
    )
    for f in factors:
        per_axis = {
            a: (((axes_doc.get(a) or {}).get("mae") or {}).get("levels") or {}).get(f) or []
            for a in AXES
        }
        first = next((v for v in per_axis.values() if v), [])
        for i, lv in enumerate(first):
            row = [f"{f} = {fmt_level(lv.get('level'))}", str(lv.get("n", ""))]
            for a in AXES:
                lvls = per_axis[a]
                row.append(_interval(lvls[i], _quantity(a, "mae")) if i < len(lvls) else "n/a")
            t.rows.append(row)
    return t


def _lag_table(lag: Mapping[str, Any]) -> Table:
    t = Table(
        "Lag fitted from the poses (per topic, over runs)",
        ["topic", "runs", "lag mean (ms)", "lag range (ms)", "explained (%)", "measured (ms)"],
        [],
        caption="error(t) ~ -lag x velocity fitted per run; measured: the mean age of the "
        "applied pose from applied stamps, when the logs have them.",
    )
    for topic, v in lag.items():
        if not isinstance(v, Mapping):
            continue
        lo, hi = v.get("fitted_s_min"), v.get("fitted_s_max")
        t.rows.append(
            [
                str(topic),
                str(v.get("n_runs", "")),
                fmt(v.get("fitted_s_mean"), Quantity.DURATION),
                f"{fmt(lo, Quantity.DURATION)} to {fmt(hi, Quantity.DURATION)}",
                fmt(v.get("explained_mean"), Quantity.FRACTION),
                fmt(v.get("measured_s_mean"), Quantity.DURATION),
            ]
        )
    return t


def _saturation(topic: str, axes_doc: Mapping[str, Any]) -> str:
    sat = [
        (a, str(((axes_doc.get(a) or {}).get("pearson_r") or {}).get("saturated_why") or ""))
        for a in AXES
        if ((axes_doc.get(a) or {}).get("pearson_r") or {}).get("saturated")
    ]
    if not sat:
        return ""
    why = next((w for _, w in sat if w), "")
    return (
        f"Pearson r is saturated on {', '.join(a for a, _ in sat)} ({topic}): it cannot tell "
        "the levels apart" + (f" ({why})" if why else "") + "; read the MAE instead."
    )


def analysis_section(found: Found) -> Section:
    """The answer: the sentence, the lag, effect sizes and per-level CIs (vehicle topic
    first); or a note that analysis.json is absent or unusable."""
    sec = Section("answer", "The answer: why Unity differs from Gazebo")
    doc = found.doc
    if doc is None:
        sec.blocks.append(
            Text(
                found.problem
                or "No analysis.json beside these results: the factorial analysis (effect "
                "sizes, per-level means with confidence intervals, the lag) is not shown. "
                "uwval demo writes it; see docs/analysis.md.",
                css="neutral",
            )
        )
        return sec
    # the answer's sentence heads the page (Report.headline): not repeated here
    factors = [str(f) for f in (doc.get("factors") or {})]
    reps = doc.get("replicates") or {}
    sec.blocks.append(
        Text(
            f"{doc.get('n_runs', '?')} runs; factors "
            + ", ".join(
                f"{f} ({', '.join(fmt_level(v) for v in (doc.get('factors') or {})[f])})"
                for f in factors
            )
            + f"; {reps.get('min', '?')}-{reps.get('max', '?')} replicate(s) per cell. "
            f"From {found.path.name if found.path else ANALYSIS_FILE}.",
            css="neutral",
        )
    )
    lag = doc.get("lag")
    if isinstance(lag, Mapping) and any(isinstance(v, Mapping) for v in lag.values()):
        sec.blocks.append(_lag_table(lag))
    else:
        sec.blocks.append(
            Text(
                "No lag in these results (compared without the lag fit, or too little "
                "motion to fit one).",
                css="neutral",
            )
        )
    topics = doc.get("topics") or {}
    for topic, axes_doc in list(topics.items())[:1]:  # the vehicle; the others in the JSON
        if not isinstance(axes_doc, Mapping):
            continue
        sec.blocks.append(_effects_table(str(topic), axes_doc, factors))
        sec.blocks.append(_levels_table(str(topic), axes_doc, factors))
        sat = _saturation(str(topic), axes_doc)
        if sat:
            sec.blocks.append(Text(sat, css="neutral"))
    return sec


_SENS_COLUMNS = [
    "variant",
    "changed",
    "position max (mm)",
    "position at end (mm)",
    "yaw max (deg)",
    "yaw at end (deg)",
    "rotation max (deg)",
]


def sensitivity_section(found: Found) -> Section:
    """How much the choice of the Gazebo model moves the pose: one row per variant."""
    sec = Section("sensitivity", "Sensitivity to the Gazebo model")
    doc = found.doc
    if doc is None:
        sec.blocks.append(
            Text(
                found.problem
                or "No sensitivity.json beside these results: how much the choice of the "
                "Gazebo model (Coriolis entries, added-mass scheme, C_A sign) moves the pose "
                "is not shown. uwval demo writes it; see docs/simulator.md.",
                css="neutral",
            )
        )
        return sec
    inp = doc.get("reference_input") or {}
    base = doc.get("baseline") or {}
    sec.blocks.append(
        Text(
            f"Vehicle {doc.get('vehicle', '?')}, {fmt_level(doc.get('duration_s'))} s of the "
            f"reference input (force {fmt_level(inp.get('force_n'))} N, torque "
            f"{fmt_level(inp.get('torque_nm'))} N m, current {fmt_level(inp.get('current_ms'))} "
            f"m/s), each variant against {base.get('label', 'the baseline model')} "
            f"({', '.join(f'{k} {v}' for k, v in base.items() if k != 'label')}).",
            css="neutral",
        )
    )
    variants = [v for v in doc.get("variants") or [] if isinstance(v, Mapping)]
    sec.blocks.append(
        Text([f"{v.get('name')}: {v.get('label') or ''}" for v in variants], kind="list")
    )
    t = Table(
        "Distance between each variant's pose and the baseline model's",
        list(_SENS_COLUMNS),
        [],
        caption="A diverged variant shows where it diverged, never a number from it.",
    )
    for v in variants:
        # only what the variant changes (the baseline is named above the table)
        changed = {k: x for k, x in (v.get("model") or {}).items() if base.get(k) != x}
        model = ", ".join(f"{k} {x}" for k, x in changed.items()) or "as the baseline"
        row = [str(v.get("name") or v.get("label")), model]
        if v.get("diverged"):
            row += [f"diverged at {fmt_level(v.get('diverged_at_s'))} s"] + ["n/a"] * 4
            t.flags[(len(t.rows), 2)] = "bad"
        else:
            row += [
                fmt(v.get("position_max_m"), Quantity.LENGTH),
                fmt(v.get("position_final_m"), Quantity.LENGTH),
                fmt(v.get("yaw_max_deg"), Quantity.ANGLE),
                fmt(v.get("yaw_final_deg"), Quantity.ANGLE),
                fmt(v.get("rotation_max_deg"), Quantity.ANGLE),
            ]
        t.rows.append(row)
    sec.blocks.append(t)
    return sec
