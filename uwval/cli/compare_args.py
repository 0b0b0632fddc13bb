"""From the command line of ``uwval compare`` to one :class:`CompareOptions`.

The options are declared once, in :data:`COMPARE_OPTIONS` (typer builds the command from
it); :func:`compare_options` turns what the user gave, the project file's ``[compare]`` table
and evo's spellings into the typed options. evo's positional shapes (``tum REF EST``,
``bag LOG /a /b``) are read by :func:`read_positionals`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from typer.core import TyperCommand

from uwval.cli.declare import Opt
from uwval.cli.shared_options import (
    ALIGN,
    CONFIG,
    EVO_ALIGN,
    EXECUTOR,
    FORMAT,
    FRAME,
    GAZEBO_TOPIC,
    JSON,
    MAX_DIFF,
    OFFSET,
    RESULT_FILE,
    SCHEDULER,
    SYNC,
    UNITY_TOPIC,
    WORKERS,
)
from uwval.comparison.options import (
    AlignmentMode,
    ApeUnit,
    ClockOffset,
    CompareInputs,
    CompareOptions,
    DriftMode,
    InputFormat,
    PoseRelation,
    SyncMethod,
    TimeWindow,
)
from uwval.errors import ConfigError


def evo_bare_align(args: list[str]) -> list[str]:
    """evo's ``--align`` is a flag (SE(3)); uwval's takes a mode. ``--align`` last, or
    followed by another option, is evo's flag: it becomes ``-a``."""
    out = list(args)
    for i, arg in enumerate(out):
        if arg == "--align" and (i + 1 == len(out) or out[i + 1].startswith("-")):
            out[i] = "-a"
    return out


