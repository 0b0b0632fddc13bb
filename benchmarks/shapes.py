"""Logs shaped like the ones users really record (issue 15), for benchmarks and tests.

Every container log holds many topics interleaved in every chunk, as a recorder writes them
in arrival order:

- ``/gazebo/model_rov_pose``, ``/gazebo/gui_camera_pose``: PoseStamped at 100 Hz (ENU world,
  ``frame_id`` "world", stamp = sim time), as uwval's recorder writes them;
- ``/unity/model_rov_pose``, ``/unity/gui_camera_pose``: PoseStamped at 60 Hz in Unity axes
  (``frame_id`` "unity-flu", 20 ms latency, 5 mm noise) with their ``.../applied_stamp``
  std_msgs/Header companions;
- ``/tf``: tf2_msgs/TFMessage at 50 Hz with :data:`TF_CHILDREN` (several children per message);
- optionally ``/camera/image_raw/compressed``: sensor_msgs/CompressedImage at 15 Hz, 40 kB of
  incompressible bytes each (a JPEG's entropy).

Formats: MCAP (zstd chunks, uwval's writer on the ``mcap`` library), rosbag2 (sqlite3 and
mcap storage, rosbags' writer), ROS 1 bag (rosbags' writer), and TUM text pairs whose
quaternions are rounded to 4 (reference) and 6 (estimate) decimals, as the TUM RGB-D ground
truths and most estimators write them (so they are not unit to 1e-9).

PoseStamped and Header payloads are encoded by :mod:`uwval.io.encode` (byte-identical to
rosbags, tested there); TFMessage and CompressedImage are serialized by rosbags' typestore.
All content is seeded: the same shape gives the same bytes every time.

``python -m benchmarks.shapes OUTDIR [NAME ...]`` writes shapes into ``OUTDIR``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

T0_NS = 1_700_000_000_000_000_000
GAZEBO_HZ = 100.0
UNITY_HZ = 60.0
TF_HZ = 50.0
IMAGE_HZ = 15.0
IMAGE_BYTES = 40_000
UNITY_LATENCY_S = 0.02
UNITY_NOISE_M = 0.005
UNITY_CONVENTION = "unity-flu"
TF_CHILDREN = (
    ("world", "base_link"),
    ("base_link", "camera_link"),
    ("base_link", "dvl_link"),
    ("base_link", "imu_link"),
    ("world", "gui_camera"),
)
IMAGE_TOPIC = "/camera/image_raw/compressed"
GAZEBO_VEHICLE = "/gazebo/model_rov_pose"
UNITY_VEHICLE = "/unity/model_rov_pose"
GAZEBO_CAMERA = "/gazebo/gui_camera_pose"
UNITY_CAMERA = "/unity/gui_camera_pose"

#: Block of log time generated and written at once (bounds the generator's memory).
_BLOCK_NS = 20 * 1_000_000_000


@dataclass(frozen=True)
class Shape:
    """One log shape: container format, length (s) and whether the image topic is in it."""

    name: str
    fmt: str  # "mcap" | "rosbag2-sqlite3" | "rosbag2-mcap" | "rosbag1" | "tum"
    duration_s: float
    images: bool = False

    @property
    def file_name(self) -> str:
        """The log's file (or directory) name; TUM shapes are a pair ``<name>.{ref,est}.tum``."""
        ext = {"mcap": ".mcap", "rosbag1": ".bag", "tum": ""}.get(self.fmt, "")
        return self.name + ext


#: The shapes of issue 15's table (and the rosbag2 ones it asked for), headline rows first.
SHAPES: dict[str, Shape] = {
    s.name: s
    for s in (
        Shape("tum-1h", "tum", 3600.0),
        Shape("mcap-1h", "mcap", 3600.0),
        Shape("mcap-10min-images", "mcap", 600.0, images=True),
        Shape("mcap-10min", "mcap", 600.0),
        Shape("rosbag1-15min", "rosbag1", 900.0),
        Shape("rosbag2-sqlite3-15min", "rosbag2-sqlite3", 900.0),
        Shape("rosbag2-mcap-15min", "rosbag2-mcap", 900.0),
    )
}


