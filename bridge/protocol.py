"""Wire format of Unity's ROS-TCP-Endpoint / ROS-TCP-Connector v0.7 (DESIGN.md section 6).

Every frame on the socket is::

    u32 LE len(destination) | destination (UTF-8) | u32 LE len(payload) | payload

A frame whose destination and payload are both empty (8 zero bytes) is a keepalive. A
destination starting with ``__`` is a system command whose payload is JSON; in ROS 2 mode
Unity appends a NUL to the destination and to JSON payloads (the length counts it), so the
parser strips one trailing NUL from destinations and :func:`decode_json` tolerates it.

Message bodies are ROS 1 serialization (ROS1 mode) or CDR little-endian with the 4-byte
encapsulation header ``00 01 00 00`` (ROS2 mode); message names travel as ``pkg/Type``.
``PoseStamped`` has a struct fast path here, tested byte-equal to rosbags.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from uwval.bridge.errors import BridgeError

F64 = NDArray[np.float64]
Protocol = Literal["ROS1", "ROS2"]

#: Version string the endpoint announces; clients accept any ``v0.7.*``.
VERSION = "v0.7.0"
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 10000
#: 8 zero bytes: empty destination, empty payload.
KEEPALIVE = b"\x00" * 8
#: Default cap on one frame's payload (bytes); a larger announced length is malformed.
MAX_FRAME_BYTES = 16 * 1024 * 1024
#: Cap on a destination's length (topic names and commands are short).
MAX_DESTINATION_BYTES = 1024
#: Cap on a system command's payload (``__subscribe`` JSON, ``__log`` text...): commands
#: are small, so a larger one is malformed (it would otherwise be buffered up to the
#: frame cap, per connection).
MAX_COMMAND_BYTES = 64 * 1024
#: ROS 2 CDR encapsulation header: representation CDR_LE, options 0.
CDR_HEADER = b"\x00\x01\x00\x00"

# System commands (destinations starting with "__").
HANDSHAKE = "__handshake"
SUBSCRIBE = "__subscribe"
PUBLISH = "__publish"
ROS_SERVICE = "__ros_service"
UNITY_SERVICE = "__unity_service"
REQUEST = "__request"
RESPONSE = "__response"
TOPIC_LIST = "__topic_list"
LOG = "__log"
WARN = "__warn"
ERROR = "__error"
SYSTEM_COMMANDS = frozenset(
    {
        HANDSHAKE,
        SUBSCRIBE,
        PUBLISH,
        ROS_SERVICE,
        UNITY_SERVICE,
        REQUEST,
        RESPONSE,
        TOPIC_LIST,
        LOG,
        WARN,
        ERROR,
    }
)

POSE_STAMPED = "geometry_msgs/PoseStamped"
HEADER = "std_msgs/Header"

_U32 = struct.Struct("<I")


class ProtocolError(BridgeError):
    """A peer sent bytes that are not a valid ROS-TCP frame (message names the byte offset)."""


@dataclass(frozen=True)
class Frame:
    """One decoded frame: ``destination`` (trailing NUL stripped) and raw ``payload``.

    ``offset`` is the byte offset of the frame's first byte in the connection's stream.
    """

    destination: str
    payload: bytes
    offset: int = 0

    @property
    def is_keepalive(self) -> bool:
        """True for the 8-zero-byte keepalive (empty destination and payload)."""
        return self.destination == "" and not self.payload

    @property
    def is_command(self) -> bool:
        """True for system commands (``__name``)."""
        return self.destination.startswith("__")

    def json(self) -> dict[str, Any]:
        """The payload of a system command parsed as a JSON object."""
        return decode_json(self.payload, where=f"{self.destination} at byte {self.offset}")


# ---------------------------------------------------------------------------- encoding


def encode_frame(
    destination: str, payload: bytes | bytearray | memoryview, *, nul: bool = False
) -> bytes:
    """One frame. ``nul=True`` appends Unity's trailing NUL to the destination."""
    dest = destination.encode("utf-8") + (b"\x00" if nul and destination else b"")
    return b"".join((_U32.pack(len(dest)), dest, _U32.pack(len(payload)), bytes(payload)))


def encode_json(params: dict[str, Any], *, nul: bool = False) -> bytes:
    """A system command's JSON payload (compact, with an optional trailing NUL)."""
    data = json.dumps(params, separators=(",", ":")).encode("utf-8")
    return data + b"\x00" if nul else data


def encode_command(
    command: str, params: dict[str, Any] | None = None, *, nul: bool = False
) -> bytes:
    """A system-command frame, e.g. ``encode_command("__subscribe", {...})``."""
    if not command.startswith("__"):
        raise ProtocolError(f"system command {command!r} must start with '__'")
    return encode_frame(command, encode_json(params or {}, nul=nul), nul=nul)


def decode_json(payload: bytes, where: str = "payload") -> dict[str, Any]:
    """Parse a command's JSON payload, tolerating trailing NULs; errors name ``where``."""
    text = bytes(payload).rstrip(b"\x00")
    if not text:
        return {}
    try:
        obj = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError(f"{where}: invalid JSON payload: {exc}") from None
    if not isinstance(obj, dict):
        raise ProtocolError(f"{where}: JSON payload must be an object, got {type(obj).__name__}")
    return obj


