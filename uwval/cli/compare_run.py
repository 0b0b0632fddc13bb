"""The work of ``uwval compare`` without typer: the fast path of the command line.

``uwval compare`` on plain arguments (:func:`fast_compare`) parses them here and runs
:func:`run_compare`, importing neither typer (which imports pydantic and builds a validator
per option) nor rich unless a table is printed: start-up is most of the whole-command time of
a compare. The typer command in :mod:`uwval.cli.compare_cmd` calls the same function.
"""

from __future__ import annotations

import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError


def _parse_offset(value: str) -> float | str:
    if value.strip().lower() == "auto":
        return "auto"
    try:
        seconds = float(value)
    except ValueError:
        raise ConfigError(f"--offset must be seconds or 'auto', got {value!r}") from None
    if not math.isfinite(seconds):
        raise ConfigError(f"--offset must be a finite number of seconds or 'auto', got {value!r}")
    return seconds


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if v != 0 and abs(v) < 1e-3:  # keep small errors short and legible: 5.03e-04
            return f"{v:.{digits - 1}e}"
        return f"{v:.{digits}g}"
    return str(v)


def _print_table(doc: dict[str, Any], title: str) -> None:
    from rich import box
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = Console()
    sync = doc.get("sync") or {}
    if sync.get("method") == "nearest":  # evo's association: say its parameter too
        title += f"  (sync nearest, max diff {sync.get('max_diff_s', 0.01):g} s, as evo)"
    elif sync.get("method"):
        title += f"  (sync {sync['method']}: Unity side interpolated at the reference stamps)"
    table = Table(title=escape(title), title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    # short on purpose (fits 80 columns): p95, std, p-value and CI are in --json
    for col in ("axis", "MAE", "RMSE", "max", "bias", "Pearson r"):
        table.add_column(col, justify="left" if col == "axis" else "right", no_wrap=True)
    for ax, s in doc["axes"].items():
        r = f"{s['pearson_r']:.6f}" if s.get("pearson_r") is not None else "n/a"
        unit = s.get("unit", "")
        table.add_row(
            escape(f"{ax} [{unit}]") if unit else ax,
            _fmt(s["mae"]),
            _fmt(s["rmse"]),
            _fmt(s["max"]),
            _fmt(s["bias"]),
            r,
        )
    console.print(table)
    undefined = [ax for ax, s in doc["axes"].items() if s.get("pearson_r") is None]
    if undefined:
        reasons = {doc["axes"][ax].get("pearson_reason") or "undefined" for ax in undefined}
        console.print(
            f"Pearson r n/a for {', '.join(undefined)}: {'; '.join(sorted(reasons))}",
            highlight=False,
        )
    pn, rot, counts = doc["position_error_norm"], doc["rotation_error_deg"], doc["counts"]
    console.print(
        f"samples {doc['n_samples']} (matched {counts['matched']}, masked {counts['masked']}, "
        f"dropped {counts['dropped']}); sync {doc['sync']['method']}; frame "
        f"{doc['frame']['configured']}; align {doc['alignment']['mode']}"
    )
    console.print(
        f"position error norm [m]: rmse {_fmt(pn['rmse'])} mean {_fmt(pn['mean'])} "
        f"median {_fmt(pn['median'])} max {_fmt(pn['max'])}; rotation [deg]: rmse "
        f"{_fmt(rot['rmse'])} max {_fmt(rot['max'])}",
        markup=False,
    )
    off = doc["offset"]
    line = f"clock offset {_fmt(off['applied_s'], 6)} s"
    if off.get("estimate"):
        line += f" (estimated, +/- {_fmt(off['estimate']['uncertainty_s'], 3)} s)"
    if doc.get("latency"):
        lat = doc["latency"]
        line += f"; latency {_fmt(lat['mean_ms'])} ms mean, {_fmt(lat['p95_ms'])} ms p95"
    console.print(line)
    for w in doc.get("warnings", []):
        console.print(f"[yellow]warning:[/] {escape(w)}", highlight=False)


def run_compare(
    log_a: Path,
    log_b: Path | None = None,
    *,
    gazebo_topic: str | None = None,
    unity_topic: str | None = None,
    fmt: str | None = None,
    frame: str | None = None,
    sync: str = "interp",
    max_gap: float | None = None,
    max_diff: float = 0.01,
    offset: str = "0",
    max_offset: float | None = None,
    align: str = "none",
    as_json: bool = False,
    output: Path | None = None,
) -> None:
    """What ``uwval compare`` does for one log or one pair of files: compare, print, save."""
    from uwval.cli.notes import warnings_as_notes
    from uwval.comparison.logs import compare_logs

    with warnings_as_notes():
        result = compare_logs(
            log_a,
            log_b,
            gazebo_topic=gazebo_topic,
            unity_topic=unity_topic,
            fmt=fmt,
            frame=frame,
            sync=sync,
            max_gap=max_gap,
            max_diff=max_diff,
            offset=_parse_offset(offset),
            max_offset=max_offset,
            align=align,
        )
    doc = result.to_json()
    text = json.dumps(doc, indent=1, allow_nan=False)
    if output is not None:
        try:
            output.parent.mkdir(parents=True, exist_ok=True)
            output.write_text(text + "\n")
        except OSError as exc:
            raise ConfigError(
                f"{output}: cannot write the JSON result: {exc.strerror or exc}"
            ) from None
    if as_json:
        sys.stdout.write(text + "\n")
        return
    for name, res in result.results.items():
        _print_table(res.to_json(), f"{name}: {res.other.describe()} vs {res.reference.describe()}")


@dataclass(frozen=True)
class CompareOption:
    """One option of ``uwval compare``: the one source of both command-line parsers.

    The typer command (:mod:`uwval.cli.compare_cmd`, for ``--help``, usage errors and
    ``--batch``) is built from :data:`COMPARE_OPTIONS`, and so is the light parser of
    :func:`fast_compare`; an option exists in both or in neither.
    """

    dest: str  # keyword of run_compare / the typer command
    flags: tuple[str, ...]
    kind: Any  # str, float, int, bool (a flag), Path, or list[str] (a repeatable option)
    default: Any
    help: str
    fast: bool = True  # False: only typer handles it (the fast path declines, runs nothing)


FRAME_HELP = (
    "Convention of the second (Unity) stream: unity-flu, unity-enu, ned, enu or auto "
    "(default: from the log's frame_id; enu for TUM files)"
)

#: Every option of ``uwval compare``, in ``--help`` order.
COMPARE_OPTIONS: tuple[CompareOption, ...] = (
    CompareOption("gazebo_topic", ("--gazebo-topic",), str, None, "Reference topic"),
    CompareOption("unity_topic", ("--unity-topic",), str, None, "Other (Unity) topic"),
    CompareOption(
        "fmt",
        ("--format",),
        str,
        None,
        "Input format: tum, or a log format read by uwval.io (default: by suffix)",
    ),
    CompareOption("frame", ("--frame",), str, None, FRAME_HELP),
    CompareOption(
        "sync",
        ("--sync",),
        str,
        "interp",
        "interp (lerp+slerp at reference stamps) or nearest (evo's association: "
        "--sync nearest --max-diff 0.01 gives evo_ape's numbers)",
    ),
    CompareOption(
        "max_gap",
        ("--max-gap",),
        float,
        None,
        "interp: mask samples in gaps longer than this (s; default 5 periods)",
    ),
    CompareOption("max_diff", ("--max-diff",), float, 0.01, "nearest: max stamp difference (s)"),
    CompareOption(
        "offset",
        ("--offset",),
        str,
        "0",
        "Clock offset added to the second stream's stamps (s), or 'auto' to estimate it",
    ),
    CompareOption("max_offset", ("--max-offset",), float, None, "Bound for --offset auto (s)"),
    CompareOption("align", ("--align",), str, "none", "none, se3, sim3 (Umeyama) or origin"),
    CompareOption("as_json", ("--json",), bool, False, "Print the JSON result"),
    CompareOption(
        "output",
        ("-o", "--output"),
        Path,
        None,
        "Also write the JSON result here (with --batch: the results directory)",
    ),
    CompareOption(
        "batch",
        ("--batch",),
        bool,
        False,
        "LOG_A is an experiment directory or manifest: compare every log into one results table",
        fast=False,
    ),
    CompareOption(
        "executor",
        ("--executor",),
        str,
        "local",
        "--batch: local (process pool), dask or inline",
        fast=False,
    ),
    CompareOption("workers", ("--workers",), int, None, "--batch: worker processes", fast=False),
    CompareOption(
        "scheduler", ("--scheduler",), str, None, "--batch: Dask scheduler address", fast=False
    ),
    CompareOption(
        "allow_protocol",
        ("--allow-protocol",),
        list[str],
        None,
        "--batch: fetch manifest logs by this remote protocol (s3, gs, http...; repeatable; "
        "also UWVAL_ALLOW_PROTOCOLS=s3,gs). Without it only local paths are read",
        fast=False,
    ),
)

#: What ``fast_compare`` understands, derived from :data:`COMPARE_OPTIONS`:
#: option flag -> (keyword of run_compare, kind).
_FAST_OPTIONS: dict[str, tuple[str, type]] = {
    flag: (o.dest, o.kind) for o in COMPARE_OPTIONS if o.fast for flag in o.flags
}
_PLAIN_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def fast_compare(argv: list[str]) -> bool:
    """Run ``uwval compare`` from the arguments after ``compare``, if they are plain.

    The same :func:`run_compare` runs, so output and errors are identical; only the
    command-line parsing is lighter. Returns False without doing anything when an argument
    is not a plain value of a known option (help, a typo, a repeated option, a number typer
    might read differently...): the caller then lets typer parse, which owns usage errors.
    """
    kwargs: dict[str, Any] = {}
    positional: list[str] = []
    args = iter(argv)
    for arg in args:
        if arg.startswith("-"):
            name, has_value, value = arg.partition("=")
            spec = _FAST_OPTIONS.get(name)
            if spec is None or spec[0] in kwargs:
                return False
            dest, kind = spec
            if kind is bool:  # a flag: no value
                if has_value:
                    return False
                kwargs[dest] = True
                continue
            if not has_value:
                value = next(args, "")
            if not value:
                return False
            if kind is float:
                if not _PLAIN_FLOAT.fullmatch(value):
                    return False
                kwargs[dest] = float(value)
            elif kind is str or kind is Path:
                kwargs[dest] = kind(value)
            else:  # a kind the light parser does not convert: typer's job
                return False
        else:
            positional.append(arg)
    if len(positional) not in (1, 2):
        return False
    run_compare(
        Path(positional[0]), Path(positional[1]) if len(positional) == 2 else None, **kwargs
    )
    return True
