"""Read pose streams from logs: the entry point that every command uses.

``read_stream(path, topic)`` returns a :class:`PoseStream`; ``read_streams`` reads several
topics in one pass; ``list_topics(path)`` lists what a log holds. The format is chosen from
the path: ``.mcap``, ``.bag`` (ROS 1), rosbag2 directories (sqlite3 / MCAP), ``.db3``,
``.csv`` (Unity exports, see :mod:`uwval.io.csv_io`) and TUM ``.txt`` / ``.tum``.

Stamps are header stamps (``time="header"``, the default) or the log's receive times
(``time="log"``; always the case for ``geometry_msgs/Pose``, which has no header).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError, PoseStreamError
from uwval.frames import CONVENTIONS
from uwval.io.containers import scan_log
from uwval.io.decode import TF_TYPES, decode_poses, decode_tf
from uwval.io.fastdecode import Decoded
from uwval.io.formats import TEXT_KINDS, log_kind
from uwval.io.names import APPLIED_SUFFIX, split_child, topics_to_scan
from uwval.io.raw import RawLog, RawTopic, TopicInfo, norm_topic
from uwval.posestream import PoseStream
from uwval.rotations import quat_multiply, rotate_vectors

__all__ = ["TopicInfo", "list_topics", "read_stream", "read_streams"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def _check_path(path: Path) -> None:
    if not path.exists():
        raise LogReadError(f"{path}: no such file or directory")
    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError(f"{path}: file is empty (0 bytes)")


def list_topics(path: str | Path) -> list[TopicInfo]:
    """Topics of a ROS log (MCAP, ROS 1 bag, rosbag2, .db3): name, type, count, span (ns)."""
    p = Path(path)
    _check_path(p)
    if log_kind(p) in TEXT_KINDS:
        s = read_stream(p, "")
        return [
            TopicInfo(s.topic or p.stem, "text/" + log_kind(p), len(s), int(s.t[0]), int(s.t[-1]))
        ]
    log = scan_log(p, [], times_only=True)
    log.warn_lost()
    return sorted(log.topics, key=lambda i: i.name)


def topic_times(path: str | Path) -> tuple[list[TopicInfo], dict[str, I64]]:
    """Topics and every message's log time (ns) per topic, for ``uwval inspect``."""
    p = Path(path)
    _check_path(p)
    log = scan_log(p, None, times_only=True)
    log.warn_lost()
    return sorted(log.topics, key=lambda i: i.name), {
        n: np.sort(r.log_time) for n, r in log.raw.items()
    }


def read_stream(
    path: str | Path,
    topic: str,
    *,
    frame: str | None = None,
    child_frame: str | None = None,
    parent_frame: str | None = None,
    **opts: Any,
) -> PoseStream:
    """Read one pose topic of a log into a PoseStream.

    Args:
        path: log file or rosbag2 directory; CSV and TUM text files too (``topic`` ignored).
        topic: topic name, with or without the leading slash.
        frame: pose convention of the result; by default the header frame_id when it names a
            uwval convention (``unity-flu``, ``unity-enu``, ``ned``, ``enu``), else ``enu``.
        child_frame / parent_frame: for TFMessage topics (``/tf``), the transform to extract;
            for Odometry / TransformStamped topics, filter on child / header frame.
        opts: ``time="header"|"log"`` (which stamp becomes ``t``); ``tf_static``: chain
            static transforms from ``/tf_static`` up to ``parent_frame`` and below
            ``child_frame`` (True: require it; None: whenever the log has ``/tf_static``, as
            ``uwval compare`` reads; False, the default: never); CSV options are passed to
            :func:`uwval.io.csv_io.read_csv`.

    The companion ``<topic>/applied_stamp`` topic, when present, fills ``applied_stamp``.
    Raises :class:`LogReadError` naming the file and the cause (missing topic: lists those
    that exist).
    """
    p = Path(path)
    _check_path(p)
    kind = log_kind(p)
    if kind == "csv":
        from uwval.io.csv_io import read_csv

        return read_csv(p, frame=frame, **opts)
    if kind == "tum":
        from uwval.io.tum import read_tum

        return read_tum(p, frame=frame or "enu", topic=topic)
    return read_streams(
        p, [topic], frame=frame, child_frame=child_frame, parent_frame=parent_frame, **opts
    )[topic]


