"""The report's figures (matplotlib, Agg backend): one function per plot, each returns a Figure.

All positions are ENU metres (x east, y north, z up); angles are ROS roll/pitch/yaw in
degrees. "Gazebo" is the reference stream, "Unity" the other one, converted back to ENU/FLU
and aligned in time by the compare engine. Figures are rendered by :mod:`uwval.reports.render`
both into the HTML page (PNG, base64) and into the PDF.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import matplotlib

matplotlib.use("Agg")  # headless: CI machines have no display

import numpy as np
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from numpy.typing import NDArray

from uwval.posestream import PoseStream
from uwval.results import AXES, AXIS_UNITS, ResultsTable, factor_label, main_effects
from uwval.rotations import rpy_from_quat

F64 = NDArray[np.float64]

GAZEBO_STYLE: dict[str, Any] = {"color": "#1f77b4", "lw": 1.6, "label": "Gazebo (reference)"}
UNITY_STYLE: dict[str, Any] = {"color": "#d62728", "lw": 1.2, "ls": "--", "label": "Unity"}
AXIS_COLOURS = {
    "x": "#1f77b4",
    "y": "#2ca02c",
    "z": "#9467bd",
    "roll": "#ff7f0e",
    "pitch": "#8c564b",
    "yaw": "#e377c2",
}


class AlignedPair(Protocol):
    """What a per-run plot needs from a ComparisonResult (``uwval.comparison``).

    ``t`` are the common stamps (int64 ns); ``reference``/``other`` the aligned streams in
    ENU/FLU; ``errors`` the signed per-axis error arrays (m for x y z, deg for roll pitch yaw).
    """

    t: NDArray[np.int64]
    reference: PoseStream
    other: PoseStream
    errors: Mapping[str, F64]


#: Strips (inches) kept free at the bottom and top of every figure: the PDF writes the
#: caption into the bottom one and a section heading into the top one, so neither can
#: overlap an axis label (the layout is solved once, for the HTML image, and then frozen).
CAPTION_STRIP_IN = 0.24
HEADING_STRIP_IN = 0.26


def _new_figure(w: float, h: float) -> Figure:
    # Figure() directly (not pyplot): no global state, safe in threads, freed when dropped
    bottom, top = CAPTION_STRIP_IN / h, HEADING_STRIP_IN / h
    engine = ConstrainedLayoutEngine(rect=(0.0, bottom, 1.0, 1.0 - bottom - top))
    return Figure(figsize=(w, h), dpi=100, layout=engine)


def freeze_ticks(fig: Figure) -> None:
    """Pin every axis' tick positions and labels to those of the last draw.

    After the HTML image is rendered, the PDF draws the same figure again; pinned ticks
    skip the locator and formatter work (a third of a redraw) and guarantee both outputs
    show the same ticks. The offset text (e.g. ``1e-16``) is kept.
    """
    from matplotlib.ticker import FixedFormatter, FixedLocator

    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            locs = axis.get_majorticklocs()
            labels = [t.get_text() for t in axis.get_majorticklabels()]
            if len(labels) != len(locs):
                continue
            offset = axis.get_major_formatter().get_offset()
            fixed = FixedFormatter(labels)
            fixed.set_offset_string(offset)
            axis.set_major_locator(FixedLocator(locs.tolist()))
            axis.set_major_formatter(fixed)


def axis_series(stream: PoseStream, ref_rpy_deg: F64 | None = None) -> dict[str, F64]:
    """Per-axis series of a stream: x y z (m) and roll pitch yaw (deg, unwrapped in time).

    With ``ref_rpy_deg`` the angles are shifted by whole turns to sit next to the reference
    (so a 359 deg vs 1 deg pair plots as 359 vs 361, matching the wrapped error of 2 deg).
    """
    rpy = np.degrees(np.unwrap(rpy_from_quat(stream.orientation), axis=0))
    if ref_rpy_deg is not None and len(rpy) == len(ref_rpy_deg) and len(rpy):
        rpy = rpy + 360.0 * np.round((ref_rpy_deg - rpy) / 360.0)
    out = {a: stream.position[:, i] for i, a in enumerate(("x", "y", "z"))}
    out.update({a: rpy[:, i] for i, a in enumerate(("roll", "pitch", "yaw"))})
    return out


def pair_series(pair: AlignedPair) -> tuple[F64, dict[str, F64], dict[str, F64]]:
    """(time in s from the first sample, Gazebo series, Unity series) of an aligned pair."""
    t = np.asarray(pair.t, dtype=np.int64)
    ts = (t - t[0]).astype(np.float64) * 1e-9 if len(t) else np.zeros(0)
    ref = axis_series(pair.reference)
    ref_rpy = np.stack([ref["roll"], ref["pitch"], ref["yaw"]], axis=1)
    oth = axis_series(pair.other, ref_rpy)
    return ts, ref, oth


def _decimate(n: int, max_points: int = 4000) -> slice:
    """A stride that keeps plots light: figures never need more than a few thousand points."""
    return slice(None, None, max(1, math.ceil(n / max_points)))


def trajectory_figure(pair: AlignedPair, title: str = "") -> Figure:
    """Trajectory overlay seen from above (x-y) and from the side (x-z), Gazebo vs Unity."""
    fig = _new_figure(10, 4.4)
    ax_top, ax_side = fig.subplots(1, 2)
    ref, oth = pair.reference.position, pair.other.position
    s = _decimate(len(ref))
    for ax, (i, j), view in ((ax_top, (0, 1), "from above"), (ax_side, (0, 2), "from the side")):
        ax.plot(ref[s, i], ref[s, j], **GAZEBO_STYLE)
        ax.plot(oth[s, i], oth[s, j], **UNITY_STYLE)
        if len(ref):
            ax.plot(ref[0, i], ref[0, j], "o", color="black", ms=5, label="start")
            ax.plot(ref[-1, i], ref[-1, j], "s", color="black", ms=5, label="end")
        ax.set_xlabel("x east (m)")
        ax.set_ylabel("y north (m)" if j == 1 else "z up (m)")
        ax.set_title(f"Trajectory {view}")
        ax.grid(True, alpha=0.3)
        ax.set_aspect("equal", adjustable="datalim")
    ax_top.legend(loc="best", fontsize=8)
    if title:
        fig.suptitle(literal(title))
    return fig


def timeseries_figure(pair: AlignedPair, title: str = "") -> Figure:
    """Per axis: Gazebo and Unity over time (left) and the signed error over time (right)."""
    ts, ref, oth = pair_series(pair)
    s = _decimate(len(ts))
    fig = _new_figure(11, 13)
    axes = fig.subplots(6, 2, sharex=True)
    for row, a in enumerate(AXES):
        unit = AXIS_UNITS[a]
        left, right = axes[row]
        left.plot(ts[s], ref[a][s], **GAZEBO_STYLE)
        left.plot(ts[s], oth[a][s], **UNITY_STYLE)
        left.set_ylabel(f"{a} ({unit})")
        left.grid(True, alpha=0.3)
        err = np.asarray(pair.errors.get(a, oth[a] - ref[a]), dtype=np.float64)
        right.plot(
            ts[s][: len(err[s])],
            err[s],
            color=AXIS_COLOURS[a],
            lw=1.0,
            label="signed error (Unity - Gazebo)",
        )
        right.fill_between(
            ts[s][: len(err[s])],
            np.abs(err[s]),
            color=AXIS_COLOURS[a],
            alpha=0.2,
            label="absolute error",
        )
        right.axhline(0.0, color="black", lw=0.6)
        right.set_ylabel(f"error {a} ({unit})")
        right.grid(True, alpha=0.3)
        if row == 0:
            left.set_title("Pose: Gazebo vs Unity")
            right.set_title("Error: Unity - Gazebo")
            left.legend(loc="best", fontsize=8)
            right.legend(loc="best", fontsize=8)
    axes[-1][0].set_xlabel("time (s)")
    axes[-1][1].set_xlabel("time (s)")
    if title:
        fig.suptitle(literal(title))
    return fig


def scatter_figure(
    pair: AlignedPair, pearson: Mapping[str, float | None] | None = None, title: str = ""
) -> Figure:
    """Unity vs Gazebo per axis with the y = x line and Pearson r (from the compare JSON)."""
    _, ref, oth = pair_series(pair)
    fig = _new_figure(11, 7)
    grid = fig.subplots(2, 3)
    for k, a in enumerate(AXES):
        ax = grid[k // 3][k % 3]
        x, y = ref[a], oth[a]
        s = _decimate(len(x), 3000)
        # Line2D markers draw much faster than a scatter PathCollection, same look
        ax.plot(x[s], y[s], ".", ms=2.5, alpha=0.6, color=AXIS_COLOURS[a], label="samples")
        if len(x):
            lo = float(min(x.min(), y.min()))
            hi = float(max(x.max(), y.max()))
            pad = 0.05 * (hi - lo) if hi > lo else 1e-3
            ax.plot(
                [lo - pad, hi + pad], [lo - pad, hi + pad], color="black", lw=0.8, label="y = x"
            )
        r = (pearson or {}).get(a)
        ax.set_title(f"{a}: r = {r:.5f}" if r is not None else f"{a}: r undefined")
        unit = AXIS_UNITS[a]
        ax.set_xlabel(f"Gazebo {a} ({unit})")
        ax.set_ylabel(f"Unity {a} ({unit})")
        ax.grid(True, alpha=0.3)
        if k == 0:
            ax.legend(loc="best", fontsize=8)
    if title:
        fig.suptitle(literal(title))
    return fig


def box_mae_figure(
    table: ResultsTable,
    factor: str,
    topic: str,
    metric: str = "mae",
    axes: Sequence[str] = AXES,
) -> Figure:
    """Box plots of ``metric`` (default MAE) per level of ``factor``, one panel per axis in
    ``axes`` (the panels of the other axes, e.g. round-off ones, are left out)."""
    fig = _new_figure(11, 6.5)
    grid = fig.subplots(2, 3)
    sub = table.select(metric=metric, topic=topic)
    levels = sorted(
        sub[factor].dropna().unique().tolist(),
        key=lambda v: (0, v) if isinstance(v, (int, float)) else (1, str(v)),
    )
    for k, a in enumerate(AXES):
        ax = grid[k // 3][k % 3]
        if a not in axes:
            ax.set_visible(False)
            continue
        rows = sub[sub["axis"] == a]
        data = [rows.loc[rows[factor] == lv, "value"].dropna().to_numpy() for lv in levels]
        if any(len(d) for d in data):
            ax.boxplot(
                [d if len(d) else np.array([np.nan]) for d in data],
                tick_labels=[_fmt(lv) for lv in levels],
                showmeans=True,
            )
        ax.set_title(f"{metric.upper()} {a}")
        ax.set_xlabel(literal(factor_label(factor)))
        ax.set_ylabel(f"{metric.upper()} ({AXIS_UNITS[a]})")
        ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle(
        literal(f"{topic}: {metric.upper()} per level of {factor} (box: runs; triangle: mean)")
    )
    return fig


def main_effects_figure(table: ResultsTable, topic: str, metric: str = "mae") -> Figure:
    """Main-effects plot: mean ``metric`` per factor level, position axes (m) above and
    rotation axes (deg) below, one column per factor."""
    factors = table.varying_factors() or table.factors
    eff = main_effects(table, metric=metric)
    eff = eff[eff["topic"] == topic]
    ncol = max(1, len(factors))
    fig = _new_figure(max(4.0 * ncol, 6.0), 6.5)
    grid = np.atleast_2d(fig.subplots(2, ncol, squeeze=False))
    for c, f in enumerate(factors):
        for r, group in enumerate((("x", "y", "z"), ("roll", "pitch", "yaw"))):
            ax = grid[r][c]
            for a in group:
                rows = eff[(eff["factor"] == f) & (eff["axis"] == a)]
                if rows.empty:
                    continue
                levels = rows["level"].tolist()
                xs = np.arange(len(levels))
                ax.plot(xs, rows["mean"].to_numpy(), "o-", color=AXIS_COLOURS[a], label=a)
                ax.set_xticks(xs, [_fmt(v) for v in levels])
            ax.set_xlabel(literal(factor_label(f)))
            ax.set_ylabel(f"mean {metric.upper()} ({'m' if r == 0 else 'deg'})")
            ax.grid(True, alpha=0.3)
            if c == 0:
                ax.legend(loc="best", fontsize=8)
    fig.suptitle(literal(f"{topic}: main effects on {metric.upper()}"))
    return fig


BRIDGE_PRIORITY = ("latency", "lag", "drop", "lost", "disconnect", "queue")


def bridge_figure(stats: Mapping[str, Mapping[str, Any]]) -> Figure | None:
    """Bar charts of the numeric bridge statistics per run (latency in ms, drops...)."""
    keys: list[str] = []
    for s in stats.values():
        for k, v in s.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool) and k not in keys:
                keys.append(k)
    if not keys or not stats:
        return None
    # latency, lag and losses first: they are what explains a Unity/Gazebo mismatch
    keys.sort(
        key=lambda k: next(
            (i for i, w in enumerate(BRIDGE_PRIORITY) if w in k), len(BRIDGE_PRIORITY)
        )
    )
    keys = keys[:6]
    runs = list(stats)
    labels = [literal(x) for x in short_run_labels(runs)]
    fig = _new_figure(11, 2.6 * math.ceil(len(keys) / 2))
    grid = np.atleast_2d(fig.subplots(math.ceil(len(keys) / 2), 2, squeeze=False))
    for i, key in enumerate(keys):
        ax = grid[i // 2][i % 2]
        vals = [
            float(stats[r].get(key, np.nan))
            if isinstance(stats[r].get(key), (int, float))
            else np.nan
            for r in runs
        ]
        ax.bar(np.arange(len(runs)), vals, color="#4c72b0")
        ax.set_xticks(np.arange(len(runs)), labels, fontsize=7)
        ax.set_xlabel("run", fontsize=8)
        ax.set_title(literal(key))
        ax.grid(True, axis="y", alpha=0.3)
    for i in range(len(keys), grid.size):
        grid[i // 2][i % 2].set_visible(False)
    fig.suptitle("Bridge statistics per run")
    return fig


def short_run_labels(runs: Sequence[str], max_len: int = 10) -> list[str]:
    """Tick labels for runs: the first '-'-separated part that differs between runs and
    tells them apart ("default-03-force=5_..." -> "03"), else the run names when short,
    else their index. Long names rotated under a bar chart leave no room for the bars."""
    parts = [r.split("-") for r in runs]
    if len(runs) > 1 and len({len(p) for p in parts}) == 1:
        for i in range(len(parts[0])):
            col = [p[i] for p in parts]
            if len(set(col)) == len(runs) and max(len(c) for c in col) <= max_len:
                return col
    if all(len(r) <= max_len for r in runs):
        return list(runs)
    return [str(i) for i in range(len(runs))]


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    return literal(str(v))


def literal(text: str) -> str:
    """``text`` shown as written: matplotlib reads a pair of ``$`` as mathtext (and fails on
    a file name such as ``price_$5_and_$6.mcap``), so user-provided text escapes them."""
    return text.replace("$", r"\$")


def close(figs: Sequence[Figure]) -> None:
    """Release figures' memory (Figure objects made without pyplot need no pyplot.close)."""
    for f in figs:
        f.clear()


