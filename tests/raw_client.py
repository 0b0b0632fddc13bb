"""A minimal Unity-like peer written from the protocol facts, for the bridge tests."""

from __future__ import annotations

import json
import socket
import struct


class RawClient:
    """A minimal Unity-like peer: struct framing over a blocking socket."""

    def __init__(self, port: int, nul: bool = True) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.nul = nul
        self.buf = b""

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def send(self, dest: str, payload: bytes, nul: bool | None = None) -> None:
        add = self.nul if nul is None else nul
        d = dest.encode() + (b"\x00" if add else b"")
        self.sock.sendall(struct.pack("<I", len(d)) + d + struct.pack("<I", len(payload)) + payload)

    def command(self, dest: str, params: dict[str, object]) -> None:
        body = json.dumps(params).encode() + (b"\x00" if self.nul else b"")
        self.send(dest, body)

    def _exact(self, n: int) -> bytes:
        while len(self.buf) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise EOFError("server closed")
            self.buf += chunk
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def read(self) -> tuple[str, bytes]:
        (dlen,) = struct.unpack("<I", self._exact(4))
        dest = self._exact(dlen).decode().rstrip("\x00")
        (plen,) = struct.unpack("<I", self._exact(4))
        return dest, self._exact(plen)

    def read_json(self) -> tuple[str, dict[str, object]]:
        dest, payload = self.read()
        return dest, json.loads(payload.rstrip(b"\x00") or b"{}")

    def handshake(self) -> dict[str, object]:
        dest, params = self.read_json()
        assert dest == "__handshake"
        return params

    def subscribe(self, topic: str, msg: str = "geometry_msgs/PoseStamped") -> None:
        self.command("__subscribe", {"topic": topic, "message_name": msg})

    def close(self) -> None:
        self.sock.close()
