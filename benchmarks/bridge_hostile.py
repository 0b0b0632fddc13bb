"""Measure the bridge server under hostile clients (issue 14); loopback only, bounded.

Starts ``uwval bridge serve`` in its own process on a free loopback port, records its RSS,
then opens N hostile connections (default 10,000) from a few threads, at most 200 open at a
time, cycling through: idle sockets held open, 256 KiB ``__subscribe`` topics, 8 MiB
``__log`` texts, subscriptions to 256 distinct 1 KiB topics, garbage length prefixes, and
connect-then-close. The baseline RSS is taken after one well-behaved warm-up client has
come and gone. When the hostile connections are all closed it times a well-behaved client
(connect, read
the handshake, ask ``__topic_list``, read the answer) and reads the RSS again.

    python -m benchmarks.bridge_hostile [--connections 10000]

Prints one JSON object: rss_start_mb, rss_peak_mb, rss_end_mb, good_client_ms, refused...
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path


def _frame(dest: str, payload: bytes) -> bytes:
    d = dest.encode()
    return struct.pack("<I", len(d)) + d + struct.pack("<I", len(payload)) + payload


def _rss_mb(pid: int) -> float:
    text = Path(f"/proc/{pid}/status").read_text()
    m = re.search(r"VmRSS:\s+(\d+) kB", text)
    return int(m.group(1)) / 1024 if m else float("nan")


def _threads(pid: int) -> int:
    text = Path(f"/proc/{pid}/status").read_text()
    m = re.search(r"Threads:\s+(\d+)", text)
    return int(m.group(1)) if m else -1


def _hostile(kind: int, port: int, held: list[socket.socket], lock: threading.Lock) -> None:
    try:
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
    except OSError:
        return
    try:
        if kind == 0:  # idle: keep it open a while
            with lock:
                held.append(s)
            return
        if kind == 1:  # 256 KiB topic name
            body = json.dumps({"topic": "/" + "a" * 262_144, "message_name": "a/B"}).encode()
            s.sendall(_frame("__subscribe", body))
        elif kind == 2:  # 8 MiB __log text (sent in part: the server closes at the header)
            body = json.dumps({"text": "b" * (8 << 20)}).encode()
            s.sendall(_frame("__log", body)[: 1 << 20])
        elif kind == 3:  # many registrations of long (1 KiB) names
            for i in range(300):
                t = f"/{i:04d}" + "c" * 1000
                s.sendall(
                    _frame("__subscribe", json.dumps({"topic": t, "message_name": "a/B"}).encode())
                )
        elif kind == 4:  # garbage length prefix
            s.sendall(b"\xf0\xff\xff\xff" + os.urandom(64))
        # kind 5: connect and close at once
    except OSError:
        pass
    s.close()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connections", type=int, default=10_000)
    ap.add_argument("--threads", type=int, default=8)
    args = ap.parse_args()
    with socket.socket() as probe:  # a free loopback port for the server
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "uwval", "bridge", "serve", "--port", str(port), "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        for _ in range(600):  # up to 60 s for the server to listen
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                time.sleep(0.1)
        # warm-up: one well-behaved client first, so lazily imported code and the first
        # thread's arenas are in the baseline (as in a server that has served someone)
        w = socket.create_connection(("127.0.0.1", port), timeout=5)
        w.sendall(_frame("__topic_list", b"{}"))
        w.recv(65536)
        time.sleep(0.3)
        w.close()
        time.sleep(1.0)
        rss_start = _rss_mb(proc.pid)
        peak = rss_start
        held: list[socket.socket] = []
        lock = threading.Lock()
        counter = iter(range(args.connections))
        clock = threading.Lock()

        def worker() -> None:
            while True:
                with clock:
                    i = next(counter, None)
                if i is None:
                    return
                _hostile(i % 6, port, held, lock)
                with lock:
                    if len(held) > 200:
                        for s in held[:100]:
                            s.close()
                        del held[:100]

        t0 = time.monotonic()
        ts = [threading.Thread(target=worker) for _ in range(args.threads)]
        for t in ts:
            t.start()
        while any(t.is_alive() for t in ts):
            peak = max(peak, _rss_mb(proc.pid))
            time.sleep(0.2)
        hostile_s = time.monotonic() - t0
        threads_peak = _threads(proc.pid)
        for s in held:
            s.close()
        time.sleep(2.0)  # let the server notice the closes
        t1 = time.monotonic()
        g = socket.create_connection(("127.0.0.1", port), timeout=5)
        buf = b""

        def read_frame() -> str:
            nonlocal buf
            while True:
                if len(buf) >= 4:
                    (dl,) = struct.unpack_from("<I", buf)
                    if len(buf) >= 8 + dl:
                        (pl,) = struct.unpack_from("<I", buf, 4 + dl)
                        if len(buf) >= 8 + dl + pl:
                            dest = buf[4 : 4 + dl].decode().rstrip("\0")
                            buf = buf[8 + dl + pl :]
                            return dest
                chunk = g.recv(65536)
                if not chunk:
                    raise EOFError
                buf += chunk

        first = read_frame()
        g.sendall(_frame("__topic_list", b"{}"))
        second = read_frame()
        good_ms = (time.monotonic() - t1) * 1000
        g.close()
        time.sleep(1.0)
        rss_end = _rss_mb(proc.pid)
        print(
            json.dumps(
                {
                    "connections": args.connections,
                    "hostile_seconds": round(hostile_s, 2),
                    "rss_start_mb": round(rss_start, 1),
                    "rss_peak_mb": round(peak, 1),
                    "rss_end_mb": round(rss_end, 1),
                    "rss_end_vs_start_pct": round(100 * (rss_end - rss_start) / rss_start, 1),
                    "server_threads_after_hostile": threads_peak,
                    "good_client_ms": round(good_ms, 2),
                    "good_client_frames": [first, second],
                    "server_alive": proc.poll() is None,
                }
            )
        )
    finally:
        proc.terminate()
        proc.wait(10)


if __name__ == "__main__":
    main()