#: Error series of a histogram panel: (key in ``pair.errors``, label, unit).
HISTOGRAM_SERIES: tuple[tuple[str, str, str], ...] = (
    *((a, f"error {a}", AXIS_UNITS[a]) for a in AXES),
    ("position_norm", "position error norm", "m"),
    ("rotation_angle", "rotation error angle", "deg"),
)


def error_series(pair: AlignedPair) -> dict[str, F64]:
    """The per-sample errors of a pair: signed x y z (m, ENU world), roll pitch yaw (deg,
    wrapped), ``position_norm`` (m) and ``rotation_angle`` (deg, geodesic). The norm is
    computed from the positions when the pair does not carry it; a missing rotation angle
    stays missing."""
    out = {k: np.asarray(v, dtype=np.float64) for k, v in pair.errors.items()}
    if "position_norm" not in out:
        d = np.asarray(pair.other.position, np.float64) - np.asarray(
            pair.reference.position, np.float64
        )
        out["position_norm"] = np.sqrt(np.sum(d * d, axis=1))
    return out


def histogram_counts(values: F64, bins: int = 40) -> tuple[NDArray[np.int64], F64]:
    """(counts, bin edges) of the finite ``values``: the numbers a histogram panel draws.

    A constant series gets one bin centred on its value (width 1e-9 of its size or 1e-12)
    instead of numpy's unit-wide bin, which would hide a 1e-12 m error in a 1 m bar."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        half = max(abs(lo) * 1e-9, 1e-12)
        counts, edges = np.histogram(v, bins=1, range=(lo - half, hi + half))
    else:
        counts, edges = np.histogram(v, bins=bins)
    return counts.astype(np.int64), edges.astype(np.float64)


def error_histogram_figure(pair: AlignedPair, title: str = "", bins: int = 40) -> Figure:
    """Histograms of the errors: one panel per axis (signed Unity - Gazebo; m for x y z, deg
    for roll pitch yaw), of the position-error norm (m) and of the rotation angle (deg).
    Each panel marks the mean (solid) and the RMSE (dashed, norm and angle only)."""
    errs = error_series(pair)
    fig = _new_figure(11, 6.5)
    # a fixed grid, not the constrained layout: 8 panels of known labels fit as placed,
    # and solving the layout was half of this figure's drawing time
    fig.set_layout_engine(None)
    fig.subplots_adjust(
        left=0.06,
        right=0.99,
        bottom=CAPTION_STRIP_IN / 6.5 + 0.07,
        top=1.0 - HEADING_STRIP_IN / 6.5 - 0.06,
        wspace=0.32,
        hspace=0.42,
    )
    grid = fig.subplots(2, 4)
    colours = {**AXIS_COLOURS, "position_norm": "#17becf", "rotation_angle": "#bcbd22"}
    for k, (key, label, unit) in enumerate(HISTOGRAM_SERIES):
        ax = grid[k // 4][k % 4]
        ax.set_xlabel(f"{label} ({unit})")
        ax.set_ylabel("samples")
        ax.grid(True, alpha=0.3)
        vals = errs.get(key)
        counts, edges = histogram_counts(vals if vals is not None else np.zeros(0), bins)
        if len(counts) == 0:
            ax.set_title(f"{key}: no data")
            continue
        ax.stairs(counts, edges, fill=True, color=colours.get(key, "#4c72b0"), alpha=0.75)
        v = np.asarray(vals, dtype=np.float64)
        v = v[np.isfinite(v)]
        mean = float(v.mean())
        ax.axvline(mean, color="black", lw=1.0, label=f"mean {mean:.3g}")
        if key in ("position_norm", "rotation_angle"):
            rmse = float(np.sqrt(np.mean(v * v)))
            ax.axvline(rmse, color="black", lw=1.0, ls="--", label=f"RMSE {rmse:.3g}")
        ax.set_title(key)
        ax.legend(loc="upper right", fontsize=6)
    if title:
        fig.suptitle(literal(title + ": error histograms (Unity - Gazebo)"))
    return fig


def trajectory_error_figure(
    pair: AlignedPair,
    title: str = "",
    error: str = "position_norm",
    cmap: str = "jet",
    error_in_mm: bool = False,
) -> Figure:
    """The reference trajectory seen from above (x-y, ENU m) coloured by the per-sample
    ``error`` (``position_norm`` in m, or in mm with ``error_in_mm`` as the report shows
    errors; ``rotation_angle`` in deg): evo_ape's ``--plot_mode xy`` colour map. Unity's
    path is drawn thin and grey for context."""
    from matplotlib.collections import LineCollection

    errs = error_series(pair)
    if error not in errs:
        raise KeyError(f"no per-sample error {error!r} in this comparison")
    length = error == "position_norm"
    unit = ("mm" if error_in_mm else "m") if length else "deg"
    what = "position error norm" if length else error.replace("_", " ")
    ref = np.asarray(pair.reference.position, dtype=np.float64)
    oth = np.asarray(pair.other.position, dtype=np.float64)
    e = np.asarray(errs[error], dtype=np.float64) * (1e3 if length and error_in_mm else 1.0)
    s = _decimate(len(ref))
    xy, c = ref[s, :2], e[s]
    fig = _new_figure(8, 6.5)
    ax = fig.subplots()
    ax.plot(oth[s, 0], oth[s, 1], color="#7f7f7f", lw=0.8, ls="--", label="Unity")
    if len(xy) >= 2:
        segs = np.stack([xy[:-1], xy[1:]], axis=1)
        seg_err = 0.5 * (c[:-1] + c[1:])  # a segment's colour: the mean of its two ends
        finite = np.isfinite(seg_err)
        lo = float(np.nanmin(c)) if np.isfinite(c).any() else 0.0
        hi = float(np.nanmax(c)) if np.isfinite(c).any() else 1.0
        lc = LineCollection(list(segs[finite]), cmap=cmap, linewidths=2.2)
        lc.set_array(seg_err[finite])
        lc.set_clim(lo, hi if hi > lo else lo + 1e-12)
        ax.add_collection(lc)
        cb = fig.colorbar(lc, ax=ax)
        cb.set_label(f"{what} ({unit})")
        ax.plot(xy[0, 0], xy[0, 1], "o", color="black", ms=5, label="start")
        ax.plot(xy[-1, 0], xy[-1, 1], "s", color="black", ms=5, label="end")
        ax.autoscale_view()
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"Gazebo trajectory from above, coloured by the {what} ({unit})")
    if title:
        fig.suptitle(literal(title))
    return fig


# ----------------------------------------------------------------------------- at a glance
#: Colour of a threshold line (the gate's bound) in every figure.
THRESHOLD_COLOUR = "#cf222e"


def _fixed_figure(
    w: float, h: float, rows: int, cols: int, head_in: float = 0.0, **adjust: float
) -> tuple[Figure, Any]:
    """A figure with a fixed grid (no layout engine: solving one costs as much as drawing),
    the caption and heading strips of :func:`_new_figure` kept free, and ``head_in``
    inches more under the title (for legends placed above the top panels)."""
    fig = Figure(figsize=(w, h), dpi=100)
    params = dict(left=0.08, right=0.98, wspace=0.25, hspace=0.55)
    params.update(adjust)
    fig.subplots_adjust(
        bottom=CAPTION_STRIP_IN / h + 0.06,
        top=1.0 - (HEADING_STRIP_IN + head_in) / h - 0.05,
        **params,
    )
    return fig, np.atleast_2d(fig.subplots(rows, cols, squeeze=False))


def draw_threshold(
    ax: Any, bound: float, label: str, data_top: float, *, both: bool = False
) -> None:
    """The gate's bound on ``ax``'s y axis (shown units): a dashed line, the axis extended
    to show it, when it lies within 3x the data's scale; else a note at the top that the
    bound is above the scale (a line far above the data would flatten it). ``both``: also
    at -bound (signed errors)."""
    if not math.isfinite(bound):
        return
    top = data_top if math.isfinite(data_top) and data_top > 0 else abs(bound)
    if abs(bound) <= 3.0 * top:
        ax.axhline(bound, color=THRESHOLD_COLOUR, lw=1.2, ls="--", label=label)
        lo, hi = ax.get_ylim()
        ax.set_ylim(min(lo, -1.08 * abs(bound)) if both else lo, max(hi, 1.08 * abs(bound)))
        if both:
            ax.axhline(-bound, color=THRESHOLD_COLOUR, lw=1.2, ls="--")
    else:
        ax.text(
            0.99,
            0.97,
            f"{label}: above this scale",
            transform=ax.transAxes,
            ha="right",
            va="top",
            fontsize=7,
            color=THRESHOLD_COLOUR,
        )


def level_means_figure(
    table: ResultsTable,
    topic: str,
    factors: Sequence[str],
    bounds: Mapping[str, tuple[float, str]],
    skip_axes: Sequence[str] = (),
) -> Figure:
    """Mean MAE per factor level (lines; bars: lowest to highest run) for the position axes
    (mm, left) and the rotation axes (deg, right), one row per factor, with the gate's MAE
    bound drawn as a dashed line. ``bounds``: "position"/"rotation" -> (bound in mm or deg,
    label)."""
    rows = max(1, len(factors))
    fig, grid = _fixed_figure(11, 2.3 * rows + 1.6, rows, 2, head_in=0.4, hspace=0.6)
    sub = table.select(metric="mae", topic=topic)
    groups = (
        ("position", ("x", "y", "z"), 1e3, "mm"),
        ("rotation", ("roll", "pitch", "yaw"), 1.0, "deg"),
    )
    for r, f in enumerate(factors):
        levels = sorted(
            sub[f].dropna().unique().tolist(),
            key=lambda v: (0, v) if isinstance(v, (int, float)) else (1, str(v)),
        )
        xs = np.arange(len(levels))
        for c, (kind, axes, scale, unit) in enumerate(groups):
            ax = grid[r][c]
            top = 0.0
            for a in axes:
                if a in skip_axes:
                    continue
                rows_a = sub[sub["axis"] == a]
                g = rows_a.groupby(f)["value"].agg(["mean", "min", "max"]).reindex(levels) * scale
                mean = g["mean"].to_numpy(dtype=float)
                lo = mean - g["min"].to_numpy(dtype=float)
                hi = g["max"].to_numpy(dtype=float) - mean
                ax.errorbar(xs, mean, yerr=[lo, hi], fmt="o-", color=AXIS_COLOURS[a], label=a,
                            capsize=3, lw=1.2, ms=4)  # fmt: skip
                if np.isfinite(g["max"]).any():
                    top = max(top, float(np.nanmax(g["max"].to_numpy(dtype=float))))
            ax.set_xticks(xs, [_fmt(v) for v in levels])
            ax.set_xlabel(literal(factor_label(f)))
            ax.set_ylabel(f"MAE ({unit})")
            ax.set_ylim(0.0, 1.1 * top if top > 0 else 1.0)
            if kind in bounds:
                bound, label = bounds[kind]
                draw_threshold(ax, bound, label, top)
            ax.grid(True, alpha=0.3)
            if r == 0:  # above the top panels, clear of the data and the bound's note
                ax.legend(
                    loc="lower left",
                    bbox_to_anchor=(0.0, 1.02),
                    fontsize=7,
                    ncol=5,
                    title=f"{kind} axes",
                    title_fontsize=8,
                    frameon=False,
                )
    fig.suptitle(literal(f"{topic}: mean MAE per level (bars: lowest to highest run)"))
    return fig


def error_time_figure(
    pair: AlignedPair, title: str, bounds: Mapping[str, tuple[float, str]]
) -> Figure:
    """Signed error over time: position axes (mm) above, rotation axes (deg) below, with the
    gate's max-|error| bound (``bounds``: "position"/"rotation" -> (bound, label)) drawn at
    +-bound."""
    ts, _, _ = pair_series(pair)
    errs = error_series(pair)
    s = _decimate(len(ts), 3000)
    fig, grid = _fixed_figure(11, 6.3, 2, 1, head_in=0.35, hspace=0.6)
    for r, (kind, axes, scale, unit) in enumerate(
        (
            ("position", ("x", "y", "z"), 1e3, "mm"),
            ("rotation", ("roll", "pitch", "yaw"), 1.0, "deg"),
        )
    ):
        ax = grid[r][0]
        top = 0.0
        for a in axes:
            e = np.asarray(errs.get(a, np.zeros(0)), dtype=np.float64) * scale
            if len(e) == 0:
                continue
            ax.plot(ts[s][: len(e[s])], e[s], color=AXIS_COLOURS[a], lw=0.9, label=a)
            if np.isfinite(e).any():
                top = max(top, float(np.nanmax(np.abs(e))))
        ax.axhline(0.0, color="black", lw=0.5)
        if kind in bounds:
            bound, label = bounds[kind]
            draw_threshold(ax, bound, label, top, both=True)
        ax.set_ylabel(f"Unity - Gazebo ({unit})")
        ax.grid(True, alpha=0.3)
        ax.legend(
            loc="lower left",
            bbox_to_anchor=(0.0, 1.01),
            fontsize=7,
            ncol=5,
            title=f"{kind} error over time",
            title_fontsize=8,
            frameon=False,
        )
    grid[-1][0].set_xlabel("time (s)")
    fig.suptitle(literal(title))
    return fig
