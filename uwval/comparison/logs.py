"""Compare logs: pick the streams (two topics of one log, or one stream from each of two files),
run :func:`uwval.comparison.compare` per topic pair (vehicle and camera), collect the results.

:func:`run_comparison` takes the typed :class:`uwval.comparison.options.CompareOptions` that
``uwval compare`` builds and returns a :class:`LogComparison` (evo_ape's statistics included
when asked for); :func:`compare_logs` is the keyword form other modules call.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uwval.comparison.engine import ComparisonResult, ape_errors, compare
from uwval.comparison.options import (
    ApeUnit,
    CompareOptions,
    InputFormat,
    PoseRelation,
    RpeOptions,
    TimeWindow,
    unit_factor,
)
from uwval.comparison.relations import RELATION_UNITS
from uwval.comparison.stats import norm_stats
from uwval.errors import LogReadError
from uwval.io.formats import INPUT_FORMATS, is_tum  # noqa: F401 - INPUT_FORMATS re-exported
from uwval.posestream import PoseStream
from uwval.topics import (
    CAMERA,
    DEFAULT_GAZEBO_TOPIC,
    DEFAULT_UNITY_TOPIC,
    GAZEBO_PREFIX,
    UNITY_PREFIX,
    VEHICLE,
    log_topics,
)


@dataclass(frozen=True)
class ApeStatistics:
    """evo_ape's statistics of one topic pair's aligned samples, in ``unit``.

    ``relation`` is evo's pose relation (``-r``); the values are evo's (rmse, mean, median,
    std (population), min, max, sse), scaled by ``--change_unit`` when one was given.
    """

    relation: str
    unit: str
    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float

    @classmethod
    def of(
        cls, result: ComparisonResult, relation: str, unit: ApeUnit | None = None
    ) -> ApeStatistics:
        """The statistics of ``result``'s APE w.r.t. ``relation`` (evo's definitions)."""
        errors = ape_errors(result.reference, result.other, relation)
        base = RELATION_UNITS[relation]
        factor = 1.0
        if unit is not None:
            factor = unit_factor(base, unit)
            errors = errors * factor
        stats = norm_stats(errors)
        return cls(relation, str(unit or base), **stats)

    def to_json(self) -> dict[str, Any]:
        """The ``ape`` section of the JSON contract (``pose_relation``, ``unit``, stats)."""
        return {
            "pose_relation": self.relation,
            "unit": self.unit,
            **{k: getattr(self, k) for k in APE_STATISTICS},
        }


#: The statistics evo_ape prints, in its order.
APE_STATISTICS = ("rmse", "mean", "median", "std", "min", "max", "sse")


@dataclass
class LogComparison:
    """Per-topic comparisons of one run; ``primary`` names the vehicle (top-level) section.

    ``ape`` holds evo_ape's statistics per topic when a pose relation was asked for; the
    JSON puts each under its topic's ``ape`` key (and the vehicle's at the top level).
    """

    results: dict[str, ComparisonResult]
    primary: str
    sources: list[str] = field(default_factory=list)
    ape: dict[str, ApeStatistics] = field(default_factory=dict)

    @property
    def vehicle(self) -> ComparisonResult:
        return self.results[self.primary]

    def topic_json(self, name: str) -> dict[str, Any]:
        """One topic's section of the JSON contract (its ``ape`` included when computed)."""
        doc = dict(self.results[name].to_json())
        if name in self.ape:
            doc["ape"] = self.ape[name].to_json()
        return doc

    def to_json(self) -> dict[str, Any]:
        """Top level = the vehicle topic's JSON; ``topics`` holds every topic's section."""
        top = self.topic_json(self.primary)
        top["primary_topic"] = self.primary
        top["sources"] = list(self.sources)
        top["topics"] = {name: self.topic_json(name) for name in self.results}
        return top


