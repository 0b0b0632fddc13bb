"""``uwval rpe REF EST``: relative pose error with evo_rpe's options (and evo's spellings).

A thin layer: the command builds one :class:`uwval.comparison.options.RpeOptions` and calls
:func:`uwval.comparison.logs.run_rpe`. Inputs are read as ``uwval compare`` reads them: TUM
text, KITTI, EuRoC, or one topic of a log each (or two topics of one log); evo's first
positional word (``tum``, ``kitti``, ``euroc``, ``bag``, ``bag2``) is accepted.
"""

from __future__ import annotations

import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uwval.cli import app
from uwval.cli.compare_args import EvoCommand, choice, read_positionals
from uwval.cli.console import error_console, output_console, warn
from uwval.cli.declare import Arg, Opt, declare_signature
from uwval.cli.shared_options import (
    ALIGN,
    EVO_ALIGN,
    FORMAT,
    FRAME,
    JSON,
    MAX_DIFF,
    OFFSET,
    RESULT_FILE,
)
from uwval.comparison.logs import RpeComparison
from uwval.comparison.options import (
    AlignmentMode,
    CompareInputs,
    InputFormat,
    PoseRelation,
    RpeOptions,
    TimeWindow,
)
from uwval.errors import ConfigError

_RELATION_NAMES = {
    "trans_part": "translation part",
    "rot_part": "rotation part",
    "full": "full transformation",
    "angle_deg": "rotation angle in degrees",
    "angle_rad": "rotation angle in radians",
    "point_distance": "point distance",
    "point_distance_error_ratio": "point distance error ratio",
}
_ALIGN_TITLES = {
    "none": "not aligned",
    "se3": "with SE(3) Umeyama alignment",
    "sim3": "with Sim(3) Umeyama alignment",
    "scale": "scale corrected",
    "origin": "with origin alignment",
}

#: Every option of ``uwval rpe``, in ``--help`` order (names and kinds as in ``compare``).
RPE_OPTIONS: tuple[Opt, ...] = (
    Opt("ref_topic", ("--ref-topic", "--gazebo-topic"), str, None, "Reference topic"),
    Opt("est_topic", ("--est-topic", "--unity-topic"), str, None, "Estimate topic"),
    FORMAT,
    FRAME,
    Opt(
        "relation",
        ("-r", "--pose_relation", "--pose-relation"),
        str,
        "trans_part",
        "trans_part, rot_part, full, angle_deg, angle_rad, point_distance, "
        "point_distance_error_ratio",
    ),
    Opt("delta", ("-d", "--delta"), float, 1.0, "Delta between poses"),
    Opt(
        "delta_unit",
        ("-u", "--delta_unit", "--delta-unit"),
        str,
        "f",
        "f (frames), m (metres), d (deg), r (rad)",
    ),
    Opt(
        "delta_tol",
        ("-t", "--delta_tol", "--delta-tol"),
        float,
        0.1,
        "Relative delta tolerance (all pairs)",
    ),
    Opt("all_pairs", ("--all_pairs", "--all-pairs"), bool, False, "All pairs, not consecutive"),
    Opt(
        "pairs_from_reference",
        ("--pairs_from_reference", "--pairs-from-reference"),
        bool,
        False,
        "Choose the pairs on the reference (default: on the estimate, as evo)",
    ),
    ALIGN,
    EVO_ALIGN,
    Opt(
        "correct_scale",
        ("-s", "--correct_scale", "--correct-scale"),
        bool,
        False,
        "evo's -s: correct the scale",
    ),
    Opt(
        "align_origin",
        ("--align_origin", "--align-origin"),
        bool,
        False,
        "evo's --align_origin: align the first poses",
    ),
    Opt("n_to_align", ("--n_to_align", "--n-to-align"), int, -1, "Poses used to align (-1: all)"),
    MAX_DIFF,
    OFFSET,
    Opt("t_start", ("--t_start", "--t-start"), float, None, "evo's --t_start (s)"),
    Opt("t_end", ("--t_end", "--t-end"), float, None, "evo's --t_end (s)"),
    Opt("downsample", ("--downsample",), int, None, "evo's --downsample N"),
    Opt("verbose", ("-v", "--verbose"), bool, False, "evo's -v: also print the alignment"),
    Opt("silent", ("--silent",), bool, False, "evo's --silent: print nothing on stdout"),
    Opt(
        "no_warnings",
        ("--no_warnings", "--no-warnings"),
        bool,
        False,
        "evo's --no_warnings: accepted (uwval never asks for confirmation)",
    ),
    Opt("logfile", ("--logfile",), Path, None, "evo's --logfile: also write the output"),
    Opt(
        "plot",
        ("--plot", "-p"),
        bool,
        False,
        "Write the RPE over time as a PNG (no window): to --save_plot, else uwval_rpe.png",
    ),
    Opt("save_plot", ("--save_plot", "--save-plot"), Path, None, "Figure path; implies --plot"),
    Opt(
        "save_results",
        ("--save_results", "--save-results"),
        Path,
        None,
        "evo's --save_results: a .zip in evo's layout when evo_rpe would give the same "
        "numbers (an estimate in ENU); otherwise without evo's stats.json/info.json",
    ),
    JSON,
    RESULT_FILE,
)