def read_streams(
    path: str | Path,
    topics: Sequence[str],
    *,
    frame: str | None = None,
    child_frame: str | None = None,
    parent_frame: str | None = None,
    **opts: Any,
) -> dict[str, PoseStream]:
    """Read several topics in one pass over the log; keys are the names as given.

    ``skip_missing=True`` leaves out topics the log does not have (instead of raising), so
    a caller can ask for every candidate topic in the same single pass.
    """
    p = Path(path)
    _check_path(p)
    time_src = str(opts.pop("time", "header"))
    tf_static_opt = opts.pop("tf_static", False)
    fast = bool(opts.pop("fast", True))
    skip_missing = bool(opts.pop("skip_missing", False))
    if opts:
        raise LogReadError(f"{p}: unknown read option(s): {', '.join(sorted(opts))}")
    if time_src not in ("header", "log"):
        raise LogReadError(f"{p}: time must be 'header' or 'log', not {time_src!r}")
    scan = topics_to_scan(topics)
    wants_child = child_frame is not None or any(split_child(t)[1] for t in topics)
    if tf_static_opt or (tf_static_opt is None and wants_child):
        scan.add("/tf_static")  # the child asked for may hang under a static transform
    log = scan_log(p, sorted(scan))
    log.warn_lost()
    static_raw = log.raw.get("/tf_static")
    tf_static = bool(tf_static_opt) or (
        tf_static_opt is None and static_raw is not None and len(static_raw) > 0
    )
    jobs: list[tuple[str, RawTopic, str | None]] = []
    for t in topics:
        bare, topic_child = split_child(t)
        name = norm_topic(bare)
        raw = log.raw.get(name)
        if raw is None:
            if skip_missing and not any(i.name == name for i in log.topics):
                continue
            raise LogReadError(_missing(p, t, log))
        if len(raw) == 0:
            raise LogReadError(f"{p}: topic {name!r} ({raw.msgtype}) has no messages")
        if topic_child and not raw.msgtype.endswith(_CHILD_TYPES) and raw.msgtype not in TF_TYPES:
            raise LogReadError(
                f"{p}: topic {t!r}: {name} is {raw.msgtype}, which has no child frame; "
                "'#CHILD' picks a child of a TF, Odometry or TransformStamped topic"
            )
        jobs.append((t, raw, topic_child))

    def stream(job: tuple[str, RawTopic, str | None]) -> PoseStream:
        _asked, raw, topic_child = job
        try:
            s = _to_stream(
                p,
                raw,
                log,
                frame=frame,
                child=topic_child or child_frame,
                parent=parent_frame,
                time_src=time_src,
                tf_static=tf_static,
                fast=fast,
            )
        except PoseStreamError as exc:
            raise LogReadError(f"{p}: topic {raw.name!r}: {exc}") from exc
        # the stream is named as asked: /tf#turtle1
        return s.with_(topic=f"{raw.name}#{topic_child}") if topic_child else s

    big = sum(len(raw) for _, raw, _ in jobs) >= PARALLEL_DECODE_MIN
    if len(jobs) > 1 and big and (os.cpu_count() or 1) > 1:
        # Topics decode independently and numpy releases the GIL in their array work: two
        # threads on two cores. Results and the first error are taken in the order asked.
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(2, thread_name_prefix="uwval-decode") as pool:
            done = [pool.submit(stream, job) for job in jobs]
            return {job[0]: d.result() for job, d in zip(jobs, done, strict=True)}
    return {job[0]: stream(job) for job in jobs}


#: Messages (all selected topics together) from which they are decoded on two threads.
PARALLEL_DECODE_MIN = 100_000


#: Message types (name endings) with a child_frame_id, besides TF messages.
_CHILD_TYPES = ("/Odometry", "/TransformStamped")


def _read_tf(path: str | Path, topic: str, *also: str) -> tuple[RawLog, str, Decoded]:
    """The log (``topic``'s TFMessage topic and the topics ``also``), that topic's name and
    its decoded transforms; a missing topic or one of another type is refused by name."""
    p = Path(path)
    _check_path(p)
    name = norm_topic(split_child(topic)[0])
    log = scan_log(p, sorted({name, *also}))
    raw = log.raw.get(name)
    if raw is None:
        raise LogReadError(_missing(p, topic, log))
    if raw.msgtype not in TF_TYPES:
        raise LogReadError(f"{p}: topic {name!r} is {raw.msgtype}, not a TF topic")
    dec, _bad = decode_tf(raw, errors="drop")
    return log, name, dec