def read_pose_stream(
    path: str | Path, topic: str | None = None, *, fmt: str | None = None, frame: str | None = None
) -> PoseStream:
    """One stream from a file: TUM text, or ``topic`` of a log via :func:`uwval.io.read_stream`.

    With no topic, a log holding exactly one pose topic gives that one.
    """
    if fmt in ("kitti", "euroc"):  # evo's text formats (uwval.io.evo_text)
        from uwval.io.evo_text import read_evo_text

        return read_evo_text(path, fmt, frame=frame or "enu", topic=topic or "")
    if is_tum(path, fmt):
        from uwval.io.tum import read_tum

        return read_tum(path, frame=frame or "enu", topic=topic or "")
    from uwval.io import list_topics, read_stream

    if topic is None:
        from uwval.io.decode import POSE_TYPES, TF_TYPES

        infos = list_topics(path)
        if not any(i.count for i in infos):
            raise LogReadError(f"{path}: the log is empty ({len(infos)} topic(s), no messages)")
        poses = sorted(
            i.name
            for i in infos
            if i.type in POSE_TYPES and i.count and not i.name.endswith("/applied_stamp")
        )
        tfs = sorted(i.name + "#CHILD" for i in infos if i.type in TF_TYPES and i.count)
        if len(poses) != 1 or tfs:
            listed = ", ".join(poses + tfs) or f"none ({len(infos)} other topic(s))"
            raise LogReadError(
                f"{path}: name the topic to compare (--gazebo-topic / "
                f"--unity-topic); pose topics: {listed}"
            )
        topic = poses[0]
    # a TF child (TOPIC#CHILD) may hang under /tf_static transforms: chained when present
    chain: dict[str, Any] = {"tf_static": None} if "#" in topic else {}
    return read_stream(path, topic, frame=frame, **chain)


def pair_label(gazebo_topic: str, unity_topic: str) -> str:
    """A label for a compared topic pair that does not collide: the path segments the two
    topics share at their end (``/gazebo/model_rov_pose`` + ``/unity/model_rov_pose`` ->
    ``model_rov_pose``; ``/model/tethys/pose`` + ``/unity/tethys/pose`` -> ``tethys/pose``),
    else both names (``odom~amcl_pose``). A TF child (``/tf#base_link``) counts as a segment."""
    a = gazebo_topic.replace("#", "/").strip("/").split("/")
    b = unity_topic.replace("#", "/").strip("/").split("/")
    common: list[str] = []
    for x, y in zip(reversed(a), reversed(b), strict=False):
        if x != y:
            break
        common.insert(0, x)
    if common and common != a and common != b:
        return "/".join(common)
    if a == b:
        return "/".join(a)
    return "/".join(a) + "~" + "/".join(b)


def no_pair_message(path: str | Path) -> str:
    """Why a log has no default topic pair, listing only the topics that hold poses."""
    from uwval.io import list_topics
    from uwval.io.decode import POSE_TYPES, TF_TYPES

    infos = list_topics(path)
    if not infos:
        return f"{path}: the log is empty (no topics, no messages)"
    if not any(i.count for i in infos):
        return f"{path}: the log is empty ({len(infos)} topic(s), no messages)"
    poses = [
        f"{i.name} ({i.type.split('/')[-1]}, {i.count})"
        for i in sorted(infos, key=lambda i: i.name)
        if i.type in POSE_TYPES and not i.name.endswith("/applied_stamp")
    ]
    tfs = [i.name for i in sorted(infos, key=lambda i: i.name) if i.type in TF_TYPES]
    head = f"{path}: no Gazebo/Unity topic pair ({DEFAULT_GAZEBO_TOPIC} and {DEFAULT_UNITY_TOPIC})"
    if not poses and not tfs:
        return f"{head}; the log holds no pose topics ({len(infos)} other topic(s))"
    parts = []
    if poses:
        parts.append("pose topics: " + ", ".join(poses))
    if tfs:
        parts.append(
            "TF topics (name a child frame: TOPIC#CHILD; `uwval inspect` lists them): "
            + ", ".join(tfs)
        )
    return f"{head}; {'; '.join(parts)}; choose with --gazebo-topic / --unity-topic"


def _topics_of(path: str | Path) -> set[str]:
    from uwval.io import list_topics

    return {"/" + t.name.strip("/") for t in list_topics(path)}