@dataclass(frozen=True)
class ShapeFiles:
    """What :func:`generate` wrote: the path(s), the topic pair to compare, counts."""

    shape: Shape
    paths: tuple[Path, ...]  # one log, or (reference.tum, estimate.tum)
    gazebo_topic: str
    unity_topic: str
    messages: int
    bytes: int
    seconds: float  # time the generator took


def _streams(duration_s: float) -> tuple[Any, Any, Any, Any]:
    """Gazebo vehicle and camera (100 Hz, ENU) and their Unity views (60 Hz, Unity axes)."""
    from uwval.comparison.synthetic import camera_motion, unity_view, vehicle_motion

    n = round(duration_s * GAZEBO_HZ)
    gv = vehicle_motion(n, rate_hz=GAZEBO_HZ, seed=0, t0_ns=T0_NS, topic=GAZEBO_VEHICLE)
    gc = camera_motion(gv, topic=GAZEBO_CAMERA)
    kw = {"rate_hz": UNITY_HZ, "latency": UNITY_LATENCY_S, "noise": UNITY_NOISE_M}
    uv = unity_view(gv, convention=UNITY_CONVENTION, seed=1, topic=UNITY_VEHICLE, **kw)
    uc = unity_view(gc, convention=UNITY_CONVENTION, seed=2, topic=UNITY_CAMERA, **kw)
    return gv, gc, uv, uc


class _Source:
    """One topic's messages: log times and a way to get payload ``i`` (bytes)."""

    def __init__(self, topic: str, msgtype: str, log_time: NDArray[np.int64], payload: Any):
        self.topic = topic
        self.msgtype = msgtype
        self.log_time = log_time
        self.payload = payload  # (N, L) uint8 rows, or a callable i -> bytes


def _pose_sources(encoding: str, duration_s: float) -> list[_Source]:
    from uwval.io.encode import encode_header, encode_pose_stamped
    from uwval.io.ros import APPLIED_SUFFIX, HEADER, POSE_STAMPED

    out = []
    for s in _streams(duration_s):
        fid = "world" if s.topic.startswith("/gazebo") else UNITY_CONVENTION
        rows = encode_pose_stamped(s.t, s.position, s.orientation, fid, encoding)
        out.append(_Source(s.topic, POSE_STAMPED, s.t, rows))
        if s.applied_stamp is not None:
            hdr = encode_header(s.applied_stamp, "world", encoding)
            out.append(_Source(s.topic + APPLIED_SUFFIX, HEADER, s.t, hdr))
    return out


