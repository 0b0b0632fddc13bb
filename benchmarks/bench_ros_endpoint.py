"""Side by side, same run: Unity's real ROS-TCP-Endpoint 0.7.0 (ROS 1) vs ``uwval bridge serve``.

``python -m benchmarks.bench_ros_endpoint [--quick] [--repeat R] [--markdown FILE]``

For each endpoint the same two uwval clients run over loopback TCP: a publisher
(:class:`uwval.bridge.gazebo.EndpointPublisher`, ``__publish``) and a Unity-like subscriber
(:class:`uwval.bridge.unity_client.UnityConnection`, ``__subscribe``) in its own process, one
PoseStamped topic. Through the real endpoint a pose goes client -> endpoint -> rospy
publisher -> TCPROS -> rospy subscriber (same endpoint process) -> client; through uwval's
server it is forwarded between the two connections. The publisher puts its
``time.monotonic_ns()`` send time in the header stamp, the subscriber subtracts it from its
receive time (one process, one clock): one-way latency, ms. Before measuring, the publisher
sends until the subscriber has seen one pose (ROS 1 drops what is published before the
subscriber is connected); then N poses are sent at the rate (50 Hz, 1 kHz, or as fast as
possible) and counted for 2 s after the last. poses/s = poses received / (last receive - first
send).

Needs ``UWVAL_ROS_TCP_ENDPOINT`` (an export of the endpoint, see tests/test_ros_endpoint.py),
``/usr/bin/rosmaster`` and rospy for ``/usr/bin/python3``.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import numpy as np

from uwval.bridge.gazebo import EndpointPublisher

TOPIC = "/uwval_bench/pose"
ROS_PYTHON = "/usr/bin/python3"
SERVE_OPTIONS = ("--protocol", "ROS1", "--quiet")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_port(port: int, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return
        time.sleep(0.05)
    raise RuntimeError(f"nothing listens on 127.0.0.1:{port} after {timeout} s")


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in reversed(procs):
        p.terminate()
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@contextmanager
def real_endpoint() -> Iterator[int]:
    """rosmaster --core + ROS-TCP-Endpoint on free loopback ports; yields the endpoint port."""
    export = os.environ.get("UWVAL_ROS_TCP_ENDPOINT", "")
    if not (Path(export) / "src" / "ros_tcp_endpoint").is_dir():
        raise SystemExit("set UWVAL_ROS_TCP_ENDPOINT to an export of ROS-TCP-Endpoint 0.7.0")
    mport, port = _free_port(), _free_port()
    env = dict(os.environ, ROS_IP="127.0.0.1", ROS_MASTER_URI=f"http://127.0.0.1:{mport}")
    env["PYTHONPATH"] = str(Path(export) / "src")
    procs: list[subprocess.Popen[bytes]] = []
    try:
        procs.append(
            subprocess.Popen(
                ["/usr/bin/rosmaster", "--core", "-p", str(mport)],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        _wait_port(mport)
        procs.append(
            subprocess.Popen(
                [
                    ROS_PYTHON,
                    "-m",
                    "ros_tcp_endpoint.default_server_endpoint",
                    "_tcp_ip:=127.0.0.1",
                    f"_tcp_port:={port}",
                ],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        _wait_port(port)
        yield port
    finally:
        _stop(procs)


@contextmanager
def uwval_serve() -> Iterator[int]:
    """``uwval bridge serve --protocol ROS1`` in its own process; yields its port."""
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "uwval", "bridge", "serve", "--port", str(port), *SERVE_OPTIONS],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_port(port)
        yield port
    finally:
        _stop([proc])


#: The Unity-like subscriber, in its own process (no GIL shared with the publisher): prints
#: "first" at its first pose, then, 2 s after the last pose, JSON [[stamp ns, recv ns], ...].
CONSUMER = """
import json, sys, time
from uwval.bridge import protocol as wire
from uwval.bridge.unity_client import UnityConnection
port, topic = int(sys.argv[1]), sys.argv[2]
conn = UnityConnection("127.0.0.1", port, subscriptions={topic: wire.POSE_STAMPED},
                       protocol="auto")
conn.connect(5)
got, last = [], time.monotonic() + 30
while time.monotonic() - last < 2.0:
    frames = conn.poll(0.05)
    now = time.monotonic_ns()
    for f in frames:
        if f.destination == topic:
            got.append((wire.decode_pose_stamped(f.payload, conn.protocol)[0], now))
            if len(got) == 1:
                print("first", flush=True)
            last = time.monotonic()
    conn.keepalive_if_idle()
