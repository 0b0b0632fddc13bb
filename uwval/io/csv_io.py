"""CSV pose logs exported from Unity scripts (user documentation: docs/formats.md).

One row per frame: a time column, ``transform.position`` (Unity's left-handed Y-up axes) and
``transform.rotation`` as a quaternion or ``transform.eulerAngles`` in degrees. Columns are
found by common names or mapped by :func:`read_csv`'s options or a mapping file (YAML or JSON,
the same keys). Positions are converted to metres and the result carries ``frame``; no axis
change is made here (``uwval.frames.convert_stream`` does that).
"""

from __future__ import annotations

import json
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np

from uwval.errors import FrameError, LogReadError
from uwval.frames import get_convention, quat_from_unity_euler
from uwval.io.raw import load_yaml, one_line
from uwval.io.stamps import ns_from_seconds
from uwval.posestream import PoseStream

TIME_NAMES = ("t", "time", "timestamp", "stamp", "time_s", "unity_time", "frame_time", "sec")


def _names(*groups: str) -> tuple[tuple[str, ...], ...]:
    """Column-name groups written as space-separated strings."""
    return tuple(tuple(g.split()) for g in groups)


POS_NAMES = _names("x y z", "pos_x pos_y pos_z", "px py pz", "position_x position_y position_z")
POS_NAMES += _names("position.x position.y position.z")
QUAT_NAMES = _names("qx qy qz qw", "rot_x rot_y rot_z rot_w")
QUAT_NAMES += _names("rotation_x rotation_y rotation_z rotation_w")
QUAT_NAMES += _names("rotation.x rotation.y rotation.z rotation.w")
EULER_NAMES = _names("ex ey ez", "euler_x euler_y euler_z", "rx ry rz")
EULER_NAMES += _names("eulerangles.x eulerangles.y eulerangles.z")
TIME_UNITS = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def load_mapping(path: str | Path) -> dict[str, Any]:
    """A column-mapping file (YAML or JSON) as a dict of :func:`read_csv` options."""
    p = Path(path)
    try:
        text = p.read_text()
        doc = json.loads(text) if p.suffix.lower() == ".json" else load_yaml(text)
    except Exception as exc:
        raise LogReadError(f"{p}: cannot read CSV mapping file: {one_line(exc)}") from exc
    if not isinstance(doc, dict):
        raise LogReadError(f"{p}: CSV mapping must be a mapping of option: value")
    known = {"time", "time_unit", "position", "quaternion", "euler", "length_unit", "frame"}
    known |= {"delimiter", "topic"}
    unknown = set(doc) - known
    if unknown:
        raise LogReadError(f"{p}: unknown mapping keys {sorted(unknown)}; known: {sorted(known)}")
    return doc


def _find(cols: list[str], options: tuple[tuple[str, ...], ...]) -> list[str] | None:
    low = {c.strip().lower(): c for c in cols}
    for names in options:
        if all(n in low for n in names):
            return [low[n] for n in names]
    return None