class EvoCommand(TyperCommand):
    """A typer command that also takes evo's bare ``--align`` flag (click's parse hook)."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        # ctx is the click Context typer vendors: its type is private to typer
        rest: list[str] = super().parse_args(ctx, evo_bare_align(args))
        return rest


#: Every option of ``uwval compare``, in ``--help`` order.
COMPARE_OPTIONS: tuple[Opt, ...] = (
    GAZEBO_TOPIC,
    UNITY_TOPIC,
    FORMAT,
    FRAME,
    SYNC,
    Opt(
        "sync_method",
        ("--sync_method",),
        str,
        None,
        "evo's spelling: nearest_time (= --sync nearest); evo's 'interpolation' is refused "
        "(it resamples the denser stream, uwval's interp the other one)",
    ),
    Opt(
        "max_gap",
        ("--max-gap",),
        float,
        None,
        "interp: mask samples in gaps longer than this (s; default 5 periods)",
    ),
    MAX_DIFF,
    OFFSET,
    Opt("max_offset", ("--max-offset",), float, None, "Bound for --offset auto (s)"),
    Opt(
        "drift",
        ("--drift",),
        str,
        None,
        "Clock drift of the second stream: auto fits it (ppm; applied stamps, else the "
        "lag's trend) and removes it; off (the default) leaves it (a long drifting run gets "
        "a warning)",
    ),
    ALIGN,
    EVO_ALIGN,
    Opt(
        "correct_scale",
        ("-s", "--correct_scale", "--correct-scale"),
        bool,
        False,
        "evo's -s: correct the scale (with -a: Sim(3); alone: the scale only)",
    ),
    Opt(
        "align_origin",
        ("--align_origin", "--align-origin"),
        bool,
        False,
        "evo's --align_origin: = --align origin",
    ),
    Opt(
        "n_to_align",
        ("--n_to_align", "--n-to-align"),
        int,
        -1,
        "Fit the alignment on the first N aligned samples only, apply it to all (-1: all)",
    ),
    Opt(
        "pose_relation",
        ("-r", "--pose_relation", "--pose-relation"),
        str,
        None,
        "Also give evo_ape's statistics of this relation: trans_part, rot_part, full, "
        "angle_deg, angle_rad or point_distance (printed, and under 'ape' in the JSON)",
    ),
    Opt(
        "change_unit",
        ("--change_unit", "--change-unit"),
        str,
        None,
        "evo's --change_unit: the APE statistics in deg, rad, mm, cm, m or km (implies "
        "-r trans_part when no -r is given)",
    ),
    Opt(
        "t_start",
        ("--t_start", "--t-start"),
        float,
        None,
        "evo's --t_start: only reference poses stamped at or after this time (s)",
    ),
    Opt(
        "t_end",
        ("--t_end", "--t-end"),
        float,
        None,
        "evo's --t_end: only reference poses stamped at or before this time (s)",
    ),
    Opt(
        "downsample",
        ("--downsample",),
        int,
        None,
        "evo's --downsample: both streams to at most N evenly spaced poses, before the sync",
    ),
    Opt(
        "project_to_plane",
        ("--project_to_plane", "--project-to-plane"),
        str,
        None,
        "evo's --project_to_plane: refused (use evo_traj --project_to_plane --save_as_tum first)",
    ),
    Opt(
        "motion_filter",
        ("--motion_filter", "--motion-filter"),
        tuple[float, float],
        None,
        "evo's --motion_filter DISTANCE ANGLE: refused (use evo_traj --motion_filter first)",
    ),
    Opt(
        "verbose",
        ("-v", "--verbose"),
        bool,
        False,
        "evo's -v: also print the alignment (rotation, translation, scale)",
    ),
    Opt(
        "silent",
        ("--silent",),
        bool,
        False,
        "evo's --silent: print nothing on stdout (files are still written; errors on stderr)",
    ),
    Opt(
        "no_warnings",
        ("--no_warnings", "--no-warnings"),
        bool,
        False,
        "evo's --no_warnings: accepted; uwval never asks for confirmation (it overwrites)",
    ),
    Opt(
        "logfile",
        ("--logfile",),
        Path,
        None,
        "evo's --logfile: also write what is printed (the table) to this file",
    ),
    Opt(
        "plot",
        ("--plot", "-p"),
        bool,
        False,
        "Write PNG files (no window opens; evo's -p): trajectory, errors over time, error "
        "histograms, trajectory coloured by the error: to --save_plot, else "
        "uwval_<topic>_{trajectory,errors,histogram,errormap}.png here",
    ),
    Opt(
        "plot_mode",
        ("--plot_mode", "--plot-mode"),
        str,
        None,
        "evo's --plot_mode: xy or xz (uwval's trajectory figure draws both views); "
        "other views are refused",
    ),
    Opt(
        "save_plot",
        ("--save_plot", "--save-plot"),
        Path,
        None,
        "Path of the trajectory figure (the others go beside it); implies --plot",
    ),
    Opt(
        "save_errors",
        ("--save-errors", "--save_errors"),
        Path,
        None,
        "Write the per-sample signed errors as CSV (stamp, x y z m, roll pitch yaw deg, "
        "position norm m, rotation angle deg)",
    ),
    Opt(
        "save_results",
        ("--save_results", "--save-results"),
        Path,
        None,
        "evo's --save_results: a .zip in evo's layout when evo_ape would give the same "
        "numbers (otherwise without evo's stats.json/info.json, so evo_res refuses it); "
        "any other suffix: the JSON result",
    ),
    Opt(
        "html",
        ("--html",),
        Path,
        None,
        "Write an interactive, self-contained HTML page (no network)",
    ),
    JSON,
    RESULT_FILE,
    CONFIG,
    Opt(
        "batch",
        ("--batch",),
        bool,
        False,
        "LOG is an experiment directory or manifest: compare every log into one results table",
    ),
    Opt(
        "results_dir",
        ("--results-dir",),
        Path,
        None,
        "--batch: the folder of comparisons.json and results.csv (default: <experiment>/results)",
    ),
    EXECUTOR,
    WORKERS,
    SCHEDULER,
    Opt(
        "allow_protocol",
        ("--allow-protocol",),
        list[str],
        None,
        "--batch: fetch manifest logs by this remote protocol (s3, gs, http...; repeatable; "
        "also UWVAL_ALLOW_PROTOCOLS=s3,gs). Without it only local paths are read",
    ),
)

#: The project file's [compare] keys, as keywords of the command.
PROJECT_KEYS = (
    "sync",
    "max_diff",
    "max_gap",
    "offset",
    "max_offset",
    "drift",
    "align",
    "frame",
    "fmt",
    "n_to_align",
    "pose_relation",
)

#: evo's first positional word -> the input format it names (None: a ROS log, any kind).
EVO_WORDS: dict[str, InputFormat | None] = {
    "tum": InputFormat.TUM,
    "kitti": InputFormat.KITTI,
    "euroc": InputFormat.EUROC,
    "bag": None,
    "bag2": None,
}

USAGE = (
    "uwval compare takes LOG, REF EST, or LOG /ref_topic /other_topic "
    "(evo's shapes too: tum|kitti|euroc REF EST, bag|bag2 LOG /ref_topic /other_topic)"
)


@dataclass(frozen=True)
class Positionals:
    """What the positional words name: files, topics and the format of evo's first word."""

    log_a: Path
    log_b: Path | None = None
    gazebo_topic: str | None = None
    unity_topic: str | None = None
    fmt: InputFormat | None = None