print(json.dumps(got), flush=True)
"""


def measure(port: int, rate: float, n: int) -> dict[str, float]:
    """Send ``n`` poses at ``rate`` Hz (0: as fast as possible) through the endpoint at
    ``port``; returns sent, received, poses/s and latency p50/p99/max (ms)."""
    # The publisher connects first: the real endpoint sends to its newest connection only.
    pub = EndpointPublisher("127.0.0.1", port, topics={"pose": TOPIC})
    consumer = subprocess.Popen(
        [sys.executable, "-c", CONSUMER, str(port), TOPIC],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert consumer.stdout is not None
    pos, quat = np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    deadline = time.monotonic() + 20
    seen_first = False
    while not seen_first and time.monotonic() < deadline:  # until one pose came through
        pub.publish("pose", time.monotonic_ns(), pos, quat)
        pub.service()
        ready, _, _ = select.select([consumer.stdout], [], [], 0.02)
        seen_first = bool(ready) and consumer.stdout.readline().strip() == "first"
    if not seen_first:
        consumer.kill()
        raise RuntimeError(f"no pose came through the endpoint on port {port} in 20 s")
    time.sleep(0.2)
    t_start = time.monotonic_ns()
    period = 1.0 / rate if rate > 0 else 0.0
    t0 = time.perf_counter()
    for k in range(n):
        if period:  # sleep, no busy wait: the 2 cores are shared with the endpoints
            lag = t0 + k * period - time.perf_counter()
            if lag > 0:
                time.sleep(lag)
        pub.publish("pose", time.monotonic_ns(), pos, quat)
        if k % 50 == 0:
            pub.service()
    out, _ = consumer.communicate(timeout=60)
    pub.close()
    got = json.loads(out.strip().splitlines()[-1])
    rows = [(s, r) for s, r in got if s >= t_start]
    if not rows:
        return {"sent": n, "received": 0, "poses_s": 0.0, "p50": 0.0, "p99": 0.0, "max": 0.0}
    lat = np.array([(r - s) * 1e-6 for s, r in rows])
    span = (rows[-1][1] - t_start) * 1e-9
    return {
        "sent": n,
        "received": len(rows),
        "poses_s": len(rows) / span,
        "p50": float(np.percentile(lat, 50)),
        "p99": float(np.percentile(lat, 99)),
        "max": float(lat.max()),
    }


def run_all(quick: bool, repeat: int = 1) -> list[tuple[str, str, dict[str, float]]]:
    """Every (rate, endpoint) pair, the endpoints alternating within one run; with
    ``repeat`` > 1 every figure is the median over the repetitions (sent/received: sums)."""
    cases = [("50 Hz", 50.0, 150 if quick else 500), ("1 kHz", 1000.0, 1000 if quick else 5000)]
    cases.append(("max", 0.0, 2000 if quick else 10000))
    runs: dict[tuple[str, str], list[dict[str, float]]] = {}
    with real_endpoint() as real_port, uwval_serve() as uw_port:
        for _ in range(repeat):
            for label, rate, n in cases:
                for name, port in (
                    ("ROS-TCP-Endpoint 0.7.0", real_port),
                    ("uwval bridge serve", uw_port),
                ):
                    m = measure(port, rate, n)
                    runs.setdefault((label, name), []).append(m)
                    print(label, name, m, file=sys.stderr, flush=True)
    out = []
    for (label, name), ms in runs.items():
        med = {k: float(np.median([m[k] for m in ms])) for k in ms[0]}
        med["sent"] = sum(m["sent"] for m in ms)
        med["received"] = sum(m["received"] for m in ms)
        out.append((label, name, med))
    return out


def markdown(rows: list[tuple[str, str, dict[str, float]]]) -> str:
    """The results as a Markdown table."""
    lines = [
        "| rate | endpoint | sent | received | poses/s | p50 latency ms | p99 latency ms "
        "| max ms |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for label, name, m in rows:
        lines.append(
            f"| {label} | {name} | {m['sent']:.0f} | {m['received']:.0f} | {m['poses_s']:.0f} | "
            f"{m['p50']:.3f} | {m['p99']:.3f} | {m['max']:.3f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ros_endpoint")
    parser.add_argument("--quick", action="store_true", help="fewer poses per case")
    parser.add_argument("--markdown", type=Path, default=None, help="also write the table here")
    parser.add_argument("--repeat", type=int, default=1, help="repetitions (medians reported)")
    args = parser.parse_args(argv)
    table = markdown(run_all(args.quick, max(1, args.repeat)))
    print(table)
    if args.markdown is not None:
        args.markdown.write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