def compare_logs(
    path_a: str | Path,
    path_b: str | Path | None = None,
    *,
    gazebo_topic: str | None = None,
    unity_topic: str | None = None,
    fmt: str | None = None,
    frame: str | None = None,
    pairs: Sequence[Any] | None = None,
    recorded_clock: bool | None = None,
    window: TimeWindow | None = None,
    **options: Any,
) -> LogComparison:
    """Compare the Gazebo (reference) and Unity streams of one log, or of two files.

    One log: with no topics given, the vehicle pair ``/gazebo/model_rov_pose`` vs
    ``/unity/model_rov_pose`` and, when present, the camera pair ``.../gui_camera_pose``.
    Two files: the reference is read from ``path_a`` (``gazebo_topic``), the other from
    ``path_b`` (``unity_topic``); TUM text by ``fmt='tum'`` or suffix. ``frame`` states the
    other stream's convention (default: from the log; ``enu`` for TUM); other ``options`` go
    to :func:`compare`. ``pairs`` (a project file's :class:`uwval.config.TopicPair` list:
    ``name``, ``reference``, ``other``, ``frame``) names the pairs of one log to compare when
    no topic is given; with two logs the first pair's topics are read; a ``frame`` given
    here wins over a pair's. ``recorded_clock``: put a Unity side stamped on the monotonic
    clock on the epoch clock with the log's ``uwval.clock`` metadata, when the two streams do
    not overlap in time (default: when ``options`` give no ``offset``). ``window``: evo's
    ``--downsample`` and ``--t_start``/``--t_end``, applied to the streams as read.
    """
    results: dict[str, ComparisonResult] = {}
    if path_b is None:
        if is_tum(path_a, fmt):
            raise LogReadError(f"{path_a}: a TUM file holds one trajectory; give two files")
        pairs_l: list[tuple[str, str, str]]
        from uwval.io import read_streams

        frames: dict[str, str | None] = {}
        # one pass over the log for every topic of the pairs (uwval.topics decides which)
        topics, skip_missing = log_topics(pairs, gazebo_topic, unity_topic)
        streams = read_streams(path_a, topics, skip_missing=skip_missing, tf_static=None)
        if pairs and not (gazebo_topic or unity_topic):
            pairs_l = [(p.name, p.reference, p.other) for p in pairs]
            frames = {p.name: p.frame for p in pairs}
        elif gazebo_topic or unity_topic:
            g, u = topics
            pairs_l = [(pair_label(g, u), g, u)]
        else:  # the candidate pairs that are present
            pairs_l = [
                (name, GAZEBO_PREFIX + name, UNITY_PREFIX + name)
                for name in (VEHICLE, CAMERA)
                if GAZEBO_PREFIX + name in streams and UNITY_PREFIX + name in streams
            ]
            if not pairs_l:
                raise LogReadError(no_pair_message(path_a))
        if recorded_clock is None:
            recorded_clock = "offset" not in options
        clock_offset = _recorded_clock_offset(path_a) if recorded_clock else None
        jobs: list[tuple[str, PoseStream, PoseStream, str | None, dict[str, Any], str | None]] = []
        for name, g, u in pairs_l:
            ref, oth = _windowed(streams[g], streams[u], window)
            pair_frame = frame if frame not in (None, "auto") else (frames.get(name) or frame)
            if pair_frame not in (None, "auto"):
                oth = oth.with_(frame=pair_frame)
            pair_options, note = options, None
            if (
                clock_offset is not None
                and len(ref)
                and len(oth)
                and (oth.t[0] > ref.t[-1] or oth.t[-1] < ref.t[0])  # two clocks, no overlap
            ):
                pair_options = {**options, "offset": clock_offset}
                note = (
                    f"clock offset {clock_offset:+.9f} s from the log's uwval.clock metadata "
                    "(the Unity side was stamped on the monotonic clock)"
                )
            jobs.append((name, ref, oth, pair_frame, pair_options, note))
        for (name, *_, note), res in zip(jobs, _compare_pairs(jobs), strict=True):
            results[name] = res
            if note:
                res.warnings.insert(0, note)
        return LogComparison(results, pairs_l[0][0], [str(path_a)])

    pair_name = None
    if pairs and not (gazebo_topic or unity_topic) and not is_tum(path_a, fmt):
        first = pairs[0]
        gazebo_topic, unity_topic, pair_name = first.reference, first.other, first.name
        frame = frame if frame not in (None, "auto") else (first.frame or frame)

    ref, oth = _read_pair(
        path_a, path_b, gazebo_topic, unity_topic, fmt, None if frame == "auto" else frame
    )
    if gazebo_topic and unity_topic:
        name = pair_label(gazebo_topic, unity_topic)
    else:
        name = (gazebo_topic or unity_topic or VEHICLE).replace("#", "/").strip("/").split("/")[-1]
    if is_tum(path_a, fmt) and not gazebo_topic:
        name = "trajectory"
    name = pair_name or name
    ref, oth = _windowed(ref, oth, window)
    results[name] = compare(ref, oth, frame=frame, **options)
    return LogComparison(results, name, [str(path_a), str(path_b)])