#: The positional words of ``rpe``.
_WORDS = Arg(
    "words",
    list[str],
    "REF EST, or LOG with --ref-topic/--est-topic; evo's shapes: "
    "tum|kitti|euroc REF EST, bag|bag2 LOG /ref_topic /est_topic",
    metavar="INPUTS",
    show_default=False,
)


@dataclass(frozen=True)
class _Flags:
    """evo's alignment flags of one command line."""

    align: str
    evo_align: bool
    correct_scale: bool
    align_origin: bool


def _align_mode(flags: _Flags) -> AlignmentMode:
    """--align MODE and evo's flags -> one mode: -a se3, -as sim3, -s scale only,
    --align_origin origin (evo_rpe refuses --align_origin with -a or -s)."""
    if flags.align_origin and (flags.evo_align or flags.correct_scale):
        raise ConfigError("--align_origin cannot be combined with -a / -s (as in evo_rpe)")
    if flags.align_origin:
        mode = AlignmentMode.ORIGIN
    elif flags.evo_align:
        mode = AlignmentMode.SIM3 if flags.correct_scale else AlignmentMode.SE3
    elif flags.correct_scale:
        mode = AlignmentMode.SCALE
    else:
        return choice(AlignmentMode, flags.align, "--align")
    if flags.align not in ("none", mode.value):
        raise ConfigError(f"--align {flags.align} contradicts evo's flags (which mean {mode})")
    return mode


def _offset_s(text: str) -> float:
    """--offset as rpe takes it: seconds added to the estimate's stamps (compare's
    'auto' estimate is not part of evo_rpe's options)."""
    try:
        return float(text)
    except ValueError:
        raise ConfigError(
            f"--offset {text!r}: rpe takes a clock offset in seconds (estimate one with "
            "uwval compare --offset auto)"
        ) from None


def rpe_options(kw: dict[str, Any]) -> RpeOptions:
    """The typed options of one ``uwval rpe`` from its command line."""
    pos = read_positionals(list(kw["words"]))
    fmt = pos.fmt or (choice(InputFormat, kw["fmt"], "--format") if kw["fmt"] else None)
    inputs = CompareInputs(
        pos.log_a,
        pos.log_b,
        pos.gazebo_topic or kw["ref_topic"],
        pos.unity_topic or kw["est_topic"],
        fmt,
    )
    flags = _Flags(kw["align"], kw["evo_align"], kw["correct_scale"], kw["align_origin"])
    return RpeOptions(
        inputs=inputs,
        frame=kw["frame"],
        relation=choice(PoseRelation, kw["relation"], "--pose_relation"),
        delta=kw["delta"],
        delta_unit=kw["delta_unit"],
        delta_tol=kw["delta_tol"],
        all_pairs=kw["all_pairs"],
        pairs_from_reference=kw["pairs_from_reference"],
        align=_align_mode(flags),
        n_to_align=kw["n_to_align"],
        max_diff=kw["max_diff"],
        offset=_offset_s(kw["offset"]),
        window=TimeWindow(kw["t_start"], kw["t_end"], kw["downsample"]),
    )


def rpe_command(**kw: Any) -> None:
    """Relative pose error as evo_rpe computes it (same pairs, relations, alignment, stats)."""
    kw.pop("ctx")
    from uwval.cli.compare_files import write_output
    from uwval.cli.notes import warnings_as_notes
    from uwval.comparison.logs import run_rpe

    options = rpe_options(kw)
    with warnings_as_notes():
        found = run_rpe(options)
    text = json.dumps(found.to_json(), indent=1, allow_nan=False)
    saved: list[Path] = []
    if kw["output"] is not None:
        write_output(kw["output"], text + "\n", "the JSON result")
        saved.append(kw["output"])
    if kw["save_results"] is not None:
        saved.append(_save_results(kw["save_results"], found, text))
    if kw["plot"] or kw["save_plot"] is not None:
        saved.append(_plot(found, kw["save_plot"]))
    if kw["as_json"]:
        if not kw["silent"]:
            sys.stdout.write(text + "\n")
        for path in saved:
            error_console().print(f"wrote {path}", markup=False, highlight=False)
        return
    console = output_console(
        file=io.StringIO() if kw["silent"] else None, record=kw["logfile"] is not None
    )
    for line in _lines(found, kw["verbose"]) + [f"wrote {p}" for p in saved]:
        console.print(line, markup=False, highlight=False)
    if kw["logfile"] is not None:
        write_output(kw["logfile"], console.export_text(), "the log file")