def tf_pairs(path: str | Path, topic: str) -> list[tuple[str, str, int]]:
    """(parent, child, number of transforms) of every pair a TFMessage ``topic`` carries."""
    _log, _name, dec = _read_tf(path, topic)
    pairs: dict[tuple[str, str], int] = {}
    if len(dec.stamp):
        codes, counts = np.unique(
            np.stack([dec.frame_code, dec.child_code], axis=1), axis=0, return_counts=True
        )
        for (a, b), n in zip(codes, counts, strict=True):
            key = (dec.names[int(a)], dec.names[int(b)])
            pairs[key] = pairs.get(key, 0) + int(n)
    return [(a, b, n) for (a, b), n in sorted(pairs.items())]


def tf_chains(path: str | Path, topic: str) -> list[tuple[str, tuple[str, ...], int]]:
    """What ``TOPIC#CHILD`` can name on a TFMessage ``topic``: per child frame, the chain of
    frames from the dynamic parent down to it, and how many of its links are static
    (from ``/tf_static``). Dynamic children have chains of two frames and no static link."""
    log, name, dec = _read_tf(path, topic, "/tf_static")
    edges = _edges(dec)
    parent_of = {child: parent for parent, child in edges}
    static: dict[str, str] = {}  # child -> parent
    st = log.raw.get("/tf_static")
    if st is not None and len(st) and name != "/tf_static":
        sd, _bad_static = decode_tf(st, errors="drop")
        static = {child: parent for parent, child in _edges(sd)}
    out: list[tuple[str, tuple[str, ...], int]] = [(c, (a, c), 0) for a, c in edges]
    for child in sorted(set(static) - set(parent_of)):
        chain, cur = [child], child
        while cur not in parent_of and cur in static and len(chain) <= len(static):
            cur = static[cur]
            chain.insert(0, cur)
        if cur in parent_of:  # reaches a dynamically published frame
            out.append((child, (parent_of[cur], *chain), len(chain) - 1))
    return out


def _missing(p: Path, topic: str, log: RawLog) -> str:
    names = ", ".join(
        f"{i.name} ({i.type}, {i.count})" for i in sorted(log.topics, key=lambda i: i.name)
    )
    # a cut-off log may have lost the topic with the bytes: say so in the error itself
    cut = (
        f" (the log is truncated: {log.lost_bytes} bytes at the end were lost)"
        if log.lost_bytes
        else ""
    )
    if not log.topics:
        return f"{p}: no topic {topic!r}: the log has no topics (no messages){cut}"
    return f"{p}: no topic {topic!r}; topics in this log: {names}{cut}"


def _to_stream(
    p: Path,
    raw: RawTopic,
    log: RawLog,
    *,
    frame: str | None,
    child: str | None,
    parent: str | None,
    time_src: str,
    tf_static: bool,
    fast: bool,
) -> PoseStream:
    dropped = dict(raw.dropped)
    if raw.msgtype in TF_TYPES:
        stamps, pose, frame_id, bad = _tf_pose(p, raw, log, child, parent, tf_static)
        position, orientation = pose[:, :3], pose[:, 3:]
        if bad:
            dropped["decode_error"] = dropped.get("decode_error", 0) + bad
        log_time = None
    else:
        dec = decode_poses(raw, fast=fast, errors="drop")
        if raw.msgtype.endswith("/Header"):
            raise LogReadError(f"{p}: topic {raw.name!r} is std_msgs/Header: it has no pose")
        keep = dec.handled.copy()
        if not keep.all():
            dropped["decode_error"] = dropped.get("decode_error", 0) + int((~keep).sum())
        if child is not None and (dec.child_code >= 0).any():
            keep &= _code_is(dec, dec.child_code, child)
        if parent is not None and (dec.frame_code >= 0).any():
            keep &= _code_is(dec, dec.frame_code, parent)
        if not keep.any():
            raise LogReadError(
                _no_pair(p, raw.name, dec, dec.frame_code, dec.child_code, parent, child)
            )
        if keep.all():  # the usual case: no copies (a pose topic's arrays are 80 B/msg)
            stamps, log_time, kept = dec.stamp, raw.log_time, dec.frame_code
            position, orientation = dec.position, dec.orientation
        else:
            stamps, log_time, kept = dec.stamp[keep], raw.log_time[keep], dec.frame_code[keep]
            position, orientation = dec.position[keep], dec.orientation[keep]
        if time_src == "log" or (stamps < 0).all():
            stamps = log_time
        # one frame_id on the whole topic is the usual case: skip the sort of np.unique
        codes = kept[:1] if kept.size and bool((kept == kept[0]).all()) else np.unique(kept)
        frame_id = [dec.names[int(c)] for c in codes if c >= 0]
    if frame is None:
        frame = next((f for f in frame_id if f in CONVENTIONS), "enu")
    applied = None
    applied_warning = ""
    comp = log.raw.get(raw.name + APPLIED_SUFFIX)
    if comp is not None and len(comp) and log_time is not None:
        applied, applied_warning = _applied(p, comp, log_time)
    s = PoseStream.from_arrays(
        stamps,
        position,
        orientation,
        frame=frame,
        topic=raw.name,
        source=str(p),
        applied_stamp=applied,
    )
    warns = log.all_warnings()
    if applied_warning:
        warns.append(applied_warning)
    if s.repairs.get("duplicates_dropped"):
        dropped["duplicate_stamp"] = s.repairs["duplicates_dropped"]
    if s.repairs.get("sorted"):
        warns.append(
            f"{p} [{raw.name}]: stamps are not in order ({s.repairs['sorted']} step(s) back "
            "in time); the samples were sorted by stamp"
        )
    return s.with_(dropped=dropped, warnings=tuple(warns), frame_ids=tuple(frame_id))


