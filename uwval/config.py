"""``uwval.toml``: a project file naming the topic pairs, frames, compare options and thresholds.

``uwval compare``, ``uwval check`` and ``uwval report`` read ``uwval.toml`` from the current
folder (or the file given by ``--config``), so that a project's commands need no flags::

    # uwval.toml
    thresholds = "ci/thresholds.toml"    # for check / report (relative to this file)

    [compare]                            # defaults of compare's options
    sync = "nearest"                     # interp | nearest
    max_diff = 0.01                      # s
    offset = "auto"                      # s, or "auto"
    align = "se3"                        # none | se3 | sim3 | origin | scale
    frame = "unity-flu"                  # convention of the other (Unity) stream

    [[pair]]                             # topic pairs compared in one log (first: vehicle)
    name = "tethys"                      # label in tables and reports (default: from topics)
    reference = "/model/tethys/pose"     # the Gazebo side (TOPIC#CHILD for a TF child)
    other = "/unity/tethys/pose"
    frame = "enu"                        # optional: this pair's convention

Options given on the command line win over the file; unknown keys are refused with the file
and the key named. Two files (``compare gt.txt est.txt``) take the first pair's topics.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError

#: The file looked for in the current folder.
CONFIG_NAME = "uwval.toml"

#: [compare] keys -> (keyword of the compare functions, accepted Python types).
COMPARE_KEYS: dict[str, tuple[str, tuple[type, ...]]] = {
    "sync": ("sync", (str,)),
    "max_diff": ("max_diff", (int, float)),
    "max_gap": ("max_gap", (int, float)),
    "offset": ("offset", (str, int, float)),
    "max_offset": ("max_offset", (int, float)),
    "drift": ("drift", (str,)),
    "align": ("align", (str,)),
    "frame": ("frame", (str,)),
    "format": ("fmt", (str,)),
    "n_to_align": ("n_to_align", (int,)),
    "pose_relation": ("pose_relation", (str,)),
}


@dataclass(frozen=True)
class TopicPair:
    """One compared pair of a log: label, reference (Gazebo) topic, other topic, frame."""

    name: str
    reference: str
    other: str
    frame: str | None = None


@dataclass(frozen=True)
class ProjectConfig:
    """A parsed ``uwval.toml``."""

    source: Path
    compare: dict[str, Any] = field(default_factory=dict)  # keyword -> value
    pairs: tuple[TopicPair, ...] = ()
    thresholds: Path | None = None


def find_config(explicit: str | Path | None = None, cwd: Path | None = None) -> Path | None:
    """``explicit`` (which must exist), else ``uwval.toml`` in ``cwd`` when present."""
    if explicit is not None:
        p = Path(explicit)
        if not p.is_file():
            raise ConfigError(f"{p}: no such project file (--config)")
        return p
    p = (cwd or Path.cwd()) / CONFIG_NAME
    return p if p.is_file() else None


def load_config(
    explicit: str | Path | None = None, cwd: Path | None = None
) -> ProjectConfig | None:
    """The project file in effect (see :func:`find_config`), parsed; None when there is none."""
    path = find_config(explicit, cwd)
    if path is None:
        return None
    # imported here: a compare without a project file does not load the TOML parser
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    try:
        obj = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return parse_config(obj, path)


def parse_config(obj: dict[str, Any], source: Path) -> ProjectConfig:
    """Check and convert the parsed TOML; every error names the file and the key."""
    known = {"compare", "pair", "thresholds"}
    extra = sorted(set(obj) - known)
    if extra:
        raise ConfigError(f"{source}: unknown key(s) {extra} (allowed: {sorted(known)})")
    raw = obj.get("compare", {})
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: [compare] must be a table")
    compare: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in COMPARE_KEYS:
            raise ConfigError(
                f"{source}: [compare] unknown key {key!r} (allowed: {', '.join(COMPARE_KEYS)})"
            )
        dest, kinds = COMPARE_KEYS[key]
        if isinstance(value, bool) or not isinstance(value, kinds):
            names = " or ".join("number" if k in (int, float) else k.__name__ for k in kinds)
            raise ConfigError(f"{source}: [compare] {key} must be a {names}, got {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{source}: [compare] {key} must be finite, got {value!r}")
        compare[dest] = value
    pairs = _parse_pairs(obj.get("pair", []), source)
    thresholds = obj.get("thresholds")
    th_path: Path | None = None
    if thresholds is not None:
        if not isinstance(thresholds, str) or not thresholds:
            raise ConfigError(f"{source}: thresholds must be a path (a string)")
        th_path = Path(thresholds)
        if not th_path.is_absolute():
            th_path = source.parent / th_path
    return ProjectConfig(source, compare, pairs, th_path)


def _parse_pairs(raw: Any, source: Path) -> tuple[TopicPair, ...]:
    if not isinstance(raw, list):
        raise ConfigError(f"{source}: 'pair' must be an array of tables ([[pair]])")
    out: list[TopicPair] = []
    for i, p in enumerate(raw):
        where = f"{source}: pair #{i + 1}"
        if not isinstance(p, dict):
            raise ConfigError(f"{where}: must be a table")
        extra = sorted(set(p) - {"name", "reference", "other", "frame"})
        if extra:
            raise ConfigError(
                f"{where}: unknown key(s) {extra} (allowed: name, reference, other, frame)"
            )
        for key in ("reference", "other"):
            if not isinstance(p.get(key), str) or not p[key]:
                raise ConfigError(f"{where}: '{key}' (a topic name) is required")
        for key in ("name", "frame"):
            if key in p and (not isinstance(p[key], str) or not p[key]):
                raise ConfigError(f"{where}: '{key}' must be a non-empty string")
        from uwval.comparison.logs import pair_label

        name = p.get("name") or pair_label(p["reference"], p["other"])
        if any(q.name == name for q in out):
            raise ConfigError(f"{where}: name {name!r} is used twice")
        out.append(TopicPair(name, p["reference"], p["other"], p.get("frame")))
    return tuple(out)


def merged_options(given: dict[str, Any], config: ProjectConfig | None) -> dict[str, Any]:
    """Compare keywords: the project file's, overridden by those given on the command line
    (``given`` holds only options the user gave). The file's pairs go in as ``pairs`` when no
    topic is given."""
    if config is None:
        return dict(given)
    out = {**config.compare, **given}
    if config.pairs and not given.get("gazebo_topic") and not given.get("unity_topic"):
        out["pairs"] = config.pairs
    return out