declare_signature(rpe_command, (_WORDS, *RPE_OPTIONS), context=True)
app.command("rpe", cls=EvoCommand)(rpe_command)


def _lines(found: RpeComparison, verbose: bool) -> list[str]:
    """What ``uwval rpe`` prints: evo_rpe's title and statistics, then any warnings."""
    from uwval.comparison.rpe import DELTA_UNITS

    res = found.result
    title = (
        f"RPE w.r.t. {_RELATION_NAMES[res.relation]} ({res.unit})\n"
        f"for delta = {res.delta:g} ({DELTA_UNITS[res.delta_unit]}) using "
        f"{'all' if res.all_pairs else 'consecutive'} pairs\n"
        f"({_ALIGN_TITLES.get(res.alignment.mode, res.alignment.mode)})"
    )
    lines = [
        title,
        f"pairs {res.n_pairs} of {res.n_poses} matched poses; sync {res.sync['method']}",
    ]
    lines += [
        f"{k:>8}  {res.stats[k]:.6f}"
        for k in ("max", "mean", "median", "min", "rmse", "sse", "std")
    ]
    if verbose and res.alignment.mode != "none":
        import numpy as np

        al = res.alignment
        lines.append(
            f"alignment {al.mode}: scale {al.scale:.9g}, translation (m) "
            f"{np.array2string(al.translation, precision=9)}, rotation\n"
            f"{np.array2string(al.rotation, precision=9)}"
        )
    lines += [f"warning: {w}" for w in res.warnings]
    return lines


def _save_results(path: Path, found: RpeComparison, text: str) -> Path:
    """evo's --save_results for RPE: evo's layout when evo_rpe would give the same numbers
    (an estimate already in ENU), else a zip evo_res refuses; any other suffix: the JSON."""
    from uwval.cli.compare_files import evo_zip, write_output

    if path.suffix.lower() != ".zip":
        write_output(path, text + "\n", "the results")
        return path
    res = found.result
    unit = res.unit
    stats = {k: res.stats[k] for k in ("rmse", "mean", "median", "std", "min", "max", "sse")}
    info = {
        "title": f"RPE w.r.t. {_RELATION_NAMES[res.relation]} ({unit})",
        "ref_name": found.sources[0],
        "est_name": found.sources[-1],
        "label": f"RPE ({unit})",
    }
    reason = None if found.other_frame == "enu" else f"frame {found.other_frame} converted to ENU"
    arrays = {"error_array": res.errors, "timestamps": res.t * 1e-9}
    data = evo_zip(stats, info, reason, arrays, {"uwval.json": text})
    write_output(path, data, "the results")
    if reason is not None:
        warn(f"{path} is not an evo result ({reason}): written without evo's stats.json/info.json")
    return path


def _plot(found: RpeComparison, save_plot: Path | None) -> Path:
    """--plot / --save_plot: the relative errors over time (s from the first pair)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ConfigError(f"--plot needs matplotlib ({exc})") from None
    from uwval.cli.compare_files import PLOT_SUFFIXES

    res = found.result
    target = save_plot or Path("uwval_rpe.png")
    if target.suffix.lower() not in PLOT_SUFFIXES:
        target = target.with_name(target.name + ".png")
    fig = Figure(figsize=(8, 3.5))
    ax = fig.subplots()
    seconds = (res.t - res.t[0]) * 1e-9 if len(res.t) else res.t
    ax.plot(seconds, res.errors, lw=0.8)
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"RPE ({res.unit})")
    ax.set_title(
        f"RPE w.r.t. {_RELATION_NAMES[res.relation]}, delta {res.delta:g} {res.delta_unit}"
    )
    ax.grid(True, alpha=0.3)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(target, dpi=100)
    except OSError as exc:
        raise ConfigError(f"{target}: cannot write the plot: {exc.strerror or exc}") from None
    return target