@lru_cache(maxsize=1)
def _ros1_store() -> Any:
    """ROS 1 Noetic typestore plus tf2_msgs/TFMessage (rosbags' Noetic store lacks it)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(
        get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
    )
    return store


def _tf_source(encoding: str, duration_s: float) -> _Source:
    """/tf at 50 Hz: one TFMessage per tick holding every child of :data:`TF_CHILDREN`."""
    from uwval.comparison.synthetic import vehicle_motion
    from uwval.io.ros import split_ns, typestore

    ros = 1 if encoding == "ros1" else 2
    ts = _ros1_store() if ros == 1 else typestore(2)
    types = ts.types
    n = round(duration_s * TF_HZ)
    motion = vehicle_motion(n, rate_hz=TF_HZ, seed=3, t0_ns=T0_NS)
    rng = np.random.default_rng(4)
    fixed = rng.normal(0.0, 0.3, (len(TF_CHILDREN), 3))
    msgtype = "tf2_msgs/msg/TFMessage"
    Time = types["builtin_interfaces/msg/Time"]
    Header = types["std_msgs/msg/Header"]
    V3 = types["geometry_msgs/msg/Vector3"]
    Q = types["geometry_msgs/msg/Quaternion"]
    Tr = types["geometry_msgs/msg/Transform"]
    TS = types["geometry_msgs/msg/TransformStamped"]
    TFM = types[msgtype]
    t_list = motion.t.tolist()
    pos = motion.position
    quat = motion.orientation

    def payload(i: int) -> bytes:
        sec, nsec = split_ns(t_list[i])
        stamp = Time(sec=sec, nanosec=nsec)
        transforms = []
        for k, (parent, child) in enumerate(TF_CHILDREN):
            p = pos[i] if k == 0 else fixed[k]
            q = quat[i] if k in (0, 4) else np.array([0.0, 0.0, 0.0, 1.0])
            hdr = (
                Header(seq=0, stamp=stamp, frame_id=parent)
                if ros == 1
                else Header(stamp=stamp, frame_id=parent)
            )
            transforms.append(
                TS(
                    header=hdr,
                    child_frame_id=child,
                    transform=Tr(
                        translation=V3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                        rotation=Q(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
                    ),
                )
            )
        msg = TFM(transforms=transforms)
        data = ts.serialize_ros1(msg, msgtype) if ros == 1 else ts.serialize_cdr(msg, msgtype)
        return bytes(data)

    return _Source("/tf", msgtype, motion.t, payload)


def _image_source(encoding: str, duration_s: float) -> _Source:
    """A 15 Hz CompressedImage topic, 40 kB of seeded random bytes per message."""
    from uwval.io.ros import split_ns, typestore

    ros = 1 if encoding == "ros1" else 2
    ts = _ros1_store() if ros == 1 else typestore(2)
    types = ts.types
    msgtype = "sensor_msgs/msg/CompressedImage"
    n = int(duration_s * IMAGE_HZ)
    t = np.int64(T0_NS) + np.round(np.arange(n) * (1e9 / IMAGE_HZ)).astype(np.int64)
    t_list = t.tolist()
    seed = np.random.default_rng(5).integers(0, 2**31, n)

    def payload(i: int) -> bytes:
        sec, nsec = split_ns(t_list[i])
        stamp = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        hdr_t = types["std_msgs/msg/Header"]
        hdr = (
            hdr_t(seq=i, stamp=stamp, frame_id="camera_link")
            if ros == 1
            else hdr_t(stamp=stamp, frame_id="camera_link")
        )
        data = np.random.default_rng(int(seed[i])).integers(0, 256, IMAGE_BYTES, dtype=np.uint8)
        msg = types[msgtype](header=hdr, format="jpeg", data=data)
        out = ts.serialize_ros1(msg, msgtype) if ros == 1 else ts.serialize_cdr(msg, msgtype)
        return bytes(out)

    return _Source(IMAGE_TOPIC, msgtype, t, payload)


def _interleaved(sources: list[_Source]) -> Iterator[tuple[_Source, int, int]]:
    """(source, index, log_time) of every message in log-time order, block by block."""
    start = min(int(s.log_time[0]) for s in sources if s.log_time.size)
    stop = max(int(s.log_time[-1]) for s in sources if s.log_time.size)
    for lo in range(start, stop + 1, _BLOCK_NS):
        hi = lo + _BLOCK_NS
        parts_t, parts_src, parts_i = [], [], []
        for k, s in enumerate(sources):
            a, b = np.searchsorted(s.log_time, [lo, hi], side="left")
            parts_t.append(s.log_time[a:b])
            parts_src.append(np.full(b - a, k, dtype=np.int64))
            parts_i.append(np.arange(a, b, dtype=np.int64))
        t = np.concatenate(parts_t)
        order = np.argsort(t, kind="stable")
        for lt, k, i in zip(
            t[order].tolist(),
            np.concatenate(parts_src)[order].tolist(),
            np.concatenate(parts_i)[order].tolist(),
            strict=True,
        ):
            yield sources[k], i, lt


def _write_container(shape: Shape, path: Path) -> int:
    from uwval.io.writers import open_writer

    encoding = "ros1" if shape.fmt == "rosbag1" else "cdr"
    sources = _pose_sources(encoding, shape.duration_s)
    sources.append(_tf_source(encoding, shape.duration_s))
    if shape.images:
        sources.append(_image_source(encoding, shape.duration_s))
    n = 0
    w = open_writer(path, shape.fmt)
    if shape.fmt == "rosbag1":  # connections described by the store that knows TFMessage
        store = _ros1_store()
        w._add_connection = lambda topic, msgtype: w._writer.add_connection(  # type: ignore[attr-defined]
            topic, msgtype, typestore=store
        )
    with w:
        for src, i, lt in _interleaved(sources):
            p = src.payload
            data = p[i].tobytes() if isinstance(p, np.ndarray) else p(i)
            w.write_raw(src.topic, src.msgtype, data, lt)
            n += 1
    return n


def _write_tum(path: Path, stream: Any, decimals: int) -> None:
    """TUM lines ``t x y z qx qy qz qw``: stamps and values to ``decimals`` places."""
    from uwval.io.stamps import seconds_from_ns

    cols = np.column_stack([seconds_from_ns(stream.t), stream.position, stream.orientation])
    fmt = " ".join([f"%.{max(decimals, 4)}f"] + [f"%.{decimals}f"] * 7)
    with open(path, "w") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw\n")
        np.savetxt(fh, cols, fmt=fmt)


def _write_tum_pair(shape: Shape, ref: Path, est: Path) -> int:
    """Reference: the Gazebo vehicle, 4 decimals (TUM RGB-D ground truth style); estimate:
    the Unity view converted back to ENU, 6 decimals. The pair evo compares as-is."""
    from uwval.frames import convert_stream

    gv, _, uv, _ = _streams(shape.duration_s)
    _write_tum(ref, gv, 4)
    _write_tum(est, convert_stream(uv, "enu"), 6)
    return len(gv) + len(uv)


def _size(p: Path) -> int:
    if p.is_dir():
        return sum(c.stat().st_size for c in p.rglob("*") if c.is_file())
    return p.stat().st_size


def generate(shape: Shape | str, directory: str | Path) -> ShapeFiles:
    """Write ``shape`` into ``directory`` (created if needed) and say what was written.

    Existing files of the same name are reused when they were complete (a ``.done`` marker),
    so a benchmark re-run does not regenerate an hour of log.
    """
    sh = SHAPES[shape] if isinstance(shape, str) else shape
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if sh.fmt == "tum":
        paths: tuple[Path, ...] = (d / f"{sh.name}.ref.tum", d / f"{sh.name}.est.tum")
    else:
        paths = (d / sh.file_name,)
    marker = d / f"{sh.name}.done"
    if marker.exists() and all(p.exists() for p in paths):
        n = int(marker.read_text().strip() or 0)
    else:
        marker.unlink(missing_ok=True)
        n = _write_tum_pair(sh, *paths) if sh.fmt == "tum" else _write_container(sh, paths[0])
        marker.write_text(f"{n}\n")
    return ShapeFiles(
        shape=sh,
        paths=paths,
        gazebo_topic=GAZEBO_VEHICLE,
        unity_topic=UNITY_VEHICLE,
        messages=n,
        bytes=sum(_size(p) for p in paths),
        seconds=time.perf_counter() - t0,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.shapes", description=__doc__)
    parser.add_argument("outdir", type=Path)
    parser.add_argument("names", nargs="*", help=f"shapes (default all): {', '.join(SHAPES)}")
    parser.add_argument(
        "--duration", type=float, default=None, help="override every shape's length (s)"
    )
    args = parser.parse_args(argv)
    for name in args.names or list(SHAPES):
        sh = SHAPES[name]
        if args.duration is not None:
            sh = Shape(f"{sh.name}-{args.duration:g}s", sh.fmt, args.duration, sh.images)
        f = generate(sh, args.outdir)
        print(
            f"{sh.name}: {', '.join(map(str, f.paths))} ({f.messages} messages, "
            f"{f.bytes / 2**20:.0f} MiB, {f.seconds:.1f} s)",
            file=sys.stderr,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
