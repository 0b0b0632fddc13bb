"""Vectorised decode of fixed-layout pose messages (ROS 2 CDR and ROS 1 serialization).

A topic's payloads sit in one byte buffer at ``offset[i]`` with ``length[i]`` bytes. Messages
whose strings (``frame_id``, ``child_frame_id``) have the same lengths share one byte layout
and are decoded by a handful of numpy gathers. What the layouts do not cover (big-endian CDR, a
length that does not match, an unknown type) is reported as not handled, for
:mod:`uwval.io.decode` to decode with rosbags, the reference. CDR: 4-byte encapsulation header,
fields aligned to their size from its end, strings count their NUL; ROS 1: packed, header with
``seq``. Stamps: sec int32 (ROS 1's uint32 too, as rosbags reads it), nanosec uint32.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]
F64 = NDArray[np.float64]

#: Field list per message type: "header", "string" (a second frame name), or an int n
#: meaning n float64 values. The first 7-double block after the header is the pose
#: (position x y z, orientation x y z w); TransformStamped's Vector3 + Quaternion is the same.
LAYOUTS: dict[str, tuple[str | int, ...]] = {
    "geometry_msgs/msg/PoseStamped": ("header", 7),
    "geometry_msgs/msg/Pose": (7,),
    "geometry_msgs/msg/PoseWithCovarianceStamped": ("header", 7, 36),
    "geometry_msgs/msg/PoseWithCovariance": (7, 36),
    "geometry_msgs/msg/TransformStamped": ("header", "string", 7),
    "geometry_msgs/msg/Transform": (7,),
    "nav_msgs/msg/Odometry": ("header", "string", 7, 36, 6, 36),
    "std_msgs/msg/Header": ("header",),
}


@dataclass
class Decoded:
    """Columns decoded from one topic's messages (row i = message i of the input).

    ``stamp``: header stamps in ns (-1 where the type has no header); ``position`` (N, 3)
    and ``orientation`` (N, 4: quaternion x, y, z, w), NaN where the type has no pose, each
    contiguous (a PoseStream takes them without another copy); ``frame_code`` /
    ``child_code``: indices into ``names`` (-1 where absent); ``handled``: rows decoded here.
    """

    stamp: I64
    position: F64
    orientation: F64
    frame_code: I64
    child_code: I64
    names: list[str]
    handled: NDArray[np.bool_]

    @classmethod
    def empty(cls, n: int) -> Decoded:
        """``n`` rows, none decoded: stamps and codes -1, poses NaN."""
        pos, quat = np.full((n, 3), np.nan), np.full((n, 4), np.nan)
        none = [np.full(n, -1, dtype=np.int64) for _ in range(3)]
        return cls(none[0], pos, quat, none[1], none[2], [], np.zeros(n, dtype=bool))

    @property
    def pose(self) -> F64:
        """(N, 7) position + quaternion: a new array (writes to it change nothing here)."""
        return np.concatenate([self.position, self.orientation], axis=1)

    def set_pose(self, rows: Any, pose: Any) -> None:
        """Write (…, 7) position + quaternion values into ``rows``."""
        p = np.asarray(pose, dtype=np.float64)
        self.position[rows] = p[..., :3]
        self.orientation[rows] = p[..., 3:]

    def code(self, name: str) -> int:
        """Index of ``name`` in ``names`` (appended when new)."""
        try:
            return self.names.index(name)
        except ValueError:
            self.names.append(name)
            return len(self.names) - 1


def gather(buf: U8, starts: I64, width: int) -> U8:
    """(N, width) copies of ``buf[starts[i] : starts[i] + width]``: one fancy index of a view
    whose item i is ``V<width>`` from byte i (2-3x faster than rows of a 2-D window)."""
    n = starts.shape[0]
    if n == 0 or width == 0:
        return np.zeros((n, width), dtype=np.uint8)
    if int(starts.min()) < 0 or int(starts.max()) + width > buf.shape[0]:
        raise ValueError("gather: a row reaches outside the buffer")
    if buf.ndim == 1 and buf.flags.c_contiguous and buf.dtype == np.uint8:
        items = np.ndarray((buf.shape[0] - width + 1,), f"V{width}", buf, strides=(1,))
        return items[starts].view(np.uint8).reshape(n, width)
    return np.lib.stride_tricks.sliding_window_view(buf, width)[starts]


class _Bytes:
    """Byte access to a topic's messages: ``at(rows, k, m)`` is the (len(rows), m) bytes at
    offset ``k`` of messages ``rows`` (sorted, unique: subsets of all messages).

    When every message has the same length ``w`` and they tile ``buf`` in order (a pose
    topic read by the container readers: offset i * w), the messages are the rows of one
    (n, w) view, and a column range of all of them is a strided view, no index arrays."""

    def __init__(self, buf: U8, offset: I64, length: I64) -> None:
        self.buf, self.offset, self.length = buf, offset, length
        n = offset.shape[0]
        self.n = n
        self.rows2d: U8 | None = None
        w = int(length[0]) if n else 0
        tiled = n > 1 and w > 0 and buf.ndim == 1 and buf.shape[0] == n * w
        if tiled and bool((length == w).all()) and np.array_equal(offset, np.arange(0, n * w, w)):
            self.rows2d = buf.reshape(n, w)
        self.width = w if self.rows2d is not None else 0

    def at(self, rows: I64, k: int, m: int) -> U8:
        r = self.rows2d
        if r is not None and k >= 0 and k + m <= self.width:
            return r[:, k : k + m] if rows.shape[0] == self.n else r[rows, k : k + m]
        return gather(self.buf, self.offset[rows] + k, m)

    def at_least(self, rows: I64, size: int) -> I64:
        """The rows whose message holds at least ``size`` bytes."""
        if self.rows2d is not None:
            return rows if self.width >= size else rows[:0]
        return rows[self.length[rows] >= size]


def _align(pos: int, size: int, cdr: bool) -> int:
    return (pos + size - 1) // size * size if cdr else pos


@dataclass
class _Leaf:
    rows: I64  # message indices of this layout group
    stamp_at: int  # offset (from payload start) of header.stamp.sec, or -1
    frame_at: int  # offset of the frame_id bytes, or -1
    frame_len: int  # number of name bytes (without NUL)
    child_at: int
    child_len: int
    pose_at: int  # offset of the 7 pose doubles, or -1


def _walk(fields: tuple[str | int, ...], k: int, rows: I64, pos: int, leaf: _Leaf, acc: _Bytes,
          cdr: bool, out: list[_Leaf]) -> None:  # fmt: skip
    """Follow the field list from field ``k`` at payload offset ``pos`` (shared by ``rows``).

    Strings split the group by their length; every leaf is checked against the real payload
    length, and rows that do not match are left out (they go to the per-message fallback).
    """
    base = 4 if cdr else 0  # CDR alignment origin: after the encapsulation header
    while k < len(fields):
        f = fields[k]
        if f == "header" or f == "string":
            if f == "header":
                if not cdr:
                    pos += 4  # ROS 1 Header.seq
                pos = _align(pos, 4, cdr)
                stamp_at = base + pos
                pos += 8
            pos = _align(pos, 4, cdr)
            rows = acc.at_least(rows, base + pos + 4)  # too short for the length field
            if rows.size == 0:
                return
            slen = acc.at(rows, base + pos, 4).view("<u4").reshape(-1).astype(np.int64)
            pos += 4
            lens_here = [int(slen[0])] if int(slen.min()) == int(slen.max()) else np.unique(slen)
            for s in lens_here:
                sub = rows if len(lens_here) == 1 else rows[slen == s]
                nbytes = int(s) - (1 if cdr else 0)
                if nbytes < 0 or int(s) > 1 << 20:
                    continue
                sub = acc.at_least(sub, base + pos + int(s))
                if cdr and sub.size:
                    # rosbags rejects a CDR string without its NUL: so does the fast path
                    nul = acc.at(sub, base + pos + nbytes, 1)[:, 0] == 0
                    sub = sub if nul.all() else sub[nul]
                if sub.size == 0:
                    continue
                nxt = _Leaf(**leaf.__dict__)
                nxt.rows = sub
                if f == "header":
                    nxt.stamp_at, nxt.frame_at, nxt.frame_len = stamp_at, base + pos, nbytes
                else:
                    nxt.child_at, nxt.child_len = base + pos, nbytes
                _walk(fields, k + 1, sub, pos + int(s), nxt, acc, cdr, out)
            return
        n = int(f)
        pos = _align(pos, 8, cdr)
        if leaf.pose_at < 0 and n == 7:
            leaf.pose_at = base + pos
        pos += 8 * n
        k += 1
    # CDR writers may pad the end to a multiple of 4 (never more than 7 bytes); ROS 1: exact.
    end = base + pos
    if acc.rows2d is not None:
        if 0 <= acc.width - end < (8 if cdr else 1):
            leaf.rows = rows
            out.append(leaf)
        return
    extra = acc.length[rows] - end
    ok = (extra >= 0) & (extra < (8 if cdr else 1))
    if ok.any():
        leaf.rows = rows[ok]
        out.append(leaf)


def fast_decode(msgtype: str, encoding: str, buf: U8, offset: I64, length: I64) -> Decoded:
    """Decode what the fixed layouts cover; ``handled`` marks the rows decoded.

    ``encoding`` is ``"cdr"`` (ROS 2) or ``"ros1"``. Values are bit-identical to rosbags'
    per-message decode (the same bytes reinterpreted as little-endian numbers).
    """
    n = offset.shape[0]
    fields = LAYOUTS.get(msgtype)
    if fields is None or n == 0 or encoding not in ("cdr", "ros1"):
        return Decoded.empty(n)
    cdr = encoding == "cdr"
    acc = _Bytes(buf, offset, length)
    dec = Decoded.empty(n)
    rows = np.arange(n, dtype=np.int64)
    if cdr:
        # Only little-endian plain CDR (encapsulation kind 0x0001) has this layout.
        rows = acc.at_least(rows, 4)
        head = acc.at(rows, 0, 2)
        good = (head[:, 0] == 0) & (head[:, 1] == 1)
        rows = rows if good.all() else rows[good]  # (all, usually: no copy of the rows)
    leaves: list[_Leaf] = []
    if rows.size:
        _walk(fields, 0, rows, 0, _Leaf(rows, -1, -1, 0, -1, 0, -1), acc, cdr, leaves)
    for lf in leaves:
        # all messages: plain slices, not fancy indexing
        into: slice | I64 = slice(None) if lf.rows.shape[0] == n else lf.rows
        if lf.stamp_at >= 0:
            st = np.ascontiguousarray(acc.at(lf.rows, lf.stamp_at, 8)).view("<u4")
            sec = st[:, 0].view("<i4").astype(np.int64)
            dec.stamp[into] = sec * 1_000_000_000 + st[:, 1]
        if lf.pose_at >= 0:  # the <f8 bytes copied straight in (rows need not be aligned)
            pose = acc.at(lf.rows, lf.pose_at, 56)
            for col, a in ((dec.position, 0), (dec.orientation, 24)):
                col.view(np.uint8).reshape(n, -1)[into] = pose[:, a : a + 8 * col.shape[1]]
                if not np.little_endian:  # native doubles are big-endian here
                    col[into] = col[into].byteswap()
        ok = np.ones(lf.rows.shape[0], dtype=bool)
        for at, size, codes in ((lf.frame_at, lf.frame_len, dec.frame_code),
                                 (lf.child_at, lf.child_len, dec.child_code)):  # fmt: skip
            if at >= 0:
                ok &= _names(dec, codes, lf.rows, acc.at(lf.rows, at, size))
        dec.handled[into if ok.all() else lf.rows[ok]] = True
    return dec


def _names(dec: Decoded, codes: I64, rows: I64, raw: U8) -> NDArray[np.bool_]:
    """Fill ``codes[rows]`` with name indices for the strings ``raw`` ((rows, width) bytes);
    returns which rows hold valid UTF-8 (the others are left to rosbags, which rejects them,
    so that both paths agree)."""
    n, width = raw.shape
    if n and bool((raw == raw[0]).all()):  # one name for the topic (usual): no sort
        try:
            codes[rows] = dec.code(bytes(raw[0]).decode("utf-8"))
        except UnicodeDecodeError:
            return np.zeros(n, dtype=bool)
        return np.ones(n, dtype=bool)
    keys = np.ascontiguousarray(raw).view(np.dtype((np.void, width))).reshape(-1)
    uniq, inverse = np.unique(keys, return_inverse=True)
    mapping = np.empty(len(uniq), dtype=np.int64)
    for k, u in enumerate(uniq):
        try:
            mapping[k] = dec.code(bytes(u).decode("utf-8"))
        except UnicodeDecodeError:
            mapping[k] = -2
    got = mapping[inverse.reshape(-1)]
    codes[rows] = np.where(got == -2, -1, got)
    return np.asarray(got != -2)
