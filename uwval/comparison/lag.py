"""The lag between the two streams, fitted from the poses alone, and what it explains.

A renderer that shows a physics simulator's pose ``L`` seconds late makes an error
``other(t) - reference(t) = reference(t - L) - reference(t) ~ -L v(t)``: the error is the
velocity times the lag. :func:`fit_lag` fits that model by least squares without an
intercept (a constant error is what a lag makes at constant velocity, so an intercept would
hide it), positions jointly (x, y, z share one lag) and, separately, the roll, pitch, yaw
errors against the angle rates. The 95 % confidence interval comes from a moving-block
bootstrap of the samples (seeded; :func:`bootstrap_lag_ci`): the samples are autocorrelated,
so the textbook least-squares error, which assumes them independent, would be far too narrow.

``explained`` is the fraction of the mean squared position error the lag accounts for,
``1 - sum|e + L v|^2 / sum|e|^2``; the residual error ``e + L v`` per axis is what remains
once the lag is removed (MAE and RMSE, m and deg).

Frames and units: positions in metres and angles in degrees (ENU world / FLU body, ROS RPY,
the reference's angles unwrapped), stamps in seconds on the reference clock; the lag is in
seconds, positive when the other stream (Unity) is late.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

POSITION_AXES = ("x", "y", "z")
ANGLE_AXES = ("roll", "pitch", "yaw")
#: Samples the fit uses at most (evenly thinned beyond): the lag of a long log is pinned long
#: before a million samples, and the bootstrap's cost grows with the sample count.
MAX_FIT_SAMPLES = 20_000
#: Bootstrap resamples of the 95 % CI.
N_BOOT = 400
#: Mean speed below which an axis group does not move enough to fit a lag (m/s, deg/s).
MIN_SPEED = {"position": 1e-6, "orientation": 1e-4}
#: Block length of the bootstrap, in integrated autocorrelation times of the score terms:
#: with 3 the CI of :func:`bootstrap_lag_ci` covered 90 % of 200 seeded AR(1) trials with
#: phi 0.95 (2: 88 %; an iid bootstrap, blocks of 1: 25 %).
BLOCK_TAUS = 3.0
#: The fitted lag agrees with a measured latency when they differ by at most this fraction
#: of the measured one (or the measured one lies inside the CI).
AGREE_FRACTION = 0.10


@dataclass(frozen=True)
class AxisResidual:
    """Error of one axis once the lag is removed (m or deg)."""

    mae: float
    rmse: float


@dataclass(frozen=True)
class LagFit:
    """A lag fitted from the poses (see the module doc).

    Attributes:
        fitted_s: the lag (s) fitted on the positions (on the angles when the body does not
            translate); > 0: the other stream shows the reference's pose late.
        ci95_s: its 95 % CI (s), moving-block bootstrap.
        explained: fraction of the mean squared error the lag explains (0..1, may be < 0
            when the model fits worse than no lag).
        signal: ``position`` or ``orientation``: which errors ``fitted_s`` comes from.
        rotation_fitted_s: the lag fitted on roll, pitch, yaw against their rates (s), or
            None when the body does not rotate.
        n: samples the fit used; block: the bootstrap's block length (samples).
        speed: mean |rate| per axis of the reference (m/s for x y z, deg/s for the angles).
        residual: per axis, the error once the lag is removed.
        raw_mae: per axis, the MAE of the samples the fit used (before removing the lag).
        measured_s: the latency measured from applied stamps (s), when known: the age of the
            pose the other stream shows at the fitted samples, weighted as the fit weights
            them (by the squared speed), so that it is the same quantity as ``fitted_s``.
        measured_mean_s: the plain mean of that latency over the other stream's frames (s).
        notes: caveats (e.g. an estimated clock offset absorbs the lag).
    """

    fitted_s: float
    ci95_s: tuple[float, float]
    explained: float
    signal: str
    rotation_fitted_s: float | None
    n: int
    block: int
    speed: dict[str, float]
    residual: dict[str, AxisResidual]
    raw_mae: dict[str, float]
    measured_s: float | None = None
    measured_mean_s: float | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def agrees(self) -> bool | None:
        """Whether the measured latency confirms the fitted lag (None without one)."""
        if self.measured_s is None:
            return None
        lo, hi = self.ci95_s
        inside = lo <= self.measured_s <= hi
        close = abs(self.fitted_s - self.measured_s) <= AGREE_FRACTION * abs(self.measured_s)
        return bool(inside or close)

    def to_json(self) -> dict[str, Any]:
        """The ``lag`` section of the compare JSON (docs/analysis.md)."""
        return {
            "fitted_s": self.fitted_s,
            "ci95_s": [self.ci95_s[0], self.ci95_s[1]],
            "explained": self.explained,
            "signal": self.signal,
            "rotation_fitted_s": self.rotation_fitted_s,
            "n": self.n,
            "block": self.block,
            "speed": dict(self.speed),
            "residual": {a: {"mae": r.mae, "rmse": r.rmse} for a, r in self.residual.items()},
            "measured_s": self.measured_s,
            "measured_mean_s": self.measured_mean_s,
            "agrees": self.agrees,
            "notes": list(self.notes),
            "sentence": lag_sentence(self),
        }


def rates(t_s: F64, values: F64) -> F64:
    """Time derivative of ``values`` ((N,) or (N, k)) at the stamps ``t_s`` (s): second-order
    central differences (one-sided at the ends), per unit of ``values`` per second."""
    return np.asarray(np.gradient(values, t_s, axis=0))


def lag_least_squares(velocity: F64, error: F64) -> float:
    """The lag L minimising sum |error + L velocity|^2 over samples and columns (s):
    ``-sum(v . e) / sum(v . v)``. Both are (N, k) (or (N,)) in one unit per second / unit."""
    den = float(np.einsum("ij,ij->", _2d(velocity), _2d(velocity)))
    if den <= 0.0:
        return math.nan
    return -float(np.einsum("ij,ij->", _2d(velocity), _2d(error))) / den


def _2d(a: F64) -> F64:
    return a[:, None] if a.ndim == 1 else a


def block_length(products: F64) -> int:
    """Moving-block length (samples) for a series of per-sample score terms: BLOCK_TAUS times its
    integrated autocorrelation time (summed up to the first negative autocorrelation), at
    least n^(1/3) and at most n / 8 (eight blocks: the t quantile of the CI stays finite)."""
    n = int(products.size)
    lo = max(1, math.ceil(float(np.cbrt(n))))
    hi = max(lo, n // 8)
    x = products - products.mean()
    var = float(np.einsum("i,i->", x, x))
    if var <= 0.0 or n < 8:
        return min(lo, max(1, n))
    size = 1 << math.ceil(math.log2(2 * n))
    spec = np.fft.rfft(x, size)
    acf = np.fft.irfft(spec * np.conj(spec), size)[: n // 2] / var
    neg = np.flatnonzero(acf[1:] < 0.0)
    k = int(neg[0]) + 1 if neg.size else acf.size
    tau = 1.0 + 2.0 * float(acf[1:k].sum())
    return int(min(hi, max(lo, math.ceil(BLOCK_TAUS * tau))))


def t_quantile_975(df: float) -> float:
    """Student's t 0.975 quantile for ``df`` degrees of freedom (Cornish-Fisher expansion
    around the normal quantile; within 1 % of scipy's for df >= 5, 0.2 % for df >= 10; no
    scipy import)."""
    z = 1.959963984540054
    d = max(1.0, df)
    return z + (z**3 + z) / (4 * d) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * d * d)


def bootstrap_lag_ci(
    velocity: F64, error: F64, *, block: int, n_boot: int = N_BOOT, seed: int = 0
) -> tuple[float, float]:
    """95 % CI (s) of :func:`lag_least_squares` from a moving-block bootstrap (seeded).

    The interval is the fitted lag +- t(0.975, N / block - 1) times the standard deviation
    of the resampled lags: with few blocks (strongly autocorrelated samples) a percentile
    interval undercovers, the t quantile widens it by what the block count warrants (on AR(1)
    ages with phi 0.95 and 16 blocks: 90 % coverage, against 84 % for percentiles). The
    per-sample sums ``v . e`` and ``v . v`` are summed per block once (cumulative sums); each
    resample draws ``ceil(N / block)`` block starts and adds their sums: no per-resample pass
    over the samples.
    """
    v, e = _2d(velocity), _2d(error)
    n = v.shape[0]
    block = max(1, min(block, n))
    fitted = lag_least_squares(v, e)
    ve = np.concatenate(([0.0], np.cumsum(np.einsum("ij,ij->i", v, e))))
    vv = np.concatenate(([0.0], np.cumsum(np.einsum("ij,ij->i", v, v))))
    starts_all = np.arange(n - block + 1)
    block_ve = ve[starts_all + block] - ve[starts_all]
    block_vv = vv[starts_all + block] - vv[starts_all]
    rng = np.random.default_rng(seed)
    n_blocks = math.ceil(n / block)
    picks = rng.integers(0, starts_all.size, size=(n_boot, n_blocks))
    num = block_ve[picks].sum(axis=1)
    den = block_vv[picks].sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        lags = -num / den
    lags = lags[np.isfinite(lags)]
    if lags.size < 2 or not math.isfinite(fitted):
        return (math.nan, math.nan)
    half = t_quantile_975(n / block - 1) * float(lags.std(ddof=1))
    return (fitted - half, fitted + half)


def fit_lag(
    t_s: F64,
    reference_xyz: F64,
    other_xyz: F64,
    reference_rpy_deg: F64 | None = None,
    angle_error_deg: F64 | None = None,
    *,
    age_s: F64 | None = None,
    seed: int = 0,
    n_boot: int = N_BOOT,
) -> LagFit | None:
    """Fit the lag of ``other`` behind ``reference`` from aligned samples (module doc).

    Args:
        t_s: (N,) sample stamps (s, reference clock), increasing.
        reference_xyz, other_xyz: (N, 3) positions (m) on those stamps, one frame.
        reference_rpy_deg: (N, 3) the reference's roll, pitch, yaw (deg), unwrapped.
        angle_error_deg: (N, 3) other - reference angles (deg, wrapped to (-180, 180]).
        age_s: (N,) the latency measured from applied stamps at each sample (s), if known:
            gives ``measured_s``, weighted as the fit weights the samples.
        seed, n_boot: the bootstrap's seed and number of resamples.

    Returns None when neither the position nor the angles move enough to fit a lag.
    """
    t = np.asarray(t_s, dtype=np.float64)
    n_all = t.size
    if n_all < 8:
        return None
    step = max(1, math.ceil(n_all / MAX_FIT_SAMPLES))
    # rates from every sample (thinning first would widen the difference quotients)
    vel = rates(t, np.asarray(reference_xyz, dtype=np.float64))[::step]
    err = (np.asarray(other_xyz, dtype=np.float64) - reference_xyz)[::step]
    groups: dict[str, tuple[F64, F64]] = {"position": (vel, err)}
    if reference_rpy_deg is not None and angle_error_deg is not None:
        omega = rates(t, np.asarray(reference_rpy_deg, dtype=np.float64))[::step]
        groups["orientation"] = (omega, np.asarray(angle_error_deg, dtype=np.float64)[::step])
    lags: dict[str, float] = {}
    for name, (v, e) in groups.items():
        speed = float(np.sqrt(np.einsum("ij,ij->", v, v) / v.shape[0]))
        if speed > MIN_SPEED[name]:
            lags[name] = lag_least_squares(v, e)
    if not lags:
        return None
    signal = "position" if "position" in lags else "orientation"
    v, e = groups[signal]
    fitted = lags[signal]
    resid = e + fitted * v
    block = block_length(np.einsum("ij,ij->i", v, resid))
    ci = bootstrap_lag_ci(v, e, block=block, n_boot=n_boot, seed=seed)
    sse = float(np.einsum("ij,ij->", e, e))
    explained = 1.0 - float(np.einsum("ij,ij->", resid, resid)) / sse if sse > 0 else math.nan
    speed_axes: dict[str, float] = {}
    residual: dict[str, AxisResidual] = {}
    raw_mae: dict[str, float] = {}
    for name, axes in (("position", POSITION_AXES), ("orientation", ANGLE_AXES)):
        if name not in groups:
            continue
        gv, ge = groups[name]
        lag = lags.get(name, 0.0)
        r = ge + lag * gv
        for j, axis in enumerate(axes):
            speed_axes[axis] = float(np.abs(gv[:, j]).mean())
            residual[axis] = AxisResidual(
                float(np.abs(r[:, j]).mean()),
                math.sqrt(float(np.einsum("i,i->", r[:, j], r[:, j])) / r.shape[0]),
            )
            raw_mae[axis] = float(np.abs(ge[:, j]).mean())
    measured = None
    if age_s is not None:
        weight = np.einsum("ij,ij->i", v, v)
        age = np.asarray(age_s, dtype=np.float64)[::step]
        ok = np.isfinite(age)
        if float(weight[ok].sum()) > 0.0:
            measured = float(np.einsum("i,i->", age[ok], weight[ok]) / weight[ok].sum())
    return LagFit(
        measured_s=measured,
        fitted_s=fitted,
        ci95_s=ci,
        explained=explained,
        signal=signal,
        rotation_fitted_s=lags.get("orientation"),
        n=int(v.shape[0]),
        block=block,
        speed=speed_axes,
        residual=residual,
        raw_mae=raw_mae,
    )


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.1f}"


def _length(metres: float) -> str:
    """A length in the unit a reader expects (mm below 1 m)."""
    return f"{metres * 1e3:.1f} mm" if abs(metres) < 1.0 else f"{metres:.3f} m"


#: Below this fraction of the error explained, the sentence does not call the error a lag.
MOSTLY_A_LAG = 0.5


def lag_sentence(fit: LagFit, axis: str = "x") -> str:
    """The answer in one sentence, e.g. "Unity shows Gazebo's pose 12.4 ms late (95 % CI
    12.1-12.7 ms); that explains 98 % of the error; what remains is 0.4 mm (x MAE)."; plus
    one on the applied stamps when their latency is known."""
    late = fit.fitted_s >= 0
    lo, hi = fit.ci95_s if late else (-fit.ci95_s[1], -fit.ci95_s[0])
    words = "late" if late else "early (ahead of it)"
    lag = f"{_ms(abs(fit.fitted_s))} ms {words} (95 % CI {_ms(lo)}-{_ms(hi)} ms)"
    if math.isfinite(fit.explained) and fit.explained < MOSTLY_A_LAG:
        # a poor fit is no answer: say so first, before any number reads as one
        text = (
            f"The error is not mostly a lag: the best-fitting lag, {lag}, explains only "
            f"{max(0.0, fit.explained) * 100:.0f} % of it"
        )
    else:
        text = f"Unity shows Gazebo's pose {lag}"
        if math.isfinite(fit.explained):
            text += f"; that explains {fit.explained * 100:.0f} % of the error"
    if axis in fit.residual:
        mae = fit.residual[axis].mae
        shown = _length(mae) if axis in POSITION_AXES else f"{mae:.3g} deg"
        text += f"; what remains is {shown} ({axis} MAE)"
    text += "."
    if fit.measured_s is not None:
        verdict = "the two agree" if fit.agrees else "they disagree"
        mean = (
            f"; {_ms(fit.measured_mean_s)} ms averaged over Unity's frames"
            if fit.measured_mean_s is not None
            else ""
        )
        text += (
            f" The applied stamps measure {_ms(fit.measured_s)} ms at the same samples"
            f"{mean}: {verdict}."
        )
    return text
