"""``uwval rpe REF EST``: relative pose error with evo_rpe's options (and evo's spellings).

A thin layer over :func:`uwval.comparison.rpe.rpe`; inputs are read as ``uwval compare`` reads
them (:func:`uwval.comparison.logs.read_pose_stream`): TUM text, KITTI, EuRoC, or one topic
of a log each (or two topics of one log).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from uwval.cli import app
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


def _align_mode(align: bool, correct_scale: bool, align_origin: bool) -> str:
    """evo's flags -> one mode: -a se3, -as sim3, -s scale only, --align_origin origin."""
    if align_origin and (align or correct_scale):
        raise ConfigError("--align-origin cannot be combined with -a / -s (as in evo_rpe)")
    if align_origin:
        return "origin"
    if align:
        return "sim3" if correct_scale else "se3"
    return "scale" if correct_scale else "none"


@app.command("rpe")
def rpe_command(
    ref: Annotated[Path, typer.Argument(help="Reference file, or a log holding both topics")],
    est: Annotated[Path | None, typer.Argument(help="Estimate file (omit: topics of REF)")] = None,
    ref_topic: Annotated[
        str | None, typer.Option("--ref-topic", "--gazebo-topic", help="Reference topic")
    ] = None,
    est_topic: Annotated[
        str | None, typer.Option("--est-topic", "--unity-topic", help="Estimate topic")
    ] = None,
    fmt: Annotated[
        str | None,
        typer.Option("--format", help="tum, kitti, euroc or a log format (default: by suffix)"),
    ] = None,
    frame: Annotated[
        str | None, typer.Option(help="Convention of the estimate (default: from the log; enu)")
    ] = None,
    relation: Annotated[
        str,
        typer.Option(
            "--pose-relation",
            "--pose_relation",
            "-r",
            help="trans_part, rot_part, full, angle_deg, angle_rad, point_distance, "
            "point_distance_error_ratio",
        ),
    ] = "trans_part",
    delta: Annotated[float, typer.Option("--delta", "-d", help="Delta between poses")] = 1.0,
    delta_unit: Annotated[
        str,
        typer.Option(
            "--delta-unit", "--delta_unit", "-u", help="f (frames), m (metres), d (deg), r (rad)"
        ),
    ] = "f",
    delta_tol: Annotated[
        float,
        typer.Option(
            "--delta-tol", "--delta_tol", "-t", help="Relative delta tolerance (all pairs)"
        ),
    ] = 0.1,
    all_pairs: Annotated[
        bool, typer.Option("--all-pairs", "--all_pairs", help="All pairs, not consecutive ones")
    ] = False,
    pairs_from_reference: Annotated[
        bool,
        typer.Option(
            "--pairs-from-reference",
            "--pairs_from_reference",
            help="Choose the pairs on the reference (default: on the estimate, as evo)",
        ),
    ] = False,
    align: Annotated[
        bool, typer.Option("--align", "-a", help="SE(3) Umeyama alignment (with -s: Sim(3))")
    ] = False,
    correct_scale: Annotated[
        bool, typer.Option("--correct-scale", "--correct_scale", "-s", help="Correct the scale")
    ] = False,
    align_origin: Annotated[
        bool,
        typer.Option("--align-origin", "--align_origin", help="Align the first poses"),
    ] = False,
    n_to_align: Annotated[
        int,
        typer.Option("--n-to-align", "--n_to_align", help="Poses used to align (-1: all)"),
    ] = -1,
    sync: Annotated[
        str, typer.Option(help="nearest (evo's association; KITTI files: by index)")
    ] = "nearest",
    max_diff: Annotated[
        float,
        typer.Option("--max-diff", "--t-max-diff", "--t_max_diff", help="Max stamp difference (s)"),
    ] = 0.01,
    t_offset: Annotated[
        float,
        typer.Option(
            "--t-offset", "--t_offset", "--offset", help="Added to the estimate's stamps (s)"
        ),
    ] = 0.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON result")] = False,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Also write the JSON result here")
    ] = None,
) -> None:
    """Relative pose error as evo_rpe computes it (same pairs, relations, alignment, stats)."""
    from uwval.comparison.logs import read_pose_stream
    from uwval.comparison.rpe import rpe

    mode = _align_mode(align, correct_scale, align_origin)
    if est is None:
        if not (ref_topic and est_topic):
            raise ConfigError(f"{ref}: give EST, or both --ref-topic and --est-topic of this log")
        from uwval.io import read_streams

        streams = read_streams(ref, [ref_topic, est_topic])
        a, b = streams[ref_topic], streams[est_topic]
    else:
        a = read_pose_stream(ref, ref_topic, fmt=fmt)
        b = read_pose_stream(est, est_topic, fmt=fmt, frame=frame)
    if frame not in (None, "auto"):
        b = b.with_(frame=frame)
    if fmt == "kitti":
        sync = "none"  # no stamps: evo pairs KITTI poses by index
    res = rpe(
        a,
        b,
        relation=relation,
        delta=delta,
        delta_unit=delta_unit,
        delta_tol=delta_tol,
        all_pairs=all_pairs,
        pairs_from_reference=pairs_from_reference,
        align=mode,
        n_to_align=n_to_align,
        sync=sync,
        max_diff=max_diff,
        offset=t_offset,
    )
    doc = res.to_json()
    doc["sources"] = [str(ref)] + ([str(est)] if est is not None else [])
    text = json.dumps(doc, indent=1, allow_nan=False)
    if output is not None:
        output.write_text(text + "\n")
    if as_json:
        sys.stdout.write(text + "\n")
        return
    from uwval.comparison.rpe import DELTA_UNITS

    title = (
        f"RPE w.r.t. {_RELATION_NAMES[res.relation]} ({res.unit})\n"
        f"for delta = {res.delta:g} ({DELTA_UNITS[res.delta_unit]}) using "
        f"{'all' if res.all_pairs else 'consecutive'} pairs\n({_ALIGN_TITLES[mode]})"
    )
    lines = [
        title,
        f"pairs {res.n_pairs} of {res.n_poses} matched poses; sync {res.sync['method']}",
    ]
    lines += [
        f"{k:>8}  {res.stats[k]:.6f}"
        for k in ("max", "mean", "median", "min", "rmse", "sse", "std")
    ]
    lines += [f"warning: {w}" for w in res.warnings]
    sys.stdout.write("\n".join(lines) + "\n")
