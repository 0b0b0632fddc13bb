"""Topic-name rules the log readers share. No numpy here: the command line uses them before
the heavy modules load (:mod:`uwval.io.early`)."""

from __future__ import annotations

from collections.abc import Iterable

#: Suffix of the companion topic carrying, per Unity frame, the Gazebo header stamp shown.
APPLIED_SUFFIX = "/applied_stamp"


def norm_topic(name: str) -> str:
    """Topic names compare with one leading slash: ``groundtruth`` == ``/groundtruth``."""
    return "/" + name.strip("/")


def split_child(topic: str) -> tuple[str, str | None]:
    """``/tf#turtle1`` -> (``/tf``, ``turtle1``): a topic name may carry the child frame to
    take from a TFMessage topic (or to filter an Odometry / TransformStamped topic on)."""
    name, sep, child = topic.partition("#")
    return name, (child.strip("/") or None) if sep else None


def topics_to_scan(topics: Iterable[str]) -> set[str]:
    """The container topics a read of pose ``topics`` needs: each one (child frame removed,
    name normalised) and its applied-stamp companion."""
    wanted = {norm_topic(split_child(t)[0]) for t in topics}
    return wanted | {t + APPLIED_SUFFIX for t in wanted}
