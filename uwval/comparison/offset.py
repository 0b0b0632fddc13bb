"""Clock offset between two streams estimated from the motion itself, and render latency.

The offset is the number of seconds to add to the other stream's stamps so that its motion
lines up with the reference (evo's ``offset_2`` sign). Two stages:

1. coarse: cross-correlation of the speed profiles (|v|, and angular speed when the body
   barely translates) on a uniform grid, via FFT with overlap-normalised lags; speed is
   invariant under every frame convention, so this works before the frame is known.
2. fine: golden-section minimisation of the demeaned squared position error as a function
   of the offset (lerp of the other stream), giving sub-sample precision; the uncertainty is
   the Gauss-Newton standard error sigma / sqrt(sum |v|^2) (it assumes independent residuals,
   so it is optimistic when the residuals are correlated in time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.comparison.stats import median, percentiles
from uwval.errors import AlignmentError
from uwval.posestream import PoseStream
from uwval.rotations import geodesic_angle

F64 = NDArray[np.float64]

_MAX_GRID = 1 << 19  # samples per signal in the coarse search
_MAX_REFINE = 50_000  # reference samples used by the fine search


@dataclass(frozen=True)
class OffsetEstimate:
    """Estimated clock offset (s, add to the other stream's stamps) and its 1-sigma (s)."""

    offset: float
    uncertainty: float
    coarse_offset: float
    correlation: float  # normalised cross-correlation of the speed profiles at the peak
    signal: str  # "velocity", "speed", "angular_speed" or "applied_stamps"
    grid_step: float  # s
    note: str | None = None  # set when the estimate is doubtful (the search could not decide)

    def to_json(self) -> dict[str, Any]:
        return {
            "offset_s": self.offset,
            "uncertainty_s": self.uncertainty,
            "coarse_offset_s": self.coarse_offset,
            "speed_correlation": self.correlation,
            "signal": self.signal,
            "grid_step_s": self.grid_step,
            "method": (
                "median of (other stamp - applied stamp): each Unity frame's own stamp "
                "against the Gazebo stamp it showed, so the estimate absorbs the median "
                "latency"
                if self.signal == "applied_stamps"
                else f"{self.signal} cross-correlation + golden-section least squares"
            ),
            "note": self.note,
            "pinned": self.pinned,
        }

    @property
    def pinned(self) -> bool:
        """Whether the data pin the offset (no doubt was noted: no rival minimum, no flat
        or edge-bound cost curve)."""
        return self.note is None


def _rel_seconds(t: NDArray[np.int64], t0: int) -> F64:
    return np.asarray((t - np.int64(t0)).astype(np.float64) * 1e-9)


def _speed_on_grid(stream: PoseStream, t0: int, dt: float, n: int, angular: bool, span: int) -> F64:
    """Speed (m/s or rad/s) of ``stream`` on the grid t0 + k dt (k < n).

    Poses are resampled on the grid first and differenced over ``span`` grid steps, so a
    sample-and-hold stream (a renderer repeating the last pose) gives a smooth profile
    rather than alternating zeros and spikes.
    """
    ts = _rel_seconds(stream.t, t0)
    grid = np.arange(n, dtype=np.float64) * dt
    k = max(1, min(span, n // 4))
    if angular:
        idx = np.clip(np.searchsorted(ts, grid), 0, len(ts) - 1)
        q = stream.orientation[idx]
        mag = geodesic_angle(q[k:], q[:-k]) / (k * dt)
    else:
        pos = np.column_stack([np.interp(grid, ts, stream.position[:, j]) for j in range(3)])
        mag = np.linalg.norm(pos[k:] - pos[:-k], axis=1) / (k * dt)
    # centre the difference quotient on its interval
    return np.asarray(np.interp(grid, grid[:-k] + 0.5 * k * dt, mag))


def _velocity_on_grid(stream: PoseStream, t0: int, dt: float, n: int, span: int) -> F64:
    """(n, 3) velocity (m/s) on the grid t0 + k dt, differenced over ``span`` steps."""
    ts = _rel_seconds(stream.t, t0)
    grid = np.arange(n, dtype=np.float64) * dt
    k = max(1, min(span, n // 4))
    pos = np.column_stack([np.interp(grid, ts, stream.position[:, j]) for j in range(3)])
    vel = (pos[k:] - pos[:-k]) / (k * dt)
    mid = grid[:-k] + 0.5 * k * dt
    return np.column_stack([np.interp(grid, mid, vel[:, j]) for j in range(3)])


def _grid(stream: PoseStream, dt: float) -> int:
    return max(2, math.floor(stream.duration / dt) + 1)


def estimate_offset(
    reference: PoseStream,
    other: PoseStream,
    *,
    max_offset: float | None = None,
    same_frame: bool = True,
) -> OffsetEstimate:
    """Estimate the clock offset of ``other`` relative to ``reference`` from their motion.

    With ``same_frame`` (both streams in one convention) the coarse stage matches velocity
    vectors (least mean squared difference per lag, sharp even for smooth motion); otherwise
    it correlates the frame-invariant speed profiles. ``max_offset`` (s) bounds the search.
    Raises :class:`AlignmentError` when the streams do not move enough to tell.
    """
    if len(reference) < 4 or len(other) < 4:
        raise AlignmentError("offset estimation needs at least 4 poses in each stream")
    if max_offset is not None and not max_offset > 0:  # NaN fails too
        raise AlignmentError(
            f"max_offset must be a positive number of seconds (or none), got {max_offset}"
        )
    from_stamps = _offset_from_applied_stamps(reference, other, max_offset)
    if from_stamps is not None:
        return from_stamps
    per_ref = float(np.median(np.diff(reference.t))) * 1e-9
    per_oth = float(np.median(np.diff(other.t))) * 1e-9
    dt = min(per_ref, per_oth)
    longest = max(reference.duration, other.duration)
    dt = max(dt, longest / _MAX_GRID)
    n_ref, n_oth = _grid(reference, dt), _grid(other, dt)
    t0_ref, t0_oth = int(reference.t[0]), int(other.t[0])

    # difference over ~4 periods of the slower stream: smooths sample-and-hold steps
    span = max(1, round(4 * max(per_ref, per_oth) / dt))
    # a bound beyond int64 nanoseconds bounds nothing (and would overflow the lag arithmetic)
    max_lag = None if max_offset is None or max_offset > 4.6e9 else int(max_offset / dt) + 1
    base = (t0_ref - t0_oth) * 1e-9 / dt
    va = _velocity_on_grid(reference, t0_ref, dt, n_ref, span)
    vb = _velocity_on_grid(other, t0_oth, dt, n_oth, span)
    moving = float(np.abs(va).max()) > 1e-9 and float(np.abs(vb).max()) > 1e-9
    if same_frame and moving:
        _refuse_unexcited(va, vb)
        lag, corr, rival, depth = _best_lag_mse(va, vb, max_lag, base)
        if depth < MIN_COST_DEPTH:
            raise AlignmentError(
                "cannot estimate the clock offset from the motion: no offset fits clearly "
                f"better than the others (the best lowers the velocity mismatch by only "
                f"{depth * 100:.0f} % of its typical value), so any answer would be a guess; "
                "give --offset S (the known clock offset) or log applied stamps"
            )
        coarse = (t0_ref - t0_oth) * 1e-9 + lag * dt
        overlap = min(reference.duration, other.duration)
        window = max(2 * max(dt, per_oth, per_ref) * span, 0.005 * overlap)
        fine, sigma, note = _refine(reference, other, coarse, window)
        if rival is not None:
            other_s = (t0_ref - t0_oth) * 1e-9 + rival * dt
            note = (
                f"--offset auto is NOT pinned: the motion repeats, offsets {coarse:.10g} s and "
                f"{other_s:.10g} s fit almost equally well, so the estimate may be wrong by "
                f"{abs(other_s - coarse):.6g} s; give --offset S or bound the search with "
                "--max-offset S" + (f" ({note})" if note else "")
            )
            # the honest uncertainty is the distance to the rival, not the local curvature
            sigma = max(sigma, abs(other_s - coarse))
        return OffsetEstimate(fine, sigma, coarse, corr, "velocity", dt, note)
    signal = "speed"
    a = _speed_on_grid(reference, t0_ref, dt, n_ref, False, span)
    b = _speed_on_grid(other, t0_oth, dt, n_oth, False, span)
    if float(np.std(a)) < 1e-9 or float(np.std(b)) < 1e-9:
        signal = "angular_speed"
        a = _speed_on_grid(reference, t0_ref, dt, n_ref, True, span)
        b = _speed_on_grid(other, t0_oth, dt, n_oth, True, span)
    if 0.0 < _excitation(a[:, None]) < MIN_EXCITATION and _excitation(b[:, None]) > 0.0:
        raise AlignmentError(
            "cannot estimate the clock offset from the motion: the reference's speed is "
            "almost constant, so every offset fits about as well; give --offset S (the "
            "known clock offset) or log applied stamps"
        )
    if float(np.std(a)) < 1e-12 or float(np.std(b)) < 1e-12:
        raise AlignmentError(
            "cannot estimate a clock offset: the speed profile of "
            f"{'the reference' if float(np.std(a)) < 1e-12 else 'the other stream'} is constant"
        )
    # remove slow trends (moving average over ~2 s): sharpens the correlation peak of
    # slowly varying speed profiles
    width = max(3, round(2.0 / dt))
    a, b = _highpass(a, width), _highpass(b, width)
    lag, corr = _best_lag(a, b, max_lag=max_lag, base=base)
    # other sample k lines up with reference sample k + lag:
    # t_oth0 + k dt + offset = t_ref0 + (k + lag) dt
    coarse = (t0_ref - t0_oth) * 1e-9 + lag * dt
    overlap = min(reference.duration, other.duration)
    window = max(2 * max(dt, per_oth, per_ref) * span, 0.02 * overlap)
    fine, sigma, note = _refine(reference, other, coarse, window)
    return OffsetEstimate(fine, sigma, coarse, corr, signal, dt, note)


def _offset_from_applied_stamps(
    reference: PoseStream, other: PoseStream, max_offset: float | None
) -> OffsetEstimate | None:
    """The offset from the recorded clocks, when the other stream carries applied stamps.

    Each Unity frame records the header stamp of the Gazebo pose it showed (on the
    reference's clock) beside its own stamp (on Unity's clock): their difference is the clock
    offset plus that frame's latency, whatever the motion (a vehicle at constant speed gives
    the motion-based search nothing to lock on). Used when most applied stamps fall inside the
    reference's time span (the two are on one clock); None otherwise, or when fewer than 4
    frames have one. The differences are taken in integer nanoseconds (no float rounding at
    epoch size); the offset is then returned in float seconds (~0.2 us at 1.8e9 s).
    """
    applied = other.applied_stamp
    if applied is None or len(reference) < 2:
        return None
    inside = (applied >= reference.t[0]) & (applied <= reference.t[-1])
    n = int(inside.sum())
    if n < 4 or n < 0.5 * len(other):
        return None
    d = np.sort(other.t[inside] - applied[inside])  # int64 ns: offset + latency per frame
    med = int(d[n // 2]) if n % 2 else (int(d[n // 2 - 1]) + int(d[n // 2])) // 2
    offset = -med * 1e-9
    if max_offset is not None and abs(offset) > max_offset:
        return None  # outside the allowed bound: let the motion decide within it
    mad = float(np.median(np.abs(d - med))) * 1e-9
    sigma = 1.2533 * 1.4826 * mad / math.sqrt(n)  # standard error of a median
    return OffsetEstimate(offset, sigma, offset, 1.0, "applied_stamps", 0.0, None)


def _lag_axis(na: int, nb: int, size: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Lags L (a[k + L] against b[k]) and their indices in a circular correlation."""
    lags = np.concatenate([np.arange(0, na), np.arange(-(nb - 1), 0)])
    where = np.where(lags >= 0, lags, size + lags)
    return lags, where


def _best_lag_mse(
    a: F64, b: F64, max_lag: int | None, base: float
) -> tuple[int, float, int | None, float]:
    """Lag L minimising the mean of |a[k + L] - b[k]|^2 over the overlap (vector signals).

    Cross terms by FFT, squared norms over each overlap by cumulative sums: O(n log n).
    Returns the lag, the correlation-like score 1 - mse / (mean|a|^2 + mean|b|^2), a
    rival lag that fits almost as well (see :func:`_rival_lag`), if any, and the depth of
    the best minimum: (median mse over the allowed lags - best) / median (near 1 for a sharp
    minimum, near 0 when every lag fits about as well: the motion cannot pin the offset).
    """
    na, nb = a.shape[0], b.shape[0]
    size = 1 << math.ceil(math.log2(na + nb))
    cc = np.zeros(size)
    for j in range(a.shape[1]):
        cc += np.fft.irfft(np.fft.rfft(a[:, j], size) * np.conj(np.fft.rfft(b[:, j], size)), size)
    lags, where = _lag_axis(na, nb, size)
    cross = cc[where]
    ca = np.concatenate(([0.0], np.cumsum(np.einsum("ij,ij->i", a, a))))
    cb = np.concatenate(([0.0], np.cumsum(np.einsum("ij,ij->i", b, b))))
    k_lo = np.maximum(0, -lags)
    k_hi = np.minimum(nb, na - lags)  # exclusive
    overlap = k_hi - k_lo
    ok = overlap >= max(3, int(0.3 * min(na, nb)))
    if max_lag is not None:
        ok &= np.abs(lags + base) <= max_lag
    if not ok.any():
        raise AlignmentError("offset search range leaves no overlap between the streams")
    k_hi_c = np.maximum(k_hi, k_lo)
    sa = ca[k_hi_c + lags] - ca[k_lo + lags]
    sb = cb[k_hi_c] - cb[k_lo]
    cnt = np.maximum(overlap, 1)
    mse = np.where(ok, (sa + sb - 2.0 * cross) / cnt, np.inf)
    j = int(np.argmin(mse))
    scale = max(1e-300, float((sa[j] + sb[j]) / cnt[j]))
    score = 1.0 - float(mse[j]) / scale
    typical = median(mse[ok])
    depth = (typical - float(mse[j])) / typical if typical > 0 else 0.0
    return int(lags[j]), score, _rival_lag(lags, mse, j, scale), depth


def _rival_lag(lags: NDArray[np.int64], mse: F64, j: int, scale: float) -> int | None:
    """Another lag that fits almost as well as lag ``j`` (the motion repeats), or None.

    A rival is a lag whose mean squared difference is within 5 % of ``scale`` (the mean
    squared velocity) of the best one and that is separated from it by a barrier at least
    20 % of ``scale`` high: a second valley, not the shoulder of the best one.
    """
    order = np.argsort(lags)
    m = mse[order]
    jb = int(np.flatnonzero(order == j)[0])
    best = float(m[jb])
    right = np.maximum.accumulate(m[jb:])  # highest point between the best lag and each lag
    left = np.maximum.accumulate(m[jb::-1])
    barrier = np.concatenate((left[:0:-1], right))
    with np.errstate(invalid="ignore"):  # inf - inf outside the allowed lags
        near = (m - best <= 0.05 * scale) & (barrier - m >= 0.2 * scale) & np.isfinite(m)
    if not near.any():
        return None
    k = int(np.flatnonzero(near)[np.argmin(m[near])])
    return int(lags[order[k]])


#: Below this excitation (:func:`_excitation`) the reference moves at an almost constant
#: velocity: shifting it in time only shifts it in space, which the search cannot see.
MIN_EXCITATION = 1e-3
#: Below this depth of the best minimum of the velocity mismatch (:func:`_best_lag_mse`)
#: no offset fits clearly better than the others.
MIN_COST_DEPTH = 0.5


def _refuse_unexcited(va: F64, vb: F64) -> None:
    """An AlignmentError when the reference (or the other) velocity barely changes."""
    for name, v in (("reference", va), ("other stream", vb)):
        ex = _excitation(v)
        if ex < MIN_EXCITATION:
            raise AlignmentError(
                f"cannot estimate the clock offset from the motion: the {name} moves at an "
                f"almost constant velocity (it varies by {math.sqrt(ex) * 100:.2g} % of its "
                "size), and a time shift of such a motion is only a shift in space, so every "
                "offset fits about as well; give --offset S (the known clock offset) or log "
                "applied stamps"
            )


def _excitation(v: F64) -> float:
    """How much a velocity signal (n, k) changes: the variance of its components around
    their means over its mean squared norm (0 for a constant velocity, ~1 for a motion
    that goes back and forth)."""
    total = float(np.einsum("ij,ij->", v, v))
    if total <= 0.0:
        return 0.0
    c = v - v.mean(axis=0)
    return float(np.einsum("ij,ij->", c, c)) / total


def _highpass(x: F64, width: int) -> F64:
    """``x`` minus its centred moving average over ``width`` samples (edges: shorter windows)."""
    if x.size < 3 * width:
        return x
    c = np.concatenate(([0.0], np.cumsum(x)))
    i = np.arange(x.size)
    lo = np.clip(i - width // 2, 0, x.size)
    hi = np.clip(i + width // 2 + 1, 0, x.size)
    return np.asarray(x - (c[hi] - c[lo]) / (hi - lo))


def _best_lag(a: F64, b: F64, max_lag: int | None, base: float) -> tuple[int, float]:
    """Lag L maximising the overlap-normalised correlation sum_k a[k + L] b[k]."""
    na, nb = a.size, b.size
    size = 1 << math.ceil(math.log2(na + nb))
    za = a - a.mean()
    zb = b - b.mean()
    fa = np.fft.rfft(za, size)
    fb = np.fft.rfft(zb, size)
    cc = np.fft.irfft(fa * np.conj(fb), size)
    # circular index j holds lag L = j for j < na and L = j - size for negative lags
    lags = np.concatenate([np.arange(0, na), np.arange(-(nb - 1), 0)])
    vals = np.concatenate([cc[:na], cc[size - (nb - 1) :]])
    # overlap of a[L:] and b[:]: number of k with 0 <= k < nb and 0 <= k + L < na
    overlap = np.minimum(na, lags + nb) - np.maximum(0, lags)
    min_overlap = max(3, int(0.3 * min(na, nb)))
    ok = overlap >= min_overlap
    if max_lag is not None:
        # bound |offset| = |base + L| (in grid steps)
        ok &= np.abs(lags + base) <= max_lag
    if not ok.any():
        raise AlignmentError("offset search range leaves no overlap between the streams")
    norm = float(np.sqrt(np.dot(za, za) / na * np.dot(zb, zb) / nb))
    score = np.where(ok, vals / np.maximum(overlap, 1) / norm, -np.inf)
    j = int(np.argmax(score))
    return int(lags[j]), float(score[j])


def _position_cost(ref_t: F64, ref_p: F64, oth_t: F64, oth_p: F64, offset: float) -> float:
    """Mean squared demeaned position error with the other stream shifted by ``offset``."""
    tq = ref_t - offset
    # ref_t is sorted: the overlap is one slice, found by two binary searches
    lo = int(np.searchsorted(tq, oth_t[0], side="left"))
    hi = int(np.searchsorted(tq, oth_t[-1], side="right"))
    m = hi - lo
    if m < 4:
        return math.inf
    tq = tq[lo:hi]
    # one search for all three axes (np.interp would search once per axis), then lerp
    k = np.clip(np.searchsorted(oth_t, tq, side="right"), 1, len(oth_t) - 1)
    t0, t1 = oth_t[k - 1], oth_t[k]
    w = ((tq - t0) / np.where(t1 > t0, t1 - t0, 1.0))[:, None]
    p0 = oth_p[k - 1]
    e = p0 + w * (oth_p[k] - p0) - ref_p[lo:hi]
    e -= e.mean(axis=0)
    return float(np.einsum("ij,ij->", e, e)) / m


#: The window scan uses every ``_SCAN_THIN``-th reference sample (when that leaves at least
#: ``_SCAN_MIN``): it only picks the cell the golden section then refines on all of them.
_SCAN_THIN = 10
_SCAN_MIN = 2_000

#: Golden-section steps at most (each shrinks the bracket by 0.618: 80 steps reach 1e-17 of
#: the scan cell, far below any tolerance, so the cap only guards against a stalled bracket).
_MAX_GOLDEN_STEPS = 80


def _refine(
    reference: PoseStream, other: PoseStream, coarse: float, window: float
) -> tuple[float, float, str | None]:
    """Scan of the position cost on [coarse - window, coarse + window], then golden section.

    Works on the residual ``delta = offset - coarse``: the other stream's stamps are moved by
    the coarse offset in integer nanoseconds first, so an offset of any size (epoch against
    monotonic clocks, ~1.8e9 s) keeps full float precision and the search ends in a bounded
    number of steps. Returns (offset s, 1-sigma s, note or None when it cannot decide).
    """
    t0 = int(reference.t[0])
    coarse_ns = round(coarse * 1e9)
    step = max(1, len(reference) // _MAX_REFINE)
    ref_t = _rel_seconds(reference.t[::step], t0)
    ref_p = reference.position[::step]
    # other stamps on the reference clock at the coarse offset, relative to t0 (int64 first)
    oth_t = np.asarray((other.t - np.int64(t0 - coarse_ns)).astype(np.float64) * 1e-9)
    oth_p = other.position
    base = coarse - coarse_ns * 1e-9  # the part of coarse below a nanosecond

    def cost(delta: float) -> float:
        return _position_cost(ref_t, ref_p, oth_t, oth_p, delta + base)

    # the scan only has to find the best cell: a tenth of the samples is plenty
    scan_t, scan_p = ref_t[::_SCAN_THIN], ref_p[::_SCAN_THIN]
    if len(scan_t) < _SCAN_MIN:
        scan_t, scan_p = ref_t, ref_p

    def scan_cost(delta: float) -> float:
        return _position_cost(scan_t, scan_p, oth_t, oth_p, delta + base)

    # scan (the coarse stage is only good to its smoothing span), then golden-section
    # inside the best scan cell
    scan = np.linspace(-window, window, 121)
    costs = np.array([scan_cost(float(x)) for x in scan])
    if not np.isfinite(costs).any():
        return (
            coarse,
            window,
            (
                "the fine offset search found no overlap around the coarse estimate: "
                f"offset {coarse:.9g} s is only good to +-{window:.3g} s"
            ),
        )
    j = int(np.argmin(costs))
    cell = float(scan[1] - scan[0])
    lo, hi = float(scan[j]) - cell, float(scan[j]) + cell
    g = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = cost(x1), cost(x2)
    tol = max(1e-9, 1e-6 * cell)
    for _ in range(_MAX_GOLDEN_STEPS):
        if hi - lo <= tol:
            break
        if f1 <= f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - g * (hi - lo)
            f1 = cost(x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + g * (hi - lo)
            f2 = cost(x2)
    delta = 0.5 * (lo + hi)
    best = coarse_ns * 1e-9 + (delta + base)
    note = None
    finite = costs[np.isfinite(costs)]
    if j in (0, scan.size - 1):
        note = (
            f"the offset search ended at the edge of its window (+-{window:.3g} s around "
            f"{coarse:.9g} s): the estimate {best:.9g} s may be wrong; give --offset S"
        )
    elif float(finite.max() - finite.min()) <= 1e-12 * max(1.0, float(finite.max())):
        note = (
            "the position error does not change with the offset near the estimate "
            f"({best:.9g} s): the motion cannot tell the offset; give --offset S"
        )
    if not math.isfinite(cost(delta)):
        return coarse, window, note
    # Gauss-Newton standard error: residual derivative wrt offset is -velocity of other
    tq = ref_t - (delta + base)
    ok = (tq >= oth_t[0]) & (tq <= oth_t[-1])
    e = np.column_stack([np.interp(tq[ok], oth_t, oth_p[:, j]) for j in range(3)]) - ref_p[ok]
    e -= e.mean(axis=0)
    vel = np.gradient(oth_p, oth_t, axis=0)
    v = np.column_stack([np.interp(tq[ok], oth_t, vel[:, j]) for j in range(3)])
    v -= v.mean(axis=0)
    m = int(ok.sum())
    sigma2 = float(np.einsum("ij,ij->", e, e)) / max(1, 3 * m - 4)
    info = float(np.einsum("ij,ij->", v, v))
    if info <= 0.0:
        return (
            best,
            math.inf,
            note
            or (
                "the other stream does not move where it overlaps: "
                f"offset {best:.9g} s is undecided"
            ),
        )
    return best, math.sqrt(sigma2 / info), note


def latency_stats(
    other: PoseStream, offset_s: float = 0.0, within_ns: tuple[int, int] | None = None
) -> dict[str, Any] | None:
    """Latency (ms) from the reference stamp a Unity frame showed to the frame's own stamp.

    Needs ``other.applied_stamp`` (reference clock); ``offset_s`` converts the other clock
    to the reference clock first. ``within_ns``: the reference stream's span (ns, reference
    clock); frames outside it are not counted (after the last reference pose a frame still
    shows it, ever older: not a latency) and are reported as ``n_outside``. None when the
    stream carries no applied stamps or no frame falls in the span.
    """
    if other.applied_stamp is None or len(other) == 0:
        return None
    lat_ns = (other.t - other.applied_stamp).astype(np.float64) + offset_s * 1e9
    n_outside = 0
    if within_ns is not None:
        t_ref = other.t.astype(np.float64) + offset_s * 1e9
        inside = (t_ref >= within_ns[0]) & (t_ref <= within_ns[1])
        n_outside = int(lat_ns.size - np.count_nonzero(inside))
        lat_ns = lat_ns[inside]
        if lat_ns.size == 0:
            return None
    lat = lat_ns * 1e-6
    return {
        "n": int(lat.size),
        "n_outside": n_outside,
        "mean_ms": float(lat.mean()),
        "median_ms": median(lat),
        "std_ms": float(lat.std()),
        "min_ms": float(lat.min()),
        "max_ms": float(lat.max()),
        "p95_ms": percentiles(lat, (95.0,))[0],
        "offset_applied_s": offset_s,
    }


#: Windows of the lag's trend over a run (drift from the motion): at most this many, each
#: at least DRIFT_WINDOW_MIN_S long; fewer than DRIFT_MIN_WINDOWS moving windows pin nothing.
DRIFT_MAX_WINDOWS = 20
DRIFT_WINDOW_MIN_S = 5.0
DRIFT_MIN_WINDOWS = 4
#: A drift is removed (and warned about) only when it is this many standard errors from 0.
DRIFT_SIGNIFICANCE = 3.0


@dataclass(frozen=True)
class DriftFit:
    """The other clock's rate error against the reference clock.

    ``ppm``: parts per million (> 0: the other clock runs fast, its stamps run ahead by
    ``ppm * 1e-6`` s per second); ``se_ppm`` its standard error; ``source``:
    ``applied_stamps`` (the other stamp minus the reference stamp it showed, against time)
    or ``motion`` (the trend of the lag fitted in windows); ``n`` the points of the fit.
    """

    ppm: float
    se_ppm: float
    source: str
    n: int

    @property
    def significant(self) -> bool:
        """Whether the drift stands out from its own uncertainty (and is removed)."""
        return bool(abs(self.ppm) > DRIFT_SIGNIFICANCE * self.se_ppm)

    @property
    def removed_ppm(self) -> float:
        """The drift compare removes: the fitted one when significant, else 0."""
        return self.ppm if self.significant else 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "fitted_ppm": self.ppm,
            "se_ppm": self.se_ppm,
            "source": self.source,
            "n": self.n,
            "removed": self.significant,
        }


def _line_fit(x: F64, y: F64) -> tuple[float, float]:
    """Least-squares slope of y on x and its standard error (units of y per unit of x)."""
    n = x.size
    xc = x - x.mean()
    sxx = float(np.dot(xc, xc))
    if n < 3 or sxx <= 0.0:
        return math.nan, math.inf
    slope = float(np.dot(xc, y - y.mean())) / sxx
    resid = y - y.mean() - slope * xc
    se = math.sqrt(float(np.dot(resid, resid)) / (n - 2) / sxx)
    return slope, se


def drift_from_applied_stamps(reference: PoseStream, other: PoseStream) -> DriftFit | None:
    """Drift from the recorded clocks: (other stamp - applied reference stamp) grows by the
    drift per second of the run, whatever the motion. None without applied stamps on the
    reference's clock (most inside its span) or with fewer than 8 of them."""
    applied = other.applied_stamp
    if applied is None or len(reference) < 2:
        return None
    inside = (applied >= reference.t[0]) & (applied <= reference.t[-1])
    n = int(inside.sum())
    if n < 8 or n < 0.5 * len(other):
        return None
    u = other.t[inside]
    x = (u - u[0]).astype(np.float64) * 1e-9
    d = (u - applied[inside]).astype(np.float64) * 1e-9
    slope, se = _line_fit(x, d)
    if not math.isfinite(slope):
        return None
    return DriftFit(slope * 1e6, se * 1e6, "applied_stamps", n)


def drift_from_motion(t_s: F64, reference_xyz: F64, other_xyz: F64) -> DriftFit | None:
    """Drift from the motion: the lag (:mod:`uwval.comparison.lag`) fitted in equal windows
    of the aligned samples (t_s seconds, positions m, drift not removed) grows by the drift
    per second. None when fewer than DRIFT_MIN_WINDOWS windows move enough to fit a lag."""
    from uwval.comparison.lag import MIN_SPEED, lag_least_squares, rates

    t = np.asarray(t_s, dtype=np.float64)
    if t.size < 16:
        return None
    duration = float(t[-1] - t[0])
    n_win = min(DRIFT_MAX_WINDOWS, int(duration // DRIFT_WINDOW_MIN_S))
    if n_win < DRIFT_MIN_WINDOWS:
        return None
    vel = rates(t, np.asarray(reference_xyz, dtype=np.float64))
    err = np.asarray(other_xyz, dtype=np.float64) - reference_xyz
    edges = np.searchsorted(t, t[0] + duration * np.arange(n_win + 1) / n_win)
    mids, lags = [], []
    for k in range(n_win):  # a handful of windows, each vectorised
        lo, hi = int(edges[k]), int(edges[k + 1])
        v, e = vel[lo:hi], err[lo:hi]
        if hi - lo < 8 or float(np.sqrt((v * v).sum() / v.shape[0])) <= MIN_SPEED["position"]:
            continue
        mids.append(float(t[lo:hi].mean()))
        lags.append(lag_least_squares(v, e))
    if len(lags) < DRIFT_MIN_WINDOWS:
        return None
    slope, se = _line_fit(np.array(mids), np.array(lags))
    if not math.isfinite(slope):
        return None
    return DriftFit(slope * 1e6, se * 1e6, "motion", len(lags))


def remove_drift(stream: PoseStream, ppm: float) -> PoseStream:
    """``stream`` with its stamps' drift removed: t' = t - ppm 1e-6 (t - t[0]) (int64 ns;
    applied stamps, on the reference clock, are kept)."""
    if ppm == 0.0 or len(stream) < 2:
        return stream
    rel = (stream.t - stream.t[0]).astype(np.float64)
    t = stream.t - np.round(rel * (ppm * 1e-6)).astype(np.int64)
    return stream.with_(t=t)
