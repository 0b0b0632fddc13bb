"""ROS message plumbing shared by the log readers and writers (rosbags typestores)."""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.io.names import APPLIED_SUFFIX as APPLIED_SUFFIX  # re-exported (writers, tests)

POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
HEADER = "std_msgs/msg/Header"


@lru_cache(maxsize=2)
def typestore(ros_version: int = 2) -> Any:
    """The rosbags typestore for ROS 2 (Humble) or ROS 1 (Noetic) message definitions."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE if ros_version == 2 else Stores.ROS1_NOETIC)


def normalize_type_name(name: str) -> str:
    """``pkg/Type`` or ``pkg/msg/Type`` -> ``pkg/msg/Type`` (ROS 2 form)."""
    parts = name.strip("/").split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return "/".join(parts)


def split_ns(t_ns: int) -> tuple[int, int]:
    """Nanoseconds -> (sec, nanosec) as in builtin_interfaces/Time."""
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return sec, nsec


def pose_stamped(
    t_ns: int,
    position: NDArray[np.float64],
    quat: NDArray[np.float64],
    frame_id: str,
    ros_version: int = 2,
) -> Any:
    """A rosbags PoseStamped message object."""
    ts = typestore(ros_version)
    Header = ts.types[HEADER if ros_version == 2 else "std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    Pose = ts.types["geometry_msgs/msg/Pose"]
    Point = ts.types["geometry_msgs/msg/Point"]
    Quaternion = ts.types["geometry_msgs/msg/Quaternion"]
    PoseStamped = ts.types[POSE_STAMPED]
    sec, nsec = split_ns(t_ns)
    if ros_version == 2:
        header = Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id)
    else:
        header = Header(seq=0, stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id)
    pose = Pose(
        position=Point(x=float(position[0]), y=float(position[1]), z=float(position[2])),
        orientation=Quaternion(
            x=float(quat[0]), y=float(quat[1]), z=float(quat[2]), w=float(quat[3])
        ),
    )
    return PoseStamped(header=header, pose=pose)


def header_msg(t_ns: int, frame_id: str = "", ros_version: int = 2) -> Any:
    """A rosbags std_msgs/Header message object stamped ``t_ns``."""
    ts = typestore(ros_version)
    Time = ts.types["builtin_interfaces/msg/Time"]
    sec, nsec = split_ns(t_ns)
    if ros_version == 2:
        return ts.types[HEADER](stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id)
    return ts.types[HEADER](seq=0, stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id)
