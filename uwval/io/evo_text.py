"""evo's text inputs besides TUM: ``--format kitti`` and ``--format euroc`` (one dispatch).

``kitti``: both files are KITTI pose files (:mod:`uwval.io.kitti`); they have no stamps, so
they must hold the same number of poses (evo refuses otherwise too). ``euroc``: as
``evo_ape euroc GT.csv EST.txt``, a file with a TUM suffix (.txt / .tum) is TUM text and any
other is an EuRoC ground-truth CSV (:mod:`uwval.io.euroc`).
"""

from __future__ import annotations

from pathlib import Path

from uwval.errors import AlignmentError, ConfigError
from uwval.posestream import PoseStream

EVO_TEXT_FORMATS = ("kitti", "euroc")


def read_evo_text(path: str | Path, fmt: str, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """One trajectory file in evo's ``kitti`` or ``euroc`` layout (see the module doc)."""
    if fmt == "kitti":
        from uwval.io.kitti import read_kitti

        return read_kitti(path, frame=frame, topic=topic)
    if fmt == "euroc":
        from uwval.io.tum import TUM_SUFFIXES, read_tum

        if Path(path).suffix.lower() in TUM_SUFFIXES:
            return read_tum(path, frame=frame, topic=topic)
        from uwval.io.euroc import read_euroc

        return read_euroc(path, frame=frame, topic=topic)
    raise ConfigError(f"--format {fmt!r}: not one of {', '.join(EVO_TEXT_FORMATS)}")


def read_evo_pair(
    path_a: str | Path, path_b: str | Path, fmt: str, *, frame_b: str = "enu"
) -> tuple[PoseStream, PoseStream]:
    """The reference and the other trajectory; KITTI files must have equal pose counts."""
    a = read_evo_text(path_a, fmt)
    b = read_evo_text(path_b, fmt, frame=frame_b)
    if fmt == "kitti" and len(a) != len(b):
        raise AlignmentError(
            f"KITTI files pair poses by line: {path_a} has {len(a)} poses, {path_b} {len(b)}"
        )
    return a, b