def _sniff(path: Path) -> tuple[str, str]:
    """(delimiter, decimal mark) from the header and first data line: ',' unless the
    header has no comma but semicolons or tabs (spreadsheet exports in locales that write
    decimal commas use ';' and '0,5')."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            data = (ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#"))
            lines = [*islice(data, 2), ""]  # the header, the first row (or "")
    except OSError:
        return ",", "."
    sep = next((c for c in ";\t" if c in lines[0]), ",") if "," not in lines[0] else ","
    return sep, ("," if sep != "," and "," in lines[1] and "." not in lines[1] else ".")


def read_csv(
    path: str | Path,
    *,
    time: str | None = None,
    time_unit: str = "s",
    position: list[str] | None = None,
    quaternion: list[str] | None = None,
    euler: list[str] | None = None,
    length_unit: str = "m",
    frame: str | None = None,
    mapping: str | Path | None = None,
    delimiter: str | None = None,
    topic: str = "",
) -> PoseStream:
    """Read a Unity CSV export into a PoseStream in convention ``frame`` (default unity-flu).

    Options given here win over the mapping file's. Raises :class:`LogReadError` naming the
    file, and the column or line at fault.
    """
    p = Path(path)
    opts: dict[str, Any] = load_mapping(mapping) if mapping is not None else {}
    given = dict(time=time, position=position, quaternion=quaternion, euler=euler)
    given.update(frame=frame, delimiter=delimiter)
    opts.update({k: v for k, v in given.items() if v is not None})
    if time_unit != "s" or "time_unit" not in opts:
        opts["time_unit"] = time_unit
    if length_unit != "m" or "length_unit" not in opts:
        opts["length_unit"] = length_unit
    try:  # the same names and aliases as everywhere else (e.g. "unity" = "unity-flu")
        frame_name = get_convention(str(opts.get("frame", "unity-flu"))).name
    except FrameError as exc:
        raise LogReadError(f"{p}: {exc}") from None
    tu, lu = str(opts["time_unit"]), str(opts["length_unit"])
    for key, unit, known in (("time_unit", tu, TIME_UNITS), ("length_unit", lu, LENGTH_UNITS)):
        if unit not in known:
            raise LogReadError(f"{p}: {key} must be one of {list(known)}, not {unit!r}")
    import pandas as pd

    sep, decimal = (str(opts["delimiter"]), ".") if "delimiter" in opts else _sniff(p)
    try:
        df = pd.read_csv(
            p, sep=sep, decimal=decimal, comment="#", skipinitialspace=True, encoding="utf-8-sig"
        )  # Windows exports start with a BOM
    except Exception as exc:
        raise LogReadError(f"{p}: cannot parse CSV: {one_line(exc)}") from exc
    cols = [str(c) for c in df.columns]
    df.columns = cols
    if df.empty:
        raise LogReadError(f"{p}: CSV has a header but no rows")

    def pick(key: str, defaults: tuple[tuple[str, ...], ...], n: int) -> list[str] | None:
        if key in opts:
            names = [opts[key]] if isinstance(opts[key], str) else list(opts[key])
            if len(names) != n:
                raise LogReadError(f"{p}: option {key!r} needs {n} column names, got {names}")
            missing = [c for c in names if c not in cols]
            if missing:
                raise LogReadError(f"{p}: column(s) {missing} not found; columns: {cols}")
            return names
        return _find(cols, defaults)

    tcol = pick("time", tuple((n,) for n in TIME_NAMES), 1)
    pcols = pick("position", POS_NAMES, 3)
    qcols = pick("quaternion", QUAT_NAMES, 4) if "euler" not in opts else None
    ecols = pick("euler", EULER_NAMES, 3) if qcols is None else None
    if tcol is None or pcols is None or (qcols is None and ecols is None):
        found = (
            ("time", tcol),
            ("position", pcols),
            ("rotation (quaternion or euler)", qcols or ecols),
        )
        what = [w for w, c in found if c is None]
        raise LogReadError(
            f"{p}: cannot find {', '.join(what)} column(s) among {cols}; map them with "
            "time=, position=, quaternion= / euler= or a mapping file"
        )

    def numbers(names: list[str]) -> np.ndarray:
        block: np.ndarray = (
            df[names].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
        )
        bad = ~np.isfinite(block)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            cell = df[names[int(c)]].iloc[int(r)]
            # empty fields (and pandas' NA spellings such as "nan") arrive as NaN
            what = "missing value" if pd.isna(cell) else f"not a finite number ({str(cell)!r})"
            # +2: one header line, 1-based line numbers (comment lines are not counted).
            raise LogReadError(f"{p}: line {int(r) + 2}, column {names[int(c)]!r}: {what}")
        return block

    t = numbers(tcol)[:, 0]
    pos = numbers(pcols) * LENGTH_UNITS[lu]
    if qcols is not None:
        quat = numbers(qcols)
    else:
        assert ecols is not None
        quat = quat_from_unity_euler(numbers(ecols))
    if not np.isfinite(t).all() or float(np.abs(t).max(initial=0.0)) * TIME_UNITS[tu] > 9e18:
        bad = int(np.flatnonzero(~np.isfinite(t) | (np.abs(t) * TIME_UNITS[tu] > 9e18))[0])
        raise LogReadError(f"{p}: data row {bad + 1}: time {t[bad]!r} is not a usable stamp")
    # seconds: the exact nanosecond of each double (as the TUM reader); other units: rounded
    t_ns = ns_from_seconds(t) if tu == "s" else np.round(t * TIME_UNITS[tu]).astype(np.int64)
    try:
        s = PoseStream.from_arrays(
            t_ns,
            pos,
            quat,
            frame=frame_name,
            topic=topic or str(opts.get("topic", p.stem)),
            source=str(p),
        )
    except Exception as exc:
        raise LogReadError(f"{p}: {one_line(exc)}") from exc
    dups = s.repairs.get("duplicates_dropped", 0)
    dropped = {"duplicate_stamp": dups} if dups else {}
    back = s.repairs.get("sorted", 0)
    warns = [f"{p}: stamps are not in order ({back} step(s) back in time); rows sorted"]
    warns = warns if back else []
    if not _ends_with_newline(p):
        warns.append(f"{p}: the last line has no line end: the file may have been cut off")
    return s.with_(dropped=dropped, warnings=tuple(warns)) if dropped or warns else s


def _ends_with_newline(p: Path) -> bool:
    """Whether the file's last byte ends a line (or the file is empty)."""
    with open(p, "rb") as fh:
        fh.seek(max(fh.seek(0, 2) - 1, 0))
        return fh.read(1) in (b"", b"\n", b"\r")
