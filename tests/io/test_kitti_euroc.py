"""KITTI and EuRoC input (issue 16 item 2): uwval's readers equal evo's, and ``uwval compare
--format kitti|euroc`` / ``uwval rpe --format ...`` give evo_ape's / evo_rpe's numbers.

The files are generated here (seeded); evo is run live on them when it is installed (the
checks skip otherwise).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.errors import LogReadError
from uwval.io.evo_text import read_euroc, read_kitti
from uwval.rotations import matrix_from_quat

EVO_BIN = Path(sys.executable).parent
STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _trajectory(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 3) and unit quaternions (n, 4) xyzw of a smooth random walk."""
    pos = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    rv = np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0)
    ang = np.linalg.norm(rv, axis=1, keepdims=True)
    quat = np.concatenate([rv / ang * np.sin(ang / 2), np.cos(ang / 2)], axis=1)
    return pos, quat


def _write_kitti(path: Path, pos: np.ndarray, quat: np.ndarray) -> None:
    m = np.concatenate([matrix_from_quat(quat), pos[:, :, None]], axis=2).reshape(-1, 12)
    np.savetxt(path, m, fmt="%.17g", delimiter=" ")


def _write_euroc(path: Path, t_ns: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> None:
    with open(path, "w") as fh:
        fh.write(
            "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
            "q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
            "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
            "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n"
        )
        for k in range(t_ns.shape[0]):
            vals = [*pos[k], quat[k, 3], *quat[k, :3], *([0.1] * 9)]
            fh.write(str(int(t_ns[k])) + "," + ",".join(f"{v:.9f}" for v in vals) + "\n")


def _write_tum(path: Path, t_s: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> None:
    rows = np.concatenate([t_s[:, None], pos, quat], axis=1)
    np.savetxt(path, rows, fmt=["%.9f"] + ["%.9f"] * 7, delimiter=" ")


@pytest.fixture
def kitti_pair(tmp_path: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(16)
    pos, quat = _trajectory(rng, 300)
    est_pos = 1.02 * pos + rng.normal(0, 0.01, pos.shape) + [0.3, -0.1, 0.05]
    _, est_quat = _trajectory(np.random.default_rng(17), 300)
    est_quat = 0.98 * quat + 0.02 * est_quat
    est_quat /= np.linalg.norm(est_quat, axis=1, keepdims=True)
    _write_kitti(tmp_path / "ref.kitti", pos, quat)
    _write_kitti(tmp_path / "est.kitti", est_pos, est_quat)
    return tmp_path / "ref.kitti", tmp_path / "est.kitti"


@pytest.fixture
def euroc_pair(tmp_path: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(18)
    n = 400
    t_ns = 1403636579758555392 + np.arange(n, dtype=np.int64) * 5_000_000
    pos, quat = _trajectory(rng, n)
    _write_euroc(tmp_path / "data.csv", t_ns, pos, quat)
    # estimate at 20 Hz, 1.3 ms late, with noise: every 4th ground-truth pose
    sel = np.arange(0, n, 4)
    t_est = (t_ns[sel] - 1403636579 * 10**9 + 1_300_000) / 1e9 + 1403636579
    _write_tum(
        tmp_path / "est.txt", t_est, pos[sel] + rng.normal(0, 0.02, (sel.size, 3)), quat[sel]
    )
    return tmp_path / "data.csv", tmp_path / "est.txt"


def _evo(tool: str, *args: str | Path, tmp_path: Path) -> dict[str, float]:
    exe = EVO_BIN / tool
    if not exe.exists():
        pytest.skip(f"{tool} not installed")
    out = tmp_path / f"{tool}.zip"
    subprocess.run(
        [str(exe), *map(str, args), "--save_results", str(out), "--no_warnings", "--silent"],
        check=True,
        capture_output=True,
        timeout=120,
    )
    import zipfile

    with zipfile.ZipFile(out) as z:
        return json.loads(z.read("stats.json"))


def _close(got: dict[str, float], want: dict[str, float]) -> None:
    for k in STAT_KEYS:
        tol = 1e-9 * max(1.0, abs(want[k])) if k == "sse" else 1e-9
        assert got[k] == pytest.approx(want[k], abs=tol), k


# ----------------------------------------------------------------------- readers vs evo's
def test_kitti_reader_equals_evo(kitti_pair: tuple[Path, Path]) -> None:
    fi = pytest.importorskip("evo.tools.file_interface")
    ours = read_kitti(kitti_pair[0])
    theirs = fi.read_kitti_poses_file(str(kitti_pair[0]))
    assert len(ours) == theirs.num_poses == 300
    np.testing.assert_array_equal(ours.position, theirs.positions_xyz)
    rot = np.array([p[:3, :3] for p in theirs.poses_se3])
    np.testing.assert_allclose(matrix_from_quat(ours.orientation), rot, atol=1e-12)
    np.testing.assert_array_equal(ours.t, np.arange(300) * 10**9)  # index as stamp (s)


def test_euroc_reader_equals_evo(euroc_pair: tuple[Path, Path]) -> None:
    fi = pytest.importorskip("evo.tools.file_interface")
    ours = read_euroc(euroc_pair[0])
    theirs = fi.read_euroc_csv_trajectory(str(euroc_pair[0]))
    assert len(ours) == theirs.num_poses == 400
    assert int(ours.t[0]) == 1403636579758555392  # exact ns, no float rounding
    np.testing.assert_allclose(ours.t / 1e9, theirs.timestamps, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(ours.position, theirs.positions_xyz)
    wxyz = theirs.orientations_quat_wxyz
    np.testing.assert_allclose(ours.orientation, wxyz[:, [1, 2, 3, 0]], atol=1e-9)


# ----------------------------------------------------------------------- numbers vs evo's
@pytest.mark.parametrize("flags", [[], ["-as"]], ids=["none", "sim3"])
def test_compare_kitti_equals_evo_ape(
    kitti_pair: tuple[Path, Path], flags: list[str], tmp_path: Path
) -> None:
    want = _evo("evo_ape", "kitti", *kitti_pair, *flags, tmp_path=tmp_path)
    align = ["--align", "sim3"] if flags else []
    proc = run_uwval("compare", *kitti_pair, "--format", "kitti", "--json", *align, check=True)
    _close(json.loads(proc.stdout)["position_error_norm"], want)


def test_rpe_kitti_equals_evo_rpe(kitti_pair: tuple[Path, Path], tmp_path: Path) -> None:
    args = ["-r", "angle_deg", "-d", "5"]
    want = _evo("evo_rpe", "kitti", *kitti_pair, *args, tmp_path=tmp_path)
    proc = run_uwval("rpe", *kitti_pair, "--format", "kitti", "--json", *args, check=True)
    _close(json.loads(proc.stdout)["stats"], want)


def test_compare_euroc_equals_evo_ape(euroc_pair: tuple[Path, Path], tmp_path: Path) -> None:
    want = _evo("evo_ape", "euroc", *euroc_pair, "-a", tmp_path=tmp_path)
    proc = run_uwval(
        "compare", *euroc_pair, "--format", "euroc", "--sync", "nearest", "--align", "se3",
        "--json", check=True,
    )  # fmt: skip
    doc = json.loads(proc.stdout)
    assert doc["n_samples"] == 100
    _close(doc["position_error_norm"], want)


def test_rpe_euroc_equals_evo_rpe(euroc_pair: tuple[Path, Path], tmp_path: Path) -> None:
    args = ["-d", "0.2", "-u", "m", "-r", "full"]
    want = _evo("evo_rpe", "euroc", *euroc_pair, *args, tmp_path=tmp_path)
    proc = run_uwval("rpe", *euroc_pair, "--format", "euroc", "--json", *args, check=True)
    _close(json.loads(proc.stdout)["stats"], want)


# ----------------------------------------------------------------------- bad input
def test_kitti_errors_name_the_line(tmp_path: Path, kitti_pair: tuple[Path, Path]) -> None:
    lines = kitti_pair[0].read_text().splitlines()
    bad = tmp_path / "bad.kitti"
    bad.write_text("# header\n" + "\n".join([*lines[:4], " ".join(lines[4].split()[:11])]) + "\n")
    with pytest.raises(
        LogReadError, match=r"bad.kitti: line 6 \(byte offset \d+\): 11 fields, expected 12"
    ):
        read_kitti(bad)
    bad.write_text("\n".join([*lines[:2], lines[2].replace(lines[2].split()[3], "x", 1)]) + "\n")
    with pytest.raises(LogReadError, match=r"line 3 \(byte offset \d+\): 'x' is not a number"):
        read_kitti(bad)
    bad.write_text("\n".join([*lines[:1], "2 0 0 0 0 1 0 0 0 0 1 0"]) + "\n")
    with pytest.raises(
        LogReadError, match=r"line 2 \(byte offset \d+\): the rotation block is not a rotation"
    ):
        read_kitti(bad)
    short = tmp_path / "short.kitti"
    short.write_text("\n".join(lines[:100]) + "\n")
    proc = run_uwval("compare", kitti_pair[0], short, "--format", "kitti")
    assert proc.returncode == 2
    assert "300 poses" in proc.stderr and "100" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_euroc_errors_name_the_line(tmp_path: Path, euroc_pair: tuple[Path, Path]) -> None:
    lines = euroc_pair[0].read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([*lines[:3], ",".join(lines[3].split(",")[:5])]) + "\n")
    with pytest.raises(
        LogReadError, match=r"bad.csv: line 4 \(byte offset \d+\): 5 fields, expected at least 8"
    ):
        read_euroc(bad)
    fields = lines[2].split(",")
    fields[2] = "nan"
    bad.write_text("\n".join([*lines[:2], ",".join(fields), *lines[3:6]]) + "\n")
    with pytest.raises(
        LogReadError,
        match=r"line 3 \(byte offset \d+\): a position or quaternion value is not finite",
    ):
        read_euroc(bad)
    bad.write_text("\n".join([lines[0], lines[2], lines[1]]) + "\n")
    with pytest.raises(
        LogReadError, match=r"line 3 \(byte offset \d+\): timestamp \d+ ns does not increase"
    ):
        read_euroc(bad)


def test_rpe_reads_topics_of_logs(tmp_path: Path) -> None:
    """Two topics of one MCAP, and one topic from each of two logs: same numbers as rpe()."""
    from uwval.comparison.rpe import rpe
    from uwval.io.writers import open_writer, write_stream
    from uwval.posestream import PoseStream

    rng = np.random.default_rng(5)
    pos, quat = _trajectory(rng, 200)
    t = 1_700_000_000_000_000_000 + np.arange(200, dtype=np.int64) * 10_000_000
    ref = PoseStream(t, pos, quat, topic="/gt")
    est = PoseStream(t + 2_000_000, pos + rng.normal(0, 0.01, pos.shape), quat, topic="/est")
    with open_writer(tmp_path / "run.mcap", "mcap") as w:
        write_stream(w, "/gt", ref, "enu")
        write_stream(w, "/est", est, "enu")
    for name, s in (("gt.mcap", ref), ("est.mcap", est)):
        with open_writer(tmp_path / name, "mcap") as w:
            write_stream(w, s.topic, s, "enu")
    want = rpe(ref, est, relation="full", delta=3).stats
    one = run_uwval(
        "rpe", tmp_path / "run.mcap", "--ref-topic", "/gt", "--est-topic", "/est", "-r", "full",
        "-d", "3", "--json", check=True,
    )  # fmt: skip
    two = run_uwval(
        "rpe", tmp_path / "gt.mcap", tmp_path / "est.mcap", "-r", "full", "-d", "3", "--json",
        check=True,
    )  # fmt: skip
    for proc in (one, two):
        doc = json.loads(proc.stdout)
        assert doc["n_pairs"] == 66
        _close(doc["stats"], want)