def handshake_frame(protocol: Protocol = "ROS2", version: str = VERSION) -> bytes:
    """The endpoint's first frame: ``__handshake`` with version and protocol metadata.

    ``metadata`` is itself a JSON string, as in ROS-TCP-Endpoint.
    """
    check_protocol(protocol)
    return encode_command(
        HANDSHAKE,
        {
            "version": version,
            "metadata": json.dumps({"protocol": protocol}),
        },
    )


def parse_handshake(frame: Frame) -> tuple[str, Protocol]:
    """(version, protocol) of a ``__handshake`` frame; rejects versions other than v0.7.*."""
    if frame.destination != HANDSHAKE:
        raise ProtocolError(
            f"expected {HANDSHAKE} first, got {frame.destination!r} at byte {frame.offset}"
        )
    params = frame.json()
    version = str(params.get("version", ""))
    if not version.startswith("v0.7."):
        raise ProtocolError(f"unsupported ROS-TCP version {version!r} (need v0.7.*)")
    meta_raw = params.get("metadata", "{}")
    meta = decode_json(
        meta_raw.encode() if isinstance(meta_raw, str) else b"{}", where="handshake metadata"
    )
    protocol = str(meta.get("protocol", "ROS1"))
    return version, check_protocol(protocol)


def check_protocol(protocol: str) -> Protocol:
    """Validate a protocol name (``ROS1`` or ``ROS2``)."""
    if protocol not in ("ROS1", "ROS2"):
        raise ProtocolError(f"unknown protocol {protocol!r}; expected ROS1 or ROS2")
    return protocol  # type: ignore[return-value]


def message_name(ros_type: str) -> str:
    """``pkg/msg/Type`` or ``pkg/Type`` -> ``pkg/Type`` (the wire form)."""
    parts = ros_type.strip("/").split("/")
    if len(parts) == 3 and parts[1] in ("msg", "srv"):
        return f"{parts[0]}/{parts[2]}"
    if len(parts) != 2 or not all(parts):
        raise ProtocolError(f"invalid message name {ros_type!r}; expected pkg/Type")
    return "/".join(parts)


# ---------------------------------------------------------------------------- parsing


