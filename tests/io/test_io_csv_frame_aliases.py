"""Unity CSV exports accept the same frame aliases as every other reader."""

from __future__ import annotations

from pathlib import Path


def test_csv_accepts_the_same_frame_aliases(tmp_path: Path) -> None:
    from uwval.io import read_stream

    csv = tmp_path / "u.csv"
    csv.write_text("time,x,y,z,qx,qy,qz,qw\n0.0,1,2,3,0,0,0,1\n0.1,1,2,3,0,0,0,1\n")
    assert read_stream(csv, "", frame="unity").frame == "unity-flu"
