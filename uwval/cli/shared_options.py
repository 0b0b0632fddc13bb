"""Options that several commands take, declared once (issue 30: one name and one kind per
option across commands). ``compare``, ``rpe``, ``report``, ``check`` and ``simulate`` put
these very declarations into their option tables, so the flags, kind, default and help of
``--t-max-diff`` or ``--thresholds`` cannot drift apart between commands."""

from __future__ import annotations

from pathlib import Path

from uwval.cli.declare import Opt

FRAME_HELP = (
    "Convention of the second (Unity) stream: unity-flu, unity-enu, ned, enu or auto "
    "(default: from the log's frame_id; enu for trajectory files)"
)

GAZEBO_TOPIC = Opt(
    "gazebo_topic",
    ("--gazebo-topic",),
    str,
    None,
    "Reference topic (a TF child: /tf#CHILD, chained through /tf_static; "
    "`uwval inspect` lists them)",
)
UNITY_TOPIC = Opt(
    "unity_topic", ("--unity-topic",), str, None, "Other (Unity) topic (/tf#CHILD too)"
)
FORMAT = Opt(
    "fmt",
    ("--format",),
    str,
    None,
    "Input format: tum, kitti, euroc, mcap, bag, rosbag2, db3, csv (default: by suffix)",
)
FRAME = Opt("frame", ("--frame",), str, None, FRAME_HELP)
SYNC = Opt(
    "sync",
    ("--sync",),
    str,
    None,
    "nearest (evo's association within --t-max-diff) or interp (lerp+slerp at the "
    "reference stamps). Default: nearest for trajectory files (TUM, KITTI, EuRoC), as "
    "evo_ape; interp for logs",
)
MAX_DIFF = Opt(
    "max_diff",
    ("--t-max-diff", "--t_max_diff", "--max-diff"),
    float,
    0.01,
    "nearest: max stamp difference (s) of evo's association. Given without --sync "
    "(compare, report, check), it means --sync nearest",
)
OFFSET = Opt(
    "offset",
    ("--offset", "--t_offset", "--t-offset"),
    str,
    "0",
    "Clock offset added to the second stream's stamps (s, evo's --t_offset sign), or "
    "'auto' to estimate it (compare, report, check)",
)
ALIGN = Opt(
    "align",
    ("--align",),
    str,
    "none",
    "Alignment: none, se3, sim3 (Umeyama), origin, scale or scale_origin "
    "(evo's flags -a, -as, --align_origin, -s do the same)",
)
EVO_ALIGN = Opt("evo_align", ("-a",), bool, False, "evo's -a: SE(3) Umeyama (-as: Sim(3))")
CONFIG = Opt(
    "config",
    ("--config",),
    Path,
    None,
    "Project file naming pairs, frames and option defaults (default: ./uwval.toml when "
    "present; options given here win)",
)
RESULT_FILE = Opt(
    "output",
    ("-o", "--output"),
    Path,
    None,
    "Write the JSON result to this file (-o is always the JSON result in compare, rpe, "
    "doctor and inspect)",
)
JSON = Opt("as_json", ("--json",), bool, False, "Print the JSON result on stdout")
THRESHOLDS = Opt(
    "thresholds",
    ("--thresholds",),
    str,
    None,
    "Thresholds TOML for the verdict; 'default' = the embedded defaults (report's "
    "default), 'none' = no threshold verdict; else thresholds = ... in uwval.toml",
)
BASELINE = Opt(
    "baseline",
    ("--baseline",),
    str,
    None,
    "Golden results (JSON/CSV) to gate on; 'default' = the embedded baseline",
)
EXECUTOR = Opt(
    "executor", ("--executor",), str, "local", "Where runs go: local (process pool), dask or inline"
)
WORKERS = Opt("workers", ("--workers",), int, None, "Worker processes (default: all cores)")
SCHEDULER = Opt("scheduler", ("--scheduler",), str, None, "Dask scheduler address (tcp://...)")

#: compare's options as ``report`` and ``check`` take them (one log, a pair, a saved result).
COMPARE_SUBSET: tuple[Opt, ...] = (
    GAZEBO_TOPIC,
    UNITY_TOPIC,
    FORMAT,
    FRAME,
    SYNC,
    MAX_DIFF,
    OFFSET,
    ALIGN,
    CONFIG,
)
