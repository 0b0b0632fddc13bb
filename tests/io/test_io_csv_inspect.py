"""Unity CSV exports and ``uwval inspect`` (end to end through the console script)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from uwval.errors import LogReadError
from uwval.frames import quat_from_unity_euler, unity_euler_from_quat
from uwval.io import open_writer, read_csv, read_stream, write_stream
from uwval.posestream import PoseStream

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


def _unity_rows(n: int = 50, seed: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 60.0 + 3.0
    pos = rng.normal(size=(n, 3))
    euler = rng.uniform(0, 360, size=(n, 3))
    euler[:, 0] = rng.uniform(-80, 80, size=n) % 360  # keep away from gimbal lock
    return t, pos, euler


def test_csv_quaternion_columns_autodetected(tmp_path: Path) -> None:
    t, pos, euler = _unity_rows()
    q = quat_from_unity_euler(euler)
    path = tmp_path / "unity.csv"
    lines = ["time,pos_x,pos_y,pos_z,rot_x,rot_y,rot_z,rot_w"]
    lines += [",".join(repr(float(v)) for v in (t[i], *pos[i], *q[i])) for i in range(len(t))]
    path.write_text("\n".join(lines) + "\n")
    s = read_stream(path, "")  # dispatch by suffix
    assert s.frame == "unity-flu"
    np.testing.assert_array_equal(s.t, np.round(t * 1e9).astype(np.int64))
    np.testing.assert_allclose(s.position, pos, rtol=0, atol=0)
    np.testing.assert_allclose(s.orientation, q, atol=1e-12)


def test_csv_euler_mapping_file_and_units(tmp_path: Path) -> None:
    t, pos, euler = _unity_rows()
    path = tmp_path / "unity_euler.csv"
    lines = ["# exported by a Unity script", "frame_ms;X;Y;Z;EX;EY;EZ"]
    lines += [
        ";".join(repr(float(v)) for v in (t[i] * 1000, *(pos[i] * 100), *euler[i]))
        for i in range(len(t))
    ]
    path.write_text("\n".join(lines) + "\n")
    mapping = tmp_path / "map.yaml"
    mapping.write_text(
        "time: frame_ms\ntime_unit: ms\nposition: [X, Y, Z]\n"
        "euler: [EX, EY, EZ]\nlength_unit: cm\nframe: unity-enu\ndelimiter: ';'\n"
    )
    s = read_csv(path, mapping=mapping)
    assert s.frame == "unity-enu"
    np.testing.assert_allclose(s.position, pos, atol=1e-12)
    np.testing.assert_allclose(s.t, np.round(t * 1e9), atol=2)
    back = unity_euler_from_quat(s.orientation)
    diff = (back - euler + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(diff, 0.0, atol=1e-7)


def test_csv_errors_name_file_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1,0,zz,0,0,0,0,1\n")
    with pytest.raises(LogReadError, match=r"bad\.csv: line 3, column 'y': not a finite number"):
        read_csv(path)
    path.write_text("t,a,b,c\n0,1,2,3\n")
    with pytest.raises(LogReadError, match=r"cannot find position, rotation.*among"):
        read_csv(path)
    with pytest.raises(LogReadError, match=r"column\(s\) \['nope'\] not found"):
        read_csv(path, time="nope")
    path.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,2\n")
    with pytest.raises(LogReadError, match="norm"):
        read_csv(path)


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "uwval", *args], capture_output=True, text=True, timeout=120
    )


def test_inspect_json_and_table(tmp_path: Path) -> None:
    n = 200
    t = np.arange(n, dtype=np.int64) * 10**7 + 5 * 10**9
    t[150:] += 2 * 10**9  # one 2 s gap
    s = PoseStream.from_arrays(t, np.zeros((n, 3)), np.tile([0, 0, 0, 1.0], (n, 1)))
    path = tmp_path / "run.mcap"
    with open_writer(path) as w:
        write_stream(w, "/gazebo/model_rov_pose", s, "world")
    proc = _run("inspect", str(path), "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    (topic,) = doc["topics"]
    assert topic["name"] == "/gazebo/model_rov_pose"
    assert topic["type"] == "geometry_msgs/msg/PoseStamped"
    assert topic["count"] == n
    assert topic["start"] == pytest.approx(5.0)
    assert topic["end"] == pytest.approx(float(t[-1]) * 1e-9)
    assert topic["largest_gaps"][0]["gap"] == pytest.approx(2.01)
    assert topic["largest_gaps"][0]["at"] == pytest.approx(float(t[149]) * 1e-9)
    table = _run("inspect", str(path))
    assert table.returncode == 0
    assert "/gazebo/model_rov_pose" in table.stdout
    assert "200" in table.stdout


def test_inspect_bad_files_exit_2_without_traceback(tmp_path: Path) -> None:
    empty = tmp_path / "empty.bag"
    empty.write_bytes(b"")
    proc = _run("inspect", str(empty))
    assert proc.returncode == 2
    assert "file is empty (0 bytes)" in proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout


@pytest.mark.skipif(not (DATA / "evo").exists(), reason="shared/data not present")
def test_inspect_real_bag_json() -> None:
    proc = _run("inspect", str(DATA / "bags" / "evo" / "ROS_example.bag"), "--json")
    assert proc.returncode == 0, proc.stderr
    topics = json.loads(proc.stdout)["topics"]
    counts = {t["name"]: t["count"] for t in topics}
    assert counts == {"/groundtruth": 12765, "/ORB-SLAM": 8362, "/S-PTAM": 5439}
    # start / end (s) are the first and last receive times, as rosbags' index has them
    from rosbags.highlevel import AnyReader

    with AnyReader([DATA / "bags" / "evo" / "ROS_example.bag"]) as reader:
        for t in topics:
            (conn,) = [c for c in reader.connections if "/" + c.topic.strip("/") == t["name"]]
            stamps = [ts for _c, ts, _d in reader.messages(connections=[conn])]
            assert t["start"] == pytest.approx(min(stamps) * 1e-9, abs=1e-9)
            assert t["end"] == pytest.approx(max(stamps) * 1e-9, abs=1e-9)
            assert t["rate_hz"] == pytest.approx((len(stamps) - 1) / (t["end"] - t["start"]))


@pytest.mark.skipif(not (DATA / "evo").exists(), reason="shared/data not present")
@pytest.mark.parametrize("name", ["freiburg1_xyz-groundtruth.txt", "fr2_desk_ORB.txt"])
def test_tum_text_dispatches_to_read_tum(name: str) -> None:
    path = DATA / "evo" / name
    ref = np.loadtxt(path, comments="#")
    s = read_stream(path, "")
    assert s.frame == "enu"
    assert len(s) == len(np.unique(ref[:, 0]))
    order = np.argsort(ref[:, 0], kind="stable")
    np.testing.assert_allclose(s.position[0], ref[order[0], 1:4])


def test_csv_unity_euler_means_ros_rpy_of_the_design_note(tmp_path: Path) -> None:
    """Unity eulerAngles (applied Z, then X, then Y; left-handed) read from a CSV and taken
    to ROS/ENU give roll = -ez, pitch = ex, yaw = -ey (DESIGN section 3), checked against
    scipy's fixed-axis XYZ rotation rather than uwval's own Euler helpers."""
    from scipy.spatial.transform import Rotation

    from uwval.frames import convert_stream

    rng = np.random.default_rng(12)
    n = 40
    euler = np.column_stack(
        [rng.uniform(-70, 70, n) % 360, rng.uniform(0, 360, n), rng.uniform(0, 360, n)]
    )  # ex away from gimbal lock
    path = tmp_path / "euler.csv"
    lines = ["time,x,y,z,ex,ey,ez"]
    pos_u = rng.normal(size=(n, 3))
    lines += [",".join(repr(float(v)) for v in (i / 60, *pos_u[i], *euler[i])) for i in range(n)]
    path.write_text("\n".join(lines) + "\n")
    s = read_csv(path)
    assert s.frame == "unity-flu"
    ros = convert_stream(s, "enu")
    expect = Rotation.from_euler(
        "xyz", np.column_stack([-euler[:, 2], euler[:, 0], -euler[:, 1]]), degrees=True
    ).as_quat()
    np.testing.assert_allclose(np.abs(np.sum(ros.orientation * expect, axis=1)), 1.0, atol=1e-12)
    # vector Unity -> ROS: (x, y, z)_ros = (z_u, -x_u, y_u)
    np.testing.assert_array_equal(
        ros.position, np.column_stack([pos_u[:, 2], -pos_u[:, 0], pos_u[:, 1]])
    )


def test_csv_spreadsheet_exports_bom_crlf_semicolons_decimal_commas(tmp_path: Path) -> None:
    """Windows/Excel-style exports: a UTF-8 BOM and CRLF; ';' with decimal commas; tabs."""
    head = ["time", "pos_x", "pos_y", "pos_z", "rot_x", "rot_y", "rot_z", "rot_w"]
    rows = [[0.0, 1.5, -2.25, 3.0, 0.0, 0.0, 0.0, 1.0], [0.5, 1.75, -2.5, 3.0, 0.0, 0.0, 0.0, 1.0]]
    variants = {
        "bom.csv": (
            "\ufeff"
            + ",".join(head)
            + "\r\n"
            + "".join(",".join(repr(v) for v in r) + "\r\n" for r in rows)
        ),
        "semi.csv": (
            ";".join(head)
            + "\n"
            + "".join(";".join(repr(v).replace(".", ",") for v in r) + "\n" for r in rows)
        ),
        "tab.csv": "\t".join(head)
        + "\n"
        + "".join("\t".join(repr(v) for v in r) + "\n" for r in rows),
    }
    for name, text in variants.items():
        path = tmp_path / name
        path.write_bytes(text.encode("utf-8"))
        s = read_csv(path)
        np.testing.assert_array_equal(s.t, [0, 500_000_000])
        np.testing.assert_array_equal(s.position, np.array(rows)[:, 1:4])


def test_csv_missing_and_infinite_values_are_named(tmp_path: Path) -> None:
    path = tmp_path / "gaps.csv"
    path.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1,0,0\n")
    with pytest.raises(LogReadError, match=r"gaps\.csv: line 3, column 'z': missing value"):
        read_csv(path)
    path.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1,0,inf,0,0,0,0,1\n")
    with pytest.raises(LogReadError, match=r"line 3, column 'y': not a finite number \('inf'\)"):
        read_csv(path)
