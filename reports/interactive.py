"""An interactive, self-contained HTML page of one comparison: zoom and pan on the errors
over time and on the trajectory (``uwval compare ... --html FILE``).

Everything is inline: the data as JSON in a ``<script type="application/json">`` element, the
hand-written SVG chart script (``templates/interactive.js``, no library) and the CSS. A
Content-Security-Policy ``default-src 'none'`` forbids every network request, so the page
opens offline and in CI artifact viewers alike.

Positions are ENU metres (x east, y north, z up), angles degrees; errors are signed
Unity - Gazebo (``ComparisonResult.errors``), time in seconds from the first aligned sample.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.reports.html import TEMPLATES, ReportError, environment
from uwval.reports.plots import AXIS_COLOURS, AlignedPair, error_series
from uwval.results import AXES, AXIS_UNITS

#: Samples per series kept in the page (a stride beyond): enough to zoom into any run of a
#: few minutes at 100 Hz sample by sample, small enough to draw smoothly.
MAX_POINTS = 20_000

_POS = (("x", "x"), ("y", "y"), ("z", "z"), ("position_norm", "norm |p|"))
_ROT = (("roll", "roll"), ("pitch", "pitch"), ("yaw", "yaw"), ("rotation_angle", "angle"))
_EXTRA_COLOURS = {"position_norm": "#17becf", "rotation_angle": "#bcbd22"}


def _column(values: Any, stride: int, digits: int = 9) -> list[float | None]:
    """A JSON-ready column: every ``stride``-th value, non-finite values as null (a gap)."""
    a = np.asarray(values, dtype=np.float64)[::stride]
    out: list[float | None] = [
        float(f"{v:.{digits}g}") if math.isfinite(v) else None for v in a.tolist()
    ]
    return out


def topic_payload(name: str, pair: AlignedPair, max_points: int = MAX_POINTS) -> dict[str, Any]:
    """The charts of one topic: columns (time s, errors, positions) and chart specs."""
    t: NDArray[np.int64] = np.asarray(pair.t, dtype=np.int64)
    n = len(t)
    stride = max(1, math.ceil(n / max_points))
    ts = (t - t[0]).astype(np.float64) * 1e-9 if n else np.zeros(0)
    errs = error_series(pair)
    cols: dict[str, list[float | None]] = {"t": _column(ts, stride)}
    for key, _ in (*_POS, *_ROT):
        if key in errs:
            cols["e_" + key] = _column(errs[key], stride)
    ref = np.asarray(pair.reference.position, dtype=np.float64)
    oth = np.asarray(pair.other.position, dtype=np.float64)
    for i, a in enumerate(("x", "y")):
        cols["ref_" + a] = _column(ref[:, i], stride)
        cols["oth_" + a] = _column(oth[:, i], stride)

    def err_series(keys: tuple[tuple[str, str], ...]) -> list[dict[str, Any]]:
        return [
            {
                "x": "t",
                "y": "e_" + k,
                "label": label,
                "color": AXIS_COLOURS.get(k, _EXTRA_COLOURS.get(k, "#4c72b0")),
                "dash": "5 3" if k in _EXTRA_COLOURS else None,
            }
            for k, label in keys
            if "e_" + k in cols
        ]

    charts = [
        {
            "title": "Position error over time (Unity - Gazebo)",
            "xlabel": "time (s)",
            "ylabel": "error (m)",
            "unit": "m",
            "series": err_series(_POS),
        },
        {
            "title": "Rotation error over time (Unity - Gazebo)",
            "xlabel": "time (s)",
            "ylabel": "error (deg)",
            "unit": "deg",
            "series": err_series(_ROT),
        },
        {
            "title": "Trajectory from above (ENU x-y), coloured by the error",
            "xlabel": "x east (m)",
            "ylabel": "y north (m)",
            "equal": True,
            "height": 520,
            "series": [
                {"x": "oth_x", "y": "oth_y", "label": "Unity", "color": "#6e7781", "dash": "6 3"},
                {"x": "ref_x", "y": "ref_y", "c": "e_position_norm", "unit": "m",
                 "label": "Gazebo (reference), coloured by the position error norm",
                 "color": "#1f77b4", "width": 2.4},
            ],
        },
    ]  # fmt: skip
    return {"name": name, "columns": cols, "charts": charts, "n": n, "stride": stride}


def _table(doc: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    """The errors per axis in the report's number format (mm, deg, r with 4+ decimals)."""
    from uwval.reports.numbers import Quantity, fmt

    cols = ["axis", "unit", "MAE", "RMSE", "max |e|", "bias", "Pearson r"]
    rows = []
    for a in AXES:
        m = doc.get("axes", {}).get(a, {})
        q = Quantity.LENGTH if AXIS_UNITS[a] == "m" else Quantity.ANGLE
        rows.append(
            [
                a,
                "mm" if q is Quantity.LENGTH else "deg",
                *[fmt(m.get(k), q) for k in ("mae", "rmse", "max", "bias")],
                fmt(m.get("pearson_r"), Quantity.CORRELATION),
            ]
        )
    for key, label, q in (
        ("position_error_norm", "position norm", Quantity.LENGTH),
        ("rotation_error_deg", "rotation angle", Quantity.ANGLE),
    ):
        s = doc.get(key) or {}
        rows.append(
            [label, "mm" if q is Quantity.LENGTH else "deg", fmt(s.get("mean"), q),
             fmt(s.get("rmse"), q), fmt(s.get("max"), q), "", ""]
        )  # fmt: skip
    return cols, rows


def render_interactive(
    results: Mapping[str, Any], title: str, subtitle: str = "", max_points: int = MAX_POINTS
) -> str:
    """The page for ``results``: topic name -> ComparisonResult (an :class:`AlignedPair`
    with ``to_json()``), in order."""
    from uwval.reports.method import method_line

    topics, payload, docs = [], [], []
    for name, res in results.items():
        p = topic_payload(name, res, max_points)
        payload.append({"columns": p["columns"], "charts": p["charts"]})
        doc = res.to_json()
        docs.append(doc)
        cols, rows = _table(doc)
        note = f"; every {p['stride']}th drawn" if p["stride"] > 1 else ""
        describe = getattr(res.other, "describe", None)
        ref_describe = getattr(res.reference, "describe", None)
        sub = f"{describe()} vs {ref_describe()}" if describe and ref_describe else ""
        topics.append(
            {
                "name": name,
                "subtitle": sub,
                "n": p["n"],
                "note": note,
                "table_columns": cols,
                "table_rows": rows,
            }
        )
    # "</" inside the JSON could close the script element: escaped, JSON stays equal
    data = json.dumps({"topics": payload}, allow_nan=False, separators=(",", ":"))
    data = data.replace("</", "<\\/")
    return (
        environment()
        .get_template("interactive.html.j2")
        .render(
            title=title,
            subtitle=subtitle,
            generated=datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            topics=topics,
            method=method_line(docs, {}),
            data=data,
            script=(TEMPLATES / "interactive.js").read_text(encoding="utf-8"),
            css=(TEMPLATES / "report.css").read_text(encoding="utf-8"),
        )
    )


def write_interactive(
    results: Mapping[str, Any], path: Path, title: str, subtitle: str = ""
) -> Path:
    """Write :func:`render_interactive` to ``path`` (parents created)."""
    text = render_interactive(results, title, subtitle)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ReportError(f"{path}: cannot write the interactive HTML: {exc}") from exc
    return path