def read_positionals(words: list[str]) -> Positionals:
    """The positional words of ``compare``: ``LOG``, ``REF EST``, ``LOG /a /b``, and evo's
    ``tum|kitti|euroc REF EST`` and ``bag|bag2 LOG /a /b`` (a word that is an existing
    file is always a file). Anything else is a ConfigError with the command to type."""
    if not words:
        raise ConfigError(f"no input given: {USAGE}")
    first = words[0]
    if first in EVO_WORDS and not Path(first).exists():
        fmt, rest = EVO_WORDS[first], words[1:]
        if fmt is not None:
            if len(rest) != 2:
                raise ConfigError(
                    f"evo's shape is `{first} REF EST`: type uwval compare {first} REF EST "
                    f"(or uwval compare REF EST --format {fmt})"
                )
            return Positionals(Path(rest[0]), Path(rest[1]), fmt=fmt)
        if len(rest) != 3:
            raise ConfigError(
                f"evo's shape is `{first} LOG REF_TOPIC EST_TOPIC`: type uwval compare LOG "
                "--gazebo-topic REF_TOPIC --unity-topic EST_TOPIC"
            )
        return Positionals(Path(rest[0]), gazebo_topic=rest[1], unity_topic=rest[2])
    if len(words) == 3 and not Path(words[1]).exists() and not Path(words[2]).exists():
        return Positionals(Path(first), gazebo_topic=words[1], unity_topic=words[2])
    if len(words) == 1:
        return Positionals(Path(first))
    if len(words) == 2:
        return Positionals(Path(first), Path(words[1]))
    raise ConfigError(f"{len(words)} inputs given ({' '.join(words)}): {USAGE}")


def align_mode(given: dict[str, Any]) -> AlignmentMode:
    """--align MODE and evo's flags (-a, -s, -as, --align_origin) -> one alignment mode."""
    align = str(given.get("align") or "none")
    evo_align, scale, origin = (
        bool(given.get(k)) for k in ("evo_align", "correct_scale", "align_origin")
    )
    flags = [f for f, on in (("-a", evo_align), ("-s", scale), ("--align_origin", origin)) if on]
    if not flags:
        return choice(AlignmentMode, align, "--align")
    if origin and evo_align:
        raise ConfigError("--align_origin cannot be combined with -a (as in evo_ape)")
    if origin:
        mode = AlignmentMode.SCALE_ORIGIN if scale else AlignmentMode.ORIGIN
    elif evo_align:
        mode = AlignmentMode.SIM3 if scale else AlignmentMode.SE3
    else:
        mode = AlignmentMode.SCALE  # evo_ape -s alone: the scale only
    if align not in ("none", mode.value):
        raise ConfigError(f"--align {align} contradicts {' '.join(flags)} (which means {mode})")
    return mode


#: What each enum of the options is called in an error message.
_ENUM_NAMES = {
    "SyncMethod": "sync method",
    "AlignmentMode": "alignment",
    "PoseRelation": "pose relation",
    "InputFormat": "input format",
    "ApeUnit": "unit",
    "DriftMode": "drift mode",
}


def choice(enum: Any, value: str, flag: str) -> Any:
    """``value`` as a member of ``enum``, or a one-line error listing the choices."""
    try:
        return enum(value.lower())
    except ValueError:
        choices = ", ".join(m.value for m in enum)
        what = _ENUM_NAMES.get(enum.__name__, "value")
        raise ConfigError(f"{flag}: unknown {what} {value!r}; choose one of {choices}") from None


