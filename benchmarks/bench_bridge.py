"""Bridge speed: loopback throughput, one-way latency at 1 kHz, and a 30 s session's wall time.

The consumer is a separate process (as Unity is) using the Unity-like connection: it
handshakes, subscribes, parses every frame and decodes every PoseStamped. Latency is
measured with CLOCK_MONOTONIC, which is shared by processes on one machine: the publisher
puts its send time in the header stamp, the consumer subtracts it from its receive time.

Targets (issue 6): >= 20k pose msg/s sustained; p99 one-way latency <= 2 ms at 1 kHz with
zero loss; a 30 s run (1500 ticks x 2 topics) well under 1-2 s.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import BenchRow
from uwval.bridge import protocol as wire
from uwval.bridge.server import BridgeServer

REPO = Path(__file__).resolve().parents[1]

CONSUMER = """
import json, sys, time
from uwval.bridge import protocol as wire
from uwval.bridge.unity_client import UnityConnection
port, n = int(sys.argv[1]), int(sys.argv[2])
conn = UnityConnection("127.0.0.1", port, subscriptions={"bench": wire.POSE_STAMPED})
conn.connect()
print("ready", flush=True)
lat = []
t_first = None
got = 0
while got < n:
    frames = conn.poll(10.0)
    if not frames:
        break
    now = time.monotonic_ns()
    if t_first is None:
        t_first = now
    for f in frames:
        stamp, pos, quat, fid = wire.decode_pose_stamped(f.payload)
        lat.append(now - stamp)
        got += 1
t_last = time.monotonic_ns()
print(json.dumps({"got": got, "t_first": t_first, "t_last": t_last, "lat_ns": lat}), flush=True)
"""


def _consumer(port: int, n: int) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", CONSUMER, str(port), str(n)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "ready":
        raise RuntimeError("bridge benchmark consumer failed to start")
    return proc


def _result(proc: subprocess.Popen[str]) -> dict[str, object]:
    out, _ = proc.communicate(timeout=120)
    return dict(json.loads(out.strip().splitlines()[-1]))


def throughput(n: int) -> tuple[float, int, int]:
    """Publish ``n`` PoseStamped as fast as possible; (msg/s received, received, dropped)."""
    with BridgeServer("127.0.0.1", 0, queue_size=1 << 20) as srv:
        proc = _consumer(srv.port, n)
        srv.wait_for_subscribers("bench", 1)
        pos = np.array([1.0, 2.0, 3.0])
        quat = np.array([0.0, 0.0, 0.0, 1.0])
        t0 = time.monotonic_ns()
        for k in range(n):
            pos[0] = k
            srv.publish("bench", wire.encode_pose_stamped(time.monotonic_ns(), pos, quat, "world"))
        res = _result(proc)
        dropped = sum(c.dropped for c in srv.clients() + srv.closed_clients())
    got = int(res["got"])  # type: ignore[call-overload]
    elapsed = (int(res["t_last"]) - t0) * 1e-9  # type: ignore[call-overload]
    return got / elapsed, got, dropped


def latency_at_rate(rate_hz: float, seconds: float) -> tuple[np.ndarray, int, int]:
    """Publish at ``rate_hz`` for ``seconds``; (one-way latencies s, sent, received)."""
    n = int(rate_hz * seconds)
    with BridgeServer("127.0.0.1", 0) as srv:
        proc = _consumer(srv.port, n)
        srv.wait_for_subscribers("bench", 1)
        pos = np.zeros(3)
        quat = np.array([0.0, 0.0, 0.0, 1.0])
        period = int(1e9 / rate_hz)
        start = time.monotonic_ns() + 10_000_000
        for k in range(n):
            due = start + k * period
            while True:
                left = due - time.monotonic_ns()
                if left <= 0:
                    break
                if left > 300_000:
                    time.sleep((left - 200_000) * 1e-9)
            srv.publish("bench", wire.encode_pose_stamped(time.monotonic_ns(), pos, quat, "world"))
        res = _result(proc)
    lat = np.asarray(res["lat_ns"], dtype=np.float64) * 1e-9
    return lat, n, int(res["got"])  # type: ignore[call-overload]


def session_wall_time() -> float:
    """Wall time of run_session over 30 s of 50 Hz ticks x 2 topics, written to MCAP."""
    from uwval.bridge.recorder import open_mcap_writer
    from uwval.bridge.session import run_session

    def ticks():  # type: ignore[no-untyped-def]
        q = np.array([0.0, 0.0, 0.0, 1.0])
        for k in range(1500):
            p = np.array([0.01 * k, 0.0, 0.0])
            yield k * 20_000_000, {"model_rov_pose": (p, q), "gui_camera_pose": (p, q)}

    with tempfile.TemporaryDirectory() as d:
        w = open_mcap_writer(Path(d) / "s.mcap")
        t0 = time.perf_counter()
        run_session(ticks(), w, latency_s=0.02, drop_prob=0.01)
        w.close()
        return time.perf_counter() - t0


def run(quick: bool = False) -> list[BenchRow]:
    """Measure the bridge; quick mode uses fewer messages and a shorter latency run."""
    rows = []
    rate, got, dropped = throughput(20_000 if quick else 100_000)
    rows.append(
        BenchRow(
            "bridge: loopback throughput (PoseStamped, 1 client)",
            rate,
            "msg/s",
            target=">= 20k msg/s",
            met=rate >= 20_000 and dropped == 0,
            notes=f"{got} received, {dropped} dropped; consumer decodes each",
        )
    )
    lat, sent, recv = latency_at_rate(1000.0, 1.0 if quick else 5.0)
    p50, p99, mx = (float(np.percentile(lat, 50)), float(np.percentile(lat, 99)), float(lat.max()))
    rows.append(
        BenchRow(
            "bridge: one-way latency p99 at 1 kHz",
            p99 * 1e3,
            "ms",
            target="<= 2 ms, zero loss",
            met=p99 <= 0.002 and recv == sent,
            notes=f"p50 {p50 * 1e3:.3f} ms, max {mx * 1e3:.3f} ms, {recv}/{sent} received",
            extra={"p50_ms": p50 * 1e3, "max_ms": mx * 1e3, "sent": sent, "received": recv},
        )
    )
    wall = min(session_wall_time() for _ in range(1 if quick else 3))
    rows.append(
        BenchRow(
            "bridge: 30 s session (1500 ticks x 2 topics) wall time",
            wall,
            "s",
            target="< 1-2 s",
            met=wall < 2.0,
            notes="virtual clock, real TCP, MCAP written",
        )
    )
    return rows


if __name__ == "__main__":
    for row in run(quick="--quick" in sys.argv):
        print(
            f"{row.name}: {row.uwval:.4g} {row.unit} (target {row.target}; met={row.met}) "
            f"{row.notes}"
        )