def _applied(p: Path, comp: RawTopic, log_time: I64) -> tuple[I64 | None, str]:
    """Applied Gazebo stamps for each pose, matched on the log (receive) time; and a warning
    when they cannot be matched one to one (then no stamps: latency is not measured)."""
    try:
        hdr = decode_poses(comp, errors="drop")
    except LogReadError as exc:
        # not one stamp decodes: the poses are still read, without latency (as when none
        # can be matched), and the warning says why
        return None, f"{p} [{comp.name}]: no applied stamp could be decoded: {exc}"
    ok = hdr.handled
    if (
        comp.log_time.shape == log_time.shape
        and bool(ok.all())
        and bool(np.all(log_time[1:] > log_time[:-1]))
        and np.array_equal(comp.log_time, log_time)
    ):
        # the usual log: each pose's applied stamp logged at the pose's own (distinct) time,
        # in the same order: _match_applied would pair message i with message i
        return hdr.stamp, ""
    return _match_applied(p, comp.name, comp.log_time, hdr.stamp, ok, log_time)


def _match_applied(
    p: Path, name: str, comp_time: I64, comp_stamp: I64, ok: NDArray[np.bool_], log_time: I64
) -> tuple[I64 | None, str]:
    """:func:`_applied`'s matching: each pose takes the decoded applied stamp logged at its
    log time (the first such, in log-time order)."""
    order = np.argsort(comp_time[ok], kind="stable")
    ct = comp_time[ok][order]
    cs = comp_stamp[ok][order]
    if ct.size == 0:
        return None, f"{p} [{name}]: no applied stamp could be decoded"
    idx = np.minimum(np.searchsorted(ct, log_time), len(ct) - 1)
    hit = ct[idx] == log_time
    if hit.all():
        return cs[idx], ""
    if not hit.any() and len(ct) == len(log_time) and ok.all():
        # a recorder that logged the two topics at different receive times: pair by rank
        return cs[np.argsort(np.argsort(log_time, kind="stable"), kind="stable")], ""
    return None, (
        f"{p} [{name}]: {int((~hit).sum())} of {len(log_time)} poses have no applied "
        "stamp logged at the same time; applied stamps (latency) not used"
    )


def _code_is(dec: Decoded, codes: I64, name: str) -> NDArray[np.bool_]:
    want = [i for i, n in enumerate(dec.names) if n.strip("/") == name.strip("/")]
    return np.isin(codes, want)


def _no_pair(
    p: Path,
    topic: str,
    dec: Decoded,
    parents: I64,
    children: I64,
    parent: str | None,
    child: str | None,
) -> str:
    pairs = sorted(
        {
            (dec.names[int(a)] if a >= 0 else "", dec.names[int(b)] if b >= 0 else "")
            for a, b in zip(parents, children, strict=True)
        }
    )
    listed = ", ".join(f"{a}->{b}" for a, b in pairs[:30])
    return (
        f"{p}: topic {topic!r} has no transform {parent or '*'}->{child or '*'}; "
        f"parent->child pairs present: {listed}"
    )


