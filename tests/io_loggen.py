"""Realistic interleaved logs for the io tests and the fuzz harness, written by the real
libraries (mcap, rosbags): uwval's pose topics (gazebo 100 Hz, unity 60 Hz + applied stamps),
/tf at 50 Hz with several children, and a compressed-image topic at 15 Hz, all interleaved in
every chunk in log-time order.

Formats: ``mcap`` (zstd / lz4 / no compression chunks, CRCs on), ``bag`` (ROS 1; none / bz2 /
lz4 chunks), ``rosbag2-sqlite3`` and ``rosbag2-mcap`` (directories).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from uwval.io.ros import typestore

GAZEBO = "/gazebo/model_rov_pose"
UNITY = "/unity/model_rov_pose"
APPLIED = UNITY + "/applied_stamp"
TF = "/tf"
IMAGE = "/camera/image/compressed"
POSE_TOPICS = (GAZEBO, UNITY)

T0 = 1_700_000_000 * 10**9


def _store(ros: int) -> Any:
    """uwval's typestore; for ROS 1 a copy that also knows tf2_msgs/TFMessage."""
    if ros == 2:
        return typestore(2)
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(
        get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
    )
    return store


def _messages(
    seconds: float, image_bytes: int, ros: int, seed: int
) -> Iterator[tuple[int, str, str, Any]]:
    """(log time ns, topic, type, rosbags message), sorted by log time."""
    T = _store(ros).types
    rng = np.random.default_rng(seed)

    def header(t: int, frame: str) -> Any:
        sec, nsec = divmod(t, 10**9)
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        if ros == 1:
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def pose(t: int, frame: str) -> Any:
        p = rng.normal(size=3)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        P = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
            orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        return T["geometry_msgs/msg/PoseStamped"](header=header(t, frame), pose=P)

    def tf(t: int) -> Any:
        trs = []
        for child in ("base_link", "camera", "sonar"):
            v = rng.normal(size=3)
            trs.append(
                T["geometry_msgs/msg/TransformStamped"](
                    header=header(t, "world"),
                    child_frame_id=child,
                    transform=T["geometry_msgs/msg/Transform"](
                        translation=T["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2]),
                        rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    ),
                )
            )
        return T["tf2_msgs/msg/TFMessage"](transforms=trs)

    def image(t: int) -> Any:
        data = rng.integers(0, 256, size=image_bytes, dtype=np.uint8)
        return T["sensor_msgs/msg/CompressedImage"](
            header=header(t, "camera"), format="jpeg", data=data
        )

    out: list[tuple[int, str, str, Any]] = []
    dur = int(seconds * 1e9)
    for hz, topic in ((100, GAZEBO), (60, UNITY), (50, TF), (15, IMAGE)):
        period = 10**9 // hz
        for k in range(dur // period):
            t = T0 + k * period + (k % 7) * 1000  # jitter: not a constant stride
            if topic == GAZEBO:
                out.append((t, topic, "geometry_msgs/msg/PoseStamped", pose(t, "world")))
            elif topic == UNITY:
                out.append((t + 5, topic, "geometry_msgs/msg/PoseStamped", pose(t, "unity-flu")))
                out.append((t + 5, APPLIED, "std_msgs/msg/Header", header(t - 10**7, "world")))
            elif topic == TF:
                out.append((t + 3, topic, "tf2_msgs/msg/TFMessage", tf(t)))
            elif image_bytes:
                out.append((t + 1, topic, "sensor_msgs/msg/CompressedImage", image(t)))
    out.sort(key=lambda m: (m[0], m[1]))
    return iter(out)


def write_log(
    path: Path,
    fmt: str,
    *,
    seconds: float = 2.0,
    image_bytes: int = 2000,
    compression: str = "zstd",
    chunk_size: int = 32 * 1024,
    seed: int = 0,
) -> Path:
    """Write an interleaved log; returns the path to read (file or rosbag2 directory)."""
    ros = 1 if fmt == "bag" else 2
    ts = _store(ros)
    msgs = _messages(seconds, image_bytes, ros, seed)
    if fmt == "mcap":
        from mcap.writer import CompressionType, Writer

        comp = {
            "zstd": CompressionType.ZSTD,
            "lz4": CompressionType.LZ4,
            "none": CompressionType.NONE,
        }
        with open(path, "wb") as fh:
            w = Writer(fh, chunk_size=chunk_size, compression=comp[compression])
            w.start(profile="ros2", library="uwval-tests")
            schemas: dict[str, int] = {}
            chans: dict[str, int] = {}
            for t, topic, typ, msg in msgs:
                if typ not in schemas:
                    text, _ = ts.generate_msgdef(typ, ros_version=2)
                    schemas[typ] = w.register_schema(
                        name=typ, encoding="ros2msg", data=text.encode()
                    )
                if topic not in chans:
                    chans[topic] = w.register_channel(
                        topic=topic, message_encoding="cdr", schema_id=schemas[typ]
                    )
                w.add_message(
                    channel_id=chans[topic],
                    log_time=t,
                    publish_time=t,
                    data=bytes(ts.serialize_cdr(msg, typ)),
                )
            w.finish()
        return path
    if fmt == "bag":
        from rosbags.rosbag1 import Writer as Bag1Writer

        w1 = Bag1Writer(path)
        if compression in ("bz2", "lz4"):
            w1.set_compression(
                {"bz2": Bag1Writer.CompressionFormat.BZ2, "lz4": Bag1Writer.CompressionFormat.LZ4}[
                    compression
                ]
            )
        w1.chunk_threshold = chunk_size
        w1.open()
        conns: dict[str, Any] = {}
        for t, topic, typ, msg in msgs:
            if topic not in conns:
                conns[topic] = w1.add_connection(topic, typ, typestore=ts)
            w1.write(conns[topic], t, bytes(ts.serialize_ros1(msg, typ)))
        w1.close()
        return path
    if fmt in ("rosbag2-sqlite3", "rosbag2-mcap"):
        from rosbags.rosbag2 import Writer as Bag2Writer
        from rosbags.rosbag2.enums import StoragePlugin

        plugin = StoragePlugin.SQLITE3 if fmt.endswith("sqlite3") else StoragePlugin.MCAP
        w2 = Bag2Writer(path, version=9, storage_plugin=plugin)
        w2.open()
        conns2: dict[str, Any] = {}
        for t, topic, typ, msg in msgs:
            if topic not in conns2:
                conns2[topic] = w2.add_connection(topic, typ, typestore=ts)
            w2.write(conns2[topic], t, bytes(ts.serialize_cdr(msg, typ)))
        w2.close()
        return path
    raise ValueError(fmt)


def storage_file(path: Path) -> Path:
    """The one file that holds the bytes of a log (the storage file of a rosbag2 dir)."""
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
        return files[0]
    return path
