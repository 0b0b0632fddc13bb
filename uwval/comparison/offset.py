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
    signal: str  # "speed" or "angular_speed"
    grid_step: float  # s

    def to_json(self) -> dict[str, Any]:
        return {
            "offset_s": self.offset,
            "uncertainty_s": self.uncertainty,
            "coarse_offset_s": self.coarse_offset,
            "speed_correlation": self.correlation,
            "signal": self.signal,
            "grid_step_s": self.grid_step,
            "method": f"{self.signal} cross-correlation + golden-section least squares",
        }


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
    per_ref = float(np.median(np.diff(reference.t))) * 1e-9
    per_oth = float(np.median(np.diff(other.t))) * 1e-9
    dt = min(per_ref, per_oth)
    longest = max(reference.duration, other.duration)
    dt = max(dt, longest / _MAX_GRID)
    n_ref, n_oth = _grid(reference, dt), _grid(other, dt)
    t0_ref, t0_oth = int(reference.t[0]), int(other.t[0])

    # difference over ~4 periods of the slower stream: smooths sample-and-hold steps
    span = max(1, round(4 * max(per_ref, per_oth) / dt))
    max_lag = None if max_offset is None else int(max_offset / dt) + 1
    base = (t0_ref - t0_oth) * 1e-9 / dt
    va = _velocity_on_grid(reference, t0_ref, dt, n_ref, span)
    vb = _velocity_on_grid(other, t0_oth, dt, n_oth, span)
    moving = float(np.abs(va).max()) > 1e-9 and float(np.abs(vb).max()) > 1e-9
    if same_frame and moving:
        lag, corr = _best_lag_mse(va, vb, max_lag, base)
        coarse = (t0_ref - t0_oth) * 1e-9 + lag * dt
        overlap = min(reference.duration, other.duration)
        window = max(2 * max(dt, per_oth, per_ref) * span, 0.005 * overlap)
        fine, sigma = _refine(reference, other, coarse, window)
        return OffsetEstimate(fine, sigma, coarse, corr, "velocity", dt)
    signal = "speed"
    a = _speed_on_grid(reference, t0_ref, dt, n_ref, False, span)
    b = _speed_on_grid(other, t0_oth, dt, n_oth, False, span)
    if float(np.std(a)) < 1e-9 or float(np.std(b)) < 1e-9:
        signal = "angular_speed"
        a = _speed_on_grid(reference, t0_ref, dt, n_ref, True, span)
        b = _speed_on_grid(other, t0_oth, dt, n_oth, True, span)
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
    fine, sigma = _refine(reference, other, coarse, window)
    return OffsetEstimate(fine, sigma, coarse, corr, signal, dt)


def _lag_axis(na: int, nb: int, size: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Lags L (a[k + L] against b[k]) and their indices in a circular correlation."""
    lags = np.concatenate([np.arange(0, na), np.arange(-(nb - 1), 0)])
    where = np.where(lags >= 0, lags, size + lags)
    return lags, where


def _best_lag_mse(a: F64, b: F64, max_lag: int | None, base: float) -> tuple[int, float]:
    """Lag L minimising the mean of |a[k + L] - b[k]|^2 over the overlap (vector signals).

    Cross terms by FFT, squared norms over each overlap by cumulative sums: O(n log n).
    Returns the lag and the correlation-like score 1 - mse / (mean|a|^2 + mean|b|^2).
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
    score = 1.0 - float(mse[j]) / max(1e-300, float((sa[j] + sb[j]) / cnt[j]))
    return int(lags[j]), score


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
    ok = (tq >= oth_t[0]) & (tq <= oth_t[-1])
    if ok.sum() < 4:
        return math.inf
    e = np.column_stack([np.interp(tq[ok], oth_t, oth_p[:, j]) for j in range(3)]) - ref_p[ok]
    e -= e.mean(axis=0)
    return float(np.einsum("ij,ij->", e, e)) / int(ok.sum())


def _refine(
    reference: PoseStream, other: PoseStream, coarse: float, window: float
) -> tuple[float, float]:
    """Scan of the position cost on [coarse - window, coarse + window], then golden section."""
    t0 = int(reference.t[0])
    step = max(1, len(reference) // _MAX_REFINE)
    ref_t = _rel_seconds(reference.t[::step], t0)
    ref_p = reference.position[::step]
    oth_t = _rel_seconds(other.t, t0)
    oth_p = other.position
    # scan (the coarse stage is only good to its smoothing span), then golden-section
    # inside the best scan cell
    scan = coarse + np.linspace(-window, window, 121)
    costs = [_position_cost(ref_t, ref_p, oth_t, oth_p, float(x)) for x in scan]
    j = int(np.argmin(costs))
    cell = scan[1] - scan[0]
    lo, hi = float(scan[j]) - cell, float(scan[j]) + cell
    g = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1 = _position_cost(ref_t, ref_p, oth_t, oth_p, x1)
    f2 = _position_cost(ref_t, ref_p, oth_t, oth_p, x2)
    tol = max(1e-9, 1e-6 * cell)
    while hi - lo > tol:
        if f1 <= f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - g * (hi - lo)
            f1 = _position_cost(ref_t, ref_p, oth_t, oth_p, x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + g * (hi - lo)
            f2 = _position_cost(ref_t, ref_p, oth_t, oth_p, x2)
    best = 0.5 * (lo + hi)
    if not math.isfinite(_position_cost(ref_t, ref_p, oth_t, oth_p, best)):
        return coarse, window
    # Gauss-Newton standard error: residual derivative wrt offset is -velocity of other
    tq = ref_t - best
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
        return best, math.inf
    return best, math.sqrt(sigma2 / info)


def latency_stats(other: PoseStream, offset_s: float = 0.0) -> dict[str, Any] | None:
    """Latency (ms) from the reference stamp a Unity frame showed to the frame's own stamp.

    Needs ``other.applied_stamp`` (reference clock); ``offset_s`` converts the other clock
    to the reference clock first. None when the stream carries no applied stamps.
    """
    if other.applied_stamp is None or len(other) == 0:
        return None
    lat_ns = (other.t - other.applied_stamp).astype(np.float64) + offset_s * 1e9
    lat = lat_ns * 1e-6
    return {
        "n": int(lat.size),
        "mean_ms": float(lat.mean()),
        "median_ms": float(np.median(lat)),
        "std_ms": float(lat.std()),
        "min_ms": float(lat.min()),
        "max_ms": float(lat.max()),
        "p95_ms": float(np.percentile(lat, 95)),
        "offset_applied_s": offset_s,
    }