class FrameParser:
    """Incremental frame parser for one connection: ``feed(bytes) -> list[Frame]``.

    Bytes may arrive split anywhere. A destination longer than ``max_destination`` bytes,
    a payload longer than ``max_frame`` bytes (``max_command`` for a system command, whose
    destination starts with ``__``), or a destination that is not UTF-8 raises
    :class:`ProtocolError` naming the byte offset of the bad frame; after an error the
    parser is unusable (the connection must be closed, since framing is lost).
    """

    def __init__(
        self,
        max_frame: int = MAX_FRAME_BYTES,
        max_destination: int = MAX_DESTINATION_BYTES,
        max_command: int = MAX_COMMAND_BYTES,
    ) -> None:
        self.max_frame = max_frame
        self.max_destination = max_destination
        self.max_command = max_command
        self._buf = bytearray()
        self._consumed = 0  # stream offset of _buf[0]
        # the reason, not the exception: an exception kept here would hold its traceback,
        # whose frames hold this parser and its buffer (a cycle only the cyclic GC frees)
        self._failed: str | None = None

    @property
    def buffered(self) -> int:
        """Bytes received but not yet part of a complete frame."""
        return len(self._buf)

    @property
    def offset(self) -> int:
        """Stream offset of the next unparsed byte."""
        return self._consumed

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Append received bytes and return every frame they complete, in order."""
        if self._failed is not None:
            raise ProtocolError(self._failed)
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        pos = 0
        n = len(buf)
        unpack = _U32.unpack_from
        while n - pos >= 4:
            dlen = unpack(buf, pos)[0]
            if dlen > self.max_destination:
                self._fail(f"destination length {dlen} exceeds {self.max_destination} bytes", pos)
            if n - pos < 8 + dlen:
                break
            plen = unpack(buf, pos + 4 + dlen)[0]
            if plen > self.max_frame:
                self._fail(
                    f"payload length {plen} exceeds the frame cap of {self.max_frame} bytes", pos
                )
            if plen > self.max_command and buf[pos + 4 : pos + 6] == b"__":
                self._fail(
                    f"system command payload of {plen} bytes exceeds the cap of "
                    f"{self.max_command} bytes",
                    pos,
                )
            end = pos + 8 + dlen + plen
            if end > n:
                break
            raw_dest = bytes(buf[pos + 4 : pos + 4 + dlen])
            if raw_dest.endswith(b"\x00"):
                raw_dest = raw_dest[:-1]
            try:
                dest = raw_dest.decode("utf-8")
            except UnicodeDecodeError:
                self._fail("destination is not valid UTF-8", pos)
            if "\x00" in dest:
                self._fail("destination contains an embedded NUL", pos)
            frames.append(Frame(dest, bytes(buf[pos + 8 + dlen : end]), self._consumed + pos))
            pos = end
        if pos:
            del buf[:pos]
            self._consumed += pos
        return frames

    def _fail(self, reason: str, pos: int) -> None:
        self._failed = f"malformed frame at byte {self._consumed + pos}: {reason}"
        raise ProtocolError(self._failed)


# ---------------------------------------------------------------------------- messages

_STAMP_CDR = struct.Struct("<iII")  # sec, nanosec, len(frame_id incl. NUL)
_STAMP_ROS1 = struct.Struct("<IIII")  # seq, secs, nsecs, len(frame_id)
_POSE = struct.Struct("<7d")


def _pos_quat(position: Any, quat: Any) -> tuple[float, ...]:
    p = np.asarray(position, dtype=np.float64).reshape(3)
    q = np.asarray(quat, dtype=np.float64).reshape(4)
    return (
        float(p[0]),
        float(p[1]),
        float(p[2]),
        float(q[0]),
        float(q[1]),
        float(q[2]),
        float(q[3]),
    )


def encode_pose_stamped(
    t_ns: int, position: Any, quat: Any, frame_id: str, protocol: Protocol = "ROS2", seq: int = 0
) -> bytes:
    """geometry_msgs/PoseStamped body: ROS 2 CDR (with encapsulation header) or ROS 1.

    ``t_ns`` is the header stamp in nanoseconds; ``quat`` is (x, y, z, w).
    Byte-identical to rosbags' ``serialize_cdr`` / ``serialize_ros1``.
    """
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    fid = frame_id.encode("utf-8")
    values = _pos_quat(position, quat)
    if protocol == "ROS2":
        head = _STAMP_CDR.pack(sec, nsec, len(fid) + 1) + fid + b"\x00"
        pad = -len(head) % 8  # doubles align to 8 relative to the end of the CDR header
        return CDR_HEADER + head + b"\x00" * pad + _POSE.pack(*values)
    if sec < 0:
        raise ProtocolError(f"ROS 1 time cannot be negative (t_ns={t_ns})")
    return _STAMP_ROS1.pack(seq & 0xFFFFFFFF, sec, nsec, len(fid)) + fid + _POSE.pack(*values)


def decode_pose_stamped(data: bytes, protocol: Protocol = "ROS2") -> tuple[int, F64, F64, str]:
    """Parse a PoseStamped body -> (stamp ns, position (3,), quat xyzw (4,), frame_id)."""
    try:
        if protocol == "ROS2":
            if data[:2] != CDR_HEADER[:2]:
                raise ProtocolError(
                    f"PoseStamped: CDR encapsulation header {bytes(data[:4]).hex()} is not "
                    "little-endian CDR (00 01 00 00)"
                )
            sec, nsec, flen = _STAMP_CDR.unpack_from(data, 4)
            fid_end = 16 + flen
            frame_id = bytes(data[16:fid_end]).rstrip(b"\x00").decode("utf-8")
            start = fid_end + (-(fid_end - 4) % 8)
        else:
            _, sec, nsec, flen = _STAMP_ROS1.unpack_from(data, 0)
            frame_id = bytes(data[16 : 16 + flen]).decode("utf-8")
            start = 16 + flen
        vals = _POSE.unpack_from(data, start)
    except (struct.error, UnicodeDecodeError) as exc:
        raise ProtocolError(f"PoseStamped body of {len(data)} bytes is malformed: {exc}") from None
    t_ns = int(sec) * 1_000_000_000 + int(nsec)
    return (
        t_ns,
        np.array(vals[:3], dtype=np.float64),
        np.array(vals[3:], dtype=np.float64),
        frame_id,
    )


def encode_with_rosbags(msg: Any, ros_type: str, protocol: Protocol = "ROS2") -> bytes:
    """Any rosbags message object -> wire body (CDR with header, or ROS 1), via rosbags."""
    from uwval.io.ros import normalize_type_name, typestore

    name = normalize_type_name(ros_type)
    if protocol == "ROS2":
        return bytes(typestore(2).serialize_cdr(msg, name))
    return bytes(typestore(1).serialize_ros1(msg, name))


def decode_with_rosbags(data: bytes, ros_type: str, protocol: Protocol = "ROS2") -> Any:
    """Wire body -> rosbags message object (the per-message correctness reference)."""
    from uwval.io.ros import normalize_type_name, typestore

    name = normalize_type_name(ros_type)
    try:
        if protocol == "ROS2":
            return typestore(2).deserialize_cdr(data, name)
        return typestore(1).deserialize_ros1(data, name)
    except Exception as exc:
        raise ProtocolError(f"cannot decode {ros_type} body of {len(data)} bytes: {exc}") from None


def known_message_type(name: str) -> bool:
    """True when rosbags' ROS 2 typestore knows the message ``pkg/Type``."""
    from uwval.io.ros import normalize_type_name, typestore

    try:
        return normalize_type_name(message_name(name)) in typestore(2).types
    except ProtocolError:
        return False