#: Pairs of one log are compared in threads (numpy releases the GIL in its loops) when at
#: least two of them have this many samples on each side and a second CPU is free.
PARALLEL_MIN_SAMPLES = 20_000


def _compare_pairs(
    jobs: Sequence[tuple[str, PoseStream, PoseStream, str | None, dict[str, Any], str | None]],
) -> list[ComparisonResult]:
    """:func:`compare` of each (name, reference, other, frame, options, note), in order.

    The vehicle and camera pairs of a long log are compared concurrently on two CPUs (the
    results are the same numbers: each comparison is its own computation). An error is the
    first pair's error, in order, as when the pairs are compared one after the other.
    """
    big = [j for j in jobs if min(len(j[1]), len(j[2])) >= PARALLEL_MIN_SAMPLES]
    if len(big) < 2 or (os.cpu_count() or 1) < 2:
        return [compare(ref, oth, frame=fr, **opts) for _, ref, oth, fr, opts, _ in jobs]
    from concurrent.futures import ThreadPoolExecutor
    from functools import partial

    pool = ThreadPoolExecutor(2, thread_name_prefix="uwval-compare")
    try:
        done = [
            pool.submit(partial(compare, ref, oth, frame=fr, **opts))
            for _, ref, oth, fr, opts, _ in jobs
        ]
        return [d.result() for d in done]
    finally:
        # on an error or Ctrl-C, pairs not started yet are dropped
        pool.shutdown(cancel_futures=True)


def _recorded_clock_offset(path: str | Path) -> float | None:
    """Seconds to add to the Unity stamps of a log ``uwval bridge unity --clock monotonic``
    wrote, from its ``uwval.clock`` metadata (Unix time minus monotonic time, and any
    Unity clock offset); None for any other log, or one whose summary cannot be read.

    The metadata records are found through the log's summary (:func:`summary_metadata`,
    a few small reads); a log without a summary, or whose summary does not parse, is left to
    mcap's reader (as before)."""
    if Path(path).suffix != ".mcap":
        return None
    from uwval.io.mcap_meta import summary_metadata

    try:
        records = summary_metadata(path, "uwval.clock")
    except Exception:  # a damaged summary: mcap's reader decides, as before
        records = None
    try:
        if records is None:  # no summary (or a damaged one): mcap's reader scans the log
            from mcap.reader import make_reader

            with open(path, "rb") as fh:
                records = [
                    dict(r.metadata)
                    for r in make_reader(fh).iter_metadata()
                    if r.name == "uwval.clock"
                ]
        for metadata in records:
            if metadata.get("unity_clock") == "monotonic":
                e_m = int(metadata["epoch_minus_monotonic_ns"])
                off = int(metadata.get("unity_clock_offset_ns", "0"))
                return (e_m - off) * 1e-9
    except Exception:  # an unfinished or damaged summary: nothing recorded to use
        return None
    return None


def _read_pair(
    path_a: str | Path,
    path_b: str | Path,
    gazebo_topic: str | None,
    unity_topic: str | None,
    fmt: str | None,
    frame: str | None,
) -> tuple[PoseStream, PoseStream]:
    """Read the two files; two TUM files are parsed concurrently when that pays off."""
    if fmt in ("kitti", "euroc"):  # evo's text formats (uwval.io.evo_text)
        from uwval.io.evo_text import read_evo_pair

        return read_evo_pair(path_a, path_b, fmt, frame_b=frame or "enu")
    if is_tum(path_a, fmt) and is_tum(path_b, fmt):
        from uwval.io.tum import read_tum_pair

        return read_tum_pair(
            path_a,
            path_b,
            frame_b=frame or "enu",
            topic_a=gazebo_topic or "",
            topic_b=unity_topic or "",
        )
    ga = gazebo_topic
    ub = unity_topic
    if ga is None and not is_tum(path_a, fmt) and DEFAULT_GAZEBO_TOPIC in _topics_of(path_a):
        ga = DEFAULT_GAZEBO_TOPIC
    if ub is None and not is_tum(path_b, fmt) and DEFAULT_UNITY_TOPIC in _topics_of(path_b):
        ub = DEFAULT_UNITY_TOPIC
    return (
        read_pose_stream(path_a, ga, fmt=fmt),
        read_pose_stream(path_b, ub, fmt=fmt, frame=frame),
    )


