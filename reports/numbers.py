"""One number format per quantity, used by every table, sentence and plot label of the report.

Positions and their errors are shown in millimetres with 2 decimals, angles in degrees with
3 decimals, Pearson r with 4 decimals (more when 4 would print a correlation below 1 as
"1.0000"), p-values with 2 significant digits, partial eta^2 as a percentage, durations in
milliseconds with 1 decimal. A column or sentence names the unit once (``MAE x (mm)``), the
cells hold bare numbers, so 0.009065 m never stands beside 5.971e-04 m again.
"""

from __future__ import annotations

import math
from enum import Enum
from typing import Any


class Quantity(str, Enum):
    """What a number is, which fixes its unit and digits in the report."""

    LENGTH = "length"  # stored in m, shown in mm
    ANGLE = "angle"  # deg
    CORRELATION = "correlation"  # Pearson r, unitless
    P_VALUE = "p"  # probability
    FRACTION = "fraction"  # 0..1, shown as a percentage
    DURATION = "duration"  # stored in s, shown in ms
    MILLISECONDS = "ms"  # stored in ms, shown in ms
    COUNT = "count"  # an integer
    PLAIN = "plain"  # anything else: 4 significant digits


#: The unit a quantity is shown in (what headers and sentences print).
SHOWN_UNIT: dict[Quantity, str] = {
    Quantity.LENGTH: "mm",
    Quantity.ANGLE: "deg",
    Quantity.CORRELATION: "",
    Quantity.P_VALUE: "",
    Quantity.FRACTION: "%",
    Quantity.DURATION: "ms",
    Quantity.MILLISECONDS: "ms",
    Quantity.COUNT: "",
    Quantity.PLAIN: "",
}

#: A results-table unit -> the quantity (``m`` lengths, ``deg`` angles, ...).
_BY_UNIT = {"m": Quantity.LENGTH, "deg": Quantity.ANGLE, "s": Quantity.DURATION}
_BY_UNIT["ms"] = Quantity.MILLISECONDS
_CORRELATION_METRICS = frozenset({"pearson_r", "pearson_ci_low", "pearson_ci_high"})


def quantity_of(metric: str, unit: str) -> Quantity:
    """The quantity of a results-table value from its metric name and stored unit."""
    if metric in _CORRELATION_METRICS:
        return Quantity.CORRELATION
    if metric == "pearson_p" or metric.endswith("p_value"):
        return Quantity.P_VALUE
    if metric.startswith(("n_", "dropped")) or metric.endswith("_count"):
        return Quantity.COUNT
    return _BY_UNIT.get(unit, Quantity.PLAIN)


def _finite(v: Any) -> float | None:
    if v is None or isinstance(v, bool):
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def fmt(v: Any, quantity: Quantity) -> str:
    """``v`` (in the stored unit: m, deg, s...) as the report shows it, without the unit;
    "n/a" when it is missing or not finite."""
    x = _finite(v)
    if x is None:
        return "n/a"
    if quantity is Quantity.LENGTH:
        return f"{x * 1e3:.2f}"
    if quantity is Quantity.ANGLE:
        return f"{x:.3f}"
    if quantity is Quantity.CORRELATION:
        return fmt_correlation(x)
    if quantity is Quantity.P_VALUE:
        return fmt_p(x)
    if quantity is Quantity.FRACTION:
        return f"{x * 100:.1f}"
    if quantity is Quantity.DURATION:
        return f"{x * 1e3:.1f}"
    if quantity is Quantity.MILLISECONDS:
        return f"{x:.1f}"
    if quantity is Quantity.COUNT:
        return f"{x:.0f}"
    return f"{x:.4g}"


def fmt_unit(v: Any, quantity: Quantity) -> str:
    """``v`` with its shown unit ("3.26 mm", "0.120 deg", "91.0 %")."""
    text = fmt(v, quantity)
    unit = SHOWN_UNIT[quantity]
    if text == "n/a" or not unit:
        return text
    return f"{text} %" if unit == "%" else f"{text} {unit}"


def fmt_correlation(r: float, decimals: int = 4) -> str:
    """Pearson r with ``decimals`` decimals, or more (up to 9) when fewer would print a
    correlation that is not exactly +-1 as "1.0000" (a saturated r must not read perfect)."""
    for d in range(decimals, 10):
        text = f"{r:.{d}f}"
        if abs(float(text)) < 1.0 or abs(r) == 1.0:
            return text
    return f"{r:.9f}"


def fmt_p(p: float) -> str:
    """A p-value: 3 decimals from 0.001 up, 2 significant digits in scientific form below."""
    if p >= 0.001:
        return f"{p:.3f}"
    if p <= 0.0:
        return "0"
    return f"{p:.1e}"


def fmt_level(v: Any) -> str:
    """A factor level as written in the experiment (5, 0.25, "teleop")."""
    x = _finite(v)
    if x is None:
        return str(v)
    return f"{x:g}"


def unit_suffix(quantity: Quantity) -> str:
    """`` (mm)`` for a column header, '' for unitless quantities."""
    unit = SHOWN_UNIT[quantity]
    return f" ({unit})" if unit else ""


def to_shown(v: float, quantity: Quantity) -> float:
    """A value in the shown unit (m -> mm, s -> ms), e.g. for plot axes and threshold lines."""
    scale = {Quantity.LENGTH: 1e3, Quantity.DURATION: 1e3, Quantity.FRACTION: 100.0}
    return v * scale.get(quantity, 1.0)


def fmt_correlation_interval(lo: Any, hi: Any, decimals: int = 4) -> str:
    """A correlation's confidence interval "[lo, hi]" with ``decimals`` decimals, or more
    (up to 9) until its two ends differ and neither reads as +-1 unless it is; "n/a" when an
    end is missing."""
    a, b = _finite(lo), _finite(hi)
    if a is None or b is None:
        return "n/a"
    for d in range(decimals, 10):
        ta, tb = f"{a:.{d}f}", f"{b:.{d}f}"
        ends_differ = ta != tb or a == b
        honest = all(abs(float(t)) < 1.0 or abs(v) == 1.0 for t, v in ((ta, a), (tb, b)))
        if ends_differ and honest:
            break
    return f"[{ta}, {tb}]"