# ---------------------------------------------------------------- tf
def _edges(dec: Decoded) -> list[tuple[str, str]]:
    return sorted(
        {
            (dec.names[int(a)], dec.names[int(b)])
            for a, b in zip(dec.frame_code, dec.child_code, strict=True)
        }
    )


def _compose(a_pose: F64, b_pose: F64) -> F64:
    """T_a * T_b for (N, 7) or (7,) poses (position, quaternion xyzw); broadcasts."""
    a = np.atleast_2d(a_pose)
    b = np.atleast_2d(b_pose)
    n = max(len(a), len(b))
    a = np.broadcast_to(a, (n, 7))
    b = np.broadcast_to(b, (n, 7))
    q = quat_multiply(a[:, 3:], b[:, 3:])
    t = a[:, :3] + rotate_vectors(a[:, 3:], b[:, :3])
    return np.concatenate([t, q], axis=1)


def _tf_pose(
    p: Path, raw: RawTopic, log: RawLog, child: str | None, parent: str | None, tf_static: bool
) -> tuple[I64, F64, list[str], int]:
    """Pose of ``child`` in ``parent`` from a TFMessage topic (+ /tf_static when asked), and
    the number of messages that could not be decoded."""
    dec, bad = decode_tf(raw, errors="drop")
    if len(dec.stamp) == 0:
        raise LogReadError(f"{p}: topic {raw.name!r} holds no transforms")
    edges = _edges(dec)
    static: dict[str, tuple[str, F64]] = {}  # child -> (parent, pose)
    if tf_static:
        st = log.raw.get("/tf_static")
        if st is None or len(st) == 0:
            raise LogReadError(f"{p}: tf_static=True but the log has no /tf_static messages")
        sd, _bad_static = decode_tf(st)
        for a, b, pose in zip(sd.frame_code, sd.child_code, sd.pose, strict=True):
            static[sd.names[int(b)]] = (sd.names[int(a)], pose)
    child_n = child.strip("/") if child else None
    parent_n = parent.strip("/") if parent else None
    if child_n is None:
        kids = sorted({c for _, c in edges if parent_n is None or _ == parent_n})
        if len(kids) != 1:
            raise LogReadError(
                f"{p}: topic {raw.name!r} carries several transforms; choose the child frame "
                f"as {raw.name}#CHILD (parent->child pairs: "
                f"{', '.join(f'{a}->{b}' for a, b in edges)})"
            )
        child_n = kids[0]
    # Walk up from the child through static transforms to a dynamically published frame.
    suffix = np.array([0, 0, 0, 0, 0, 0, 1.0])
    cur = child_n
    dyn_children = {c for _, c in edges}
    while cur not in dyn_children and cur in static:
        par, pose = static[cur]
        suffix = _compose(pose, suffix)[0]
        cur = par
    cands = [(a, b) for a, b in edges if b == cur]
    if parent_n is not None and not tf_static:
        cands = [(a, b) for a, b in cands if a == parent_n]
    if not cands:
        hint = (
            ""
            if tf_static or parent_n is None
            else (" (pass tf_static=True to chain static transforms from /tf_static)")
        )
        raise LogReadError(
            _no_pair(p, raw.name, dec, dec.frame_code, dec.child_code, parent, child) + hint
        )
    dyn_parent, dyn_child = cands[0]
    codes_p = [i for i, n in enumerate(dec.names) if n == dyn_parent]
    codes_c = [i for i, n in enumerate(dec.names) if n == dyn_child]
    rows = np.isin(dec.frame_code, codes_p) & np.isin(dec.child_code, codes_c)
    pose = dec.pose[rows]
    stamps = dec.stamp[rows]
    prefix = np.array([0, 0, 0, 0, 0, 0, 1.0])
    top = dyn_parent
    if parent_n is not None and parent_n != dyn_parent:
        while top != parent_n and top in static:
            par, sp = static[top]
            prefix = _compose(sp, prefix)[0]
            top = par
        if top != parent_n:
            raise LogReadError(
                f"{p}: no chain from {parent_n!r} to {child_n!r}: {raw.name} has "
                f"{dyn_parent}->{dyn_child}"
                + (
                    f", static chain reaches {top!r}"
                    if tf_static
                    else "; pass tf_static=True to chain /tf_static transforms"
                )
            )
    if child_n != dyn_child or top != dyn_parent:
        pose = _compose(_compose(prefix, pose), suffix)
    return stamps, pose, [top], bad