def _windowed(
    reference: PoseStream, other: PoseStream, window: TimeWindow | None
) -> tuple[PoseStream, PoseStream]:
    """evo's preprocessing, in evo_ape's order: both streams downsampled to at most N evenly
    spaced poses (``np.linspace`` indices, as evo), then the reference trimmed to
    [t_start, t_end] (absolute seconds of its stamps; evo trims the reference only)."""
    if window is None or not window.active:
        return reference, other
    if window.downsample is not None:
        reference, other = (_downsampled(s, window.downsample) for s in (reference, other))
    if window.t_start is not None or window.t_end is not None:
        secs = reference.t * 1e-9
        keep = np.ones(len(reference), dtype=bool)
        if window.t_start is not None:
            keep &= secs >= window.t_start
        if window.t_end is not None:
            keep &= secs <= window.t_end
        if not keep.any():
            raise LogReadError(
                f"{reference.describe()}: no pose in --t_start {window.t_start} .. --t_end "
                f"{window.t_end} (its stamps span {secs[0]:.6f} .. {secs[-1]:.6f} s)"
            )
        reference = reference.slice(np.flatnonzero(keep))
    return reference, other


def _downsampled(stream: PoseStream, n: int) -> PoseStream:
    """At most ``n`` poses, evenly spaced by index (evo's ``downsample``)."""
    if len(stream) <= n:
        return stream
    return stream.slice(np.linspace(0, len(stream) - 1, n, dtype=int))


def run_comparison(options: CompareOptions) -> LogComparison:
    """What ``uwval compare`` computes: read the inputs, compare each topic pair with the
    engine, and add evo_ape's statistics when ``options`` ask for a pose relation."""
    inp = options.inputs
    result = compare_logs(
        inp.log_a,
        inp.log_b,
        gazebo_topic=inp.gazebo_topic,
        unity_topic=inp.unity_topic,
        fmt=inp.fmt.value if inp.fmt is not None else None,
        frame=options.frame,
        pairs=inp.pairs or None,
        recorded_clock=options.offset is None,
        window=options.window,
        **options.engine_options(),
    )
    relation: PoseRelation | None = options.ape_relation
    if relation is not None:
        result.ape = {
            name: ApeStatistics.of(res, relation.value, options.change_unit)
            for name, res in result.results.items()
        }
    return result


@dataclass(frozen=True)
class RpeComparison:
    """One ``uwval rpe``: evo_rpe's result on the two streams, and where they came from."""

    result: Any  # uwval.comparison.rpe.RpeResult
    sources: tuple[str, ...]
    other_frame: str

    def to_json(self) -> dict[str, Any]:
        """The JSON contract of ``uwval rpe --json``: the result's, plus ``sources``."""
        doc: dict[str, Any] = self.result.to_json()
        doc["sources"] = list(self.sources)
        return doc


def run_rpe(options: RpeOptions) -> RpeComparison:
    """Relative pose error as evo_rpe computes it, on the inputs ``options`` name: two files
    (TUM, KITTI, EuRoC or one topic of a log each) or two topics of one log."""
    from uwval.comparison.rpe import rpe

    inp = options.inputs
    fmt = inp.fmt.value if inp.fmt is not None else None
    frame = options.frame if options.frame not in (None, "auto") else None
    if inp.log_b is None:
        if not (inp.gazebo_topic and inp.unity_topic):
            raise LogReadError(
                f"{inp.log_a}: give EST, or both --ref-topic and --est-topic of this log"
            )
        from uwval.io import read_streams

        streams = read_streams(inp.log_a, [inp.gazebo_topic, inp.unity_topic], tf_static=None)
        ref, est = streams[inp.gazebo_topic], streams[inp.unity_topic]
    else:
        ref = read_pose_stream(inp.log_a, inp.gazebo_topic, fmt=fmt)
        est = read_pose_stream(inp.log_b, inp.unity_topic, fmt=fmt, frame=frame)
    if frame is not None:
        est = est.with_(frame=frame)
    ref, est = _windowed(ref, est, options.window)
    result = rpe(
        ref,
        est,
        relation=options.relation.value,
        delta=options.delta,
        delta_unit=options.delta_unit,
        delta_tol=options.delta_tol,
        all_pairs=options.all_pairs,
        pairs_from_reference=options.pairs_from_reference,
        align=options.align.value,
        n_to_align=options.n_to_align,
        sync="none" if inp.fmt is InputFormat.KITTI else "nearest",  # KITTI: by index
        max_diff=options.max_diff,
        offset=options.offset,
    )
    sources = (str(inp.log_a),) + ((str(inp.log_b),) if inp.log_b is not None else ())
    return RpeComparison(result, sources, est.frame)
