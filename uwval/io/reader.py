"""Read pose streams from logs: the entry point that every command uses.

``read_stream(path, topic)`` returns a :class:`PoseStream`; ``list_topics(path)`` lists what a
log holds. The format is chosen from the path (MCAP here; more formats plug in by suffix).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uwval.errors import LogReadError
from uwval.frames import CONVENTIONS
from uwval.io.ros import APPLIED_SUFFIX, normalize_type_name
from uwval.posestream import PoseStream


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a log: name, ROS type (pkg/msg/Type), message count, span (ns)."""

    name: str
    type: str
    count: int
    start_ns: int
    end_ns: int


def _check_file(path: Path) -> None:
    if not path.exists():
        raise LogReadError(f"{path}: no such file or directory")
    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError(f"{path}: file is empty (0 bytes)")


def list_topics(path: str | Path) -> list[TopicInfo]:
    """Topics of an MCAP log, from its summary."""
    p = Path(path)
    _check_file(p)
    from mcap.reader import make_reader

    with open(p, "rb") as fh:
        try:
            summary = make_reader(fh).get_summary()
        except Exception as exc:
            raise LogReadError(f"{p}: not a readable MCAP file: {exc}") from exc
    if summary is None:
        raise LogReadError(f"{p}: MCAP has no summary section")
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    out = []
    for cid, ch in summary.channels.items():
        schema = summary.schemas.get(ch.schema_id)
        typ = normalize_type_name(schema.name) if schema else ""
        start = summary.statistics.message_start_time if summary.statistics else 0
        end = summary.statistics.message_end_time if summary.statistics else 0
        out.append(TopicInfo(ch.topic, typ, int(counts.get(cid, 0)), int(start), int(end)))
    return out


def _norm_topic(name: str) -> str:
    return "/" + name.strip("/")


def read_stream(path: str | Path, topic: str, *, frame: str | None = None) -> PoseStream:
    """Read one PoseStamped topic of an MCAP log into a PoseStream.

    ``frame`` overrides the convention; by default it is read from the header frame_id when
    that names a uwval convention (``unity-flu``, ``unity-enu``, ``ned``), else ``enu``.
    The companion ``<topic>/applied_stamp`` topic, when present, fills ``applied_stamp``.
    """
    p = Path(path)
    _check_file(p)
    from mcap.reader import make_reader

    ts = _typestore()
    want = _norm_topic(topic)
    tt, pp, qq, frame_ids = [], [], [], set()
    applied: list[int] = []
    found = False
    with open(p, "rb") as fh:
        reader = make_reader(fh)
        try:
            for schema, channel, message in reader.iter_messages():
                name = _norm_topic(channel.topic)
                if name == want:
                    found = True
                    msg = ts.deserialize_cdr(message.data, normalize_type_name(schema.name))
                    h = msg.header
                    tt.append(h.stamp.sec * 1_000_000_000 + h.stamp.nanosec)
                    po = msg.pose.position
                    qo = msg.pose.orientation
                    pp.append((po.x, po.y, po.z))
                    qq.append((qo.x, qo.y, qo.z, qo.w))
                    frame_ids.add(h.frame_id)
                elif name == want + APPLIED_SUFFIX:
                    msg = ts.deserialize_cdr(message.data, normalize_type_name(schema.name))
                    applied.append(msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec)
        except Exception as exc:
            raise LogReadError(f"{p}: cannot read MCAP: {exc}") from exc
    if not found:
        names = ", ".join(sorted(t.name for t in list_topics(p)))
        raise LogReadError(f"{p}: no topic {topic!r}; topics: {names}")
    if frame is None:
        frame = next((f for f in frame_ids if f in CONVENTIONS), "enu")
    stamps = np.asarray(applied, dtype=np.int64) if len(applied) == len(tt) else None
    return PoseStream.from_arrays(
        np.asarray(tt, dtype=np.int64), np.asarray(pp), np.asarray(qq),
        frame=frame, topic=want, source=str(p), applied_stamp=stamps,
    )


def _typestore():  # type: ignore[no-untyped-def]
    from uwval.io.ros import typestore

    return typestore(2)