def sync_method(opts: dict[str, Any], max_diff_given: bool) -> SyncMethod | None:
    """--sync, or evo's --sync_method; a max diff given alone on the command line means
    evo's association (under interp it would be silently unused)."""
    evo = opts.get("sync_method")
    sync = opts.get("sync")
    if evo is not None:
        if evo == "interpolation":
            raise ConfigError(
                "--sync_method interpolation: evo resamples the denser trajectory at the "
                "sparser one's stamps, uwval's --sync interp the other stream at the "
                "reference stamps (the numbers differ); use --sync interp or --sync nearest"
            )
        if evo != "nearest_time":
            raise ConfigError(f"--sync_method {evo!r}: choose nearest_time (evo's)")
        if sync not in (None, "nearest"):
            raise ConfigError(f"--sync {sync} contradicts --sync_method nearest_time")
        return SyncMethod.NEAREST
    if sync is not None:
        return choice(SyncMethod, str(sync), "--sync")
    if max_diff_given:
        return SyncMethod.NEAREST
    return None


def _refused(given: dict[str, Any]) -> None:
    """evo's options whose numbers uwval does not compute: refused with what to use."""
    if given.get("project_to_plane") is not None:
        raise ConfigError(
            "--project_to_plane is not supported (uwval compares in 3-D); project first: "
            "evo_traj tum REF EST --project_to_plane xy --save_as_tum, then compare the "
            "written files"
        )
    if given.get("motion_filter") is not None:
        raise ConfigError(
            "--motion_filter is not supported; filter first: evo_traj tum REF EST "
            "--motion_filter DISTANCE ANGLE --save_as_tum, then compare the written files"
        )
    mode = given.get("plot_mode")
    if mode is not None and mode not in ("xy", "xz"):
        raise ConfigError(
            f"--plot_mode {mode}: uwval's trajectory figure draws the xy and xz views; "
            "use evo_traj --plot_mode for other views"
        )


def merge_project(given: dict[str, Any], project: Any) -> dict[str, Any]:
    """The options the user gave, filled from the project file's [compare] table (the
    command line wins); evo's alignment flags beat the file's ``align``."""
    if project is None:
        return dict(given)
    merged = {k: v for k, v in project.compare.items() if k in PROJECT_KEYS} | given
    evo_flags = any(given.get(k) for k in ("evo_align", "correct_scale", "align_origin"))
    if evo_flags and "align" not in given:
        merged.pop("align", None)
    return merged


def compare_options(given: dict[str, Any], project: Any = None) -> CompareOptions:
    """The typed options of one comparison from ``given`` (only what the user typed, by
    keyword of :data:`COMPARE_OPTIONS`, plus ``words``: the positional words) and the
    project file (:class:`uwval.config.ProjectConfig` or None)."""
    _refused(given)
    pos = read_positionals(list(given.get("words") or []))
    if pos.gazebo_topic and (given.get("gazebo_topic") or given.get("unity_topic")):
        raise ConfigError(
            "topics given twice: as positional words and as --gazebo-topic/--unity-topic"
        )
    opts = merge_project(given, project)
    fmt_text = opts.get("fmt")
    fmt = pos.fmt or (choice(InputFormat, fmt_text, "--format") if fmt_text else None)
    pairs = ()
    gazebo = pos.gazebo_topic or opts.get("gazebo_topic")
    unity = pos.unity_topic or opts.get("unity_topic")
    if project is not None and project.pairs and not (gazebo or unity):
        pairs = tuple(project.pairs)
    inputs = CompareInputs(pos.log_a, pos.log_b, gazebo, unity, fmt, pairs)
    relation = opts.get("pose_relation")
    unit = opts.get("change_unit")
    offset = opts.get("offset")
    drift = opts.get("drift")
    return CompareOptions(
        inputs=inputs,
        frame=opts.get("frame"),
        sync=sync_method(opts, "max_diff" in given),
        max_gap=opts.get("max_gap"),
        max_diff=float(opts.get("max_diff", 0.01)),
        offset=None if offset is None else ClockOffset.parse(str(offset)),
        max_offset=opts.get("max_offset"),
        drift=choice(DriftMode, drift, "--drift") if drift else None,
        align=align_mode(opts),
        n_to_align=int(opts.get("n_to_align", -1)),
        pose_relation=choice(PoseRelation, relation, "--pose_relation") if relation else None,
        change_unit=choice(ApeUnit, unit, "--change_unit") if unit else None,
        window=TimeWindow(opts.get("t_start"), opts.get("t_end"), opts.get("downsample")),
    )
