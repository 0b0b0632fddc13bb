"""The gate's verdict: what failed (:class:`Violation`, by :class:`ViolationKind`) and the
whole outcome (:class:`GateResult`: text, rich markup, JSON)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any


class ViolationKind(str, Enum):
    """Why the gate failed on one value, run or rule."""

    THRESHOLD = "threshold"  # a value broke a rule's bound
    BASELINE = "baseline"  # a value regressed against the golden baseline
    MISSING = "missing"  # a baseline value is absent from the results
    MISSING_RUN = "missing-run"  # a run of the manifest or the baseline has no results
    UNDEFINED = "undefined"  # a gated value is NaN / null with no rule allowing it
    INVALID = "invalid"  # an impossible value (negative MAE, |r| > 1)
    NO_MATCH = "no-match"  # a rule matched no row (or none of one run's)
    UNGATED = "ungated"  # a run/topic of the results the baseline does not cover
    LOG_WARNING = "log-warning"  # a reader warned about the run's log
    UNCOVERED = "uncovered"  # a gated metric the baseline holds no value of

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Violation:
    """One thing that regressed: which value broke which bound, and where."""

    kind: ViolationKind
    metric: str
    topic: str
    axis: str
    run: str
    factors: dict[str, Any]
    value: float
    bound: float
    op: str  # the relation that had to hold, e.g. "<=" or ">="
    unit: str = ""
    rule: str = ""
    note: str = ""

    def describe(self) -> str:
        levels = " ".join(f"{k}={_fmt_level(v)}" for k, v in self.factors.items())
        where = " ".join(
            p
            for p in (
                f"run={self.run}" if self.run else "",
                f"topic={self.topic}" if self.topic else "",
                f"axis={self.axis}" if self.axis else "",
                levels,
            )
            if p
        )
        unit = f" {self.unit}" if self.unit else ""
        K = ViolationKind
        why = f" ({self.note})" if self.note else ""
        if self.kind is K.NO_MATCH:
            return f"rule [{self.rule}] matched no results ({where or 'any topic/axis'}){why}"
        if self.kind is K.MISSING:
            return (
                f"{self.metric} {where}: missing from the results (baseline {self.bound:.6g}{unit})"
            )
        if self.kind is K.MISSING_RUN:
            return f"{where}: the run is missing from the results{why}"
        if self.kind is K.UNGATED:
            return f"{where}: not covered by the baseline, so not gated{why}"
        if self.kind is K.UNCOVERED:
            return f"{self.metric}: not checked against the baseline: {self.note}"
        if self.kind is K.LOG_WARNING:
            return f"{where}: the log reader warned: {self.note} [{self.rule}]"
        if self.kind is K.INVALID:
            return f"{self.metric} {where}: {self.value:.6g}{unit} is impossible{why}"
        if self.kind is K.UNDEFINED:
            return (
                f"{self.metric} {where}: undefined (NaN){why}, must be {self.op} "
                f"{self.bound:.6g}{unit} [{self.rule}]"
            )
        return (
            f"{self.metric} {where}: {self.value:.6g}{unit}, must be {self.op} "
            f"{self.bound:.6g}{unit} [{self.rule}]"
        )


@dataclass
class GateResult:
    """Outcome of :func:`check`: violations (empty = pass), counts of checked/skipped values."""

    violations: list[Violation] = field(default_factory=list)
    checked: int = 0
    skipped: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.violations

    def format(self, limit: int | None = 200) -> str:
        """A readable multi-line verdict for terminals and CI logs."""
        head = (
            f"uwval check: PASS ({self.checked} values checked)"
            if self.passed
            else f"uwval check: FAIL - {len(self.violations)} regression(s) "
            f"among {self.checked} values checked"
        )
        lines = [head]
        shown = self.violations if limit is None else self.violations[:limit]
        lines += [f"  - {v.describe()}" for v in shown]
        if limit is not None and len(self.violations) > limit:
            lines.append(f"  ... and {len(self.violations) - limit} more")
        allowed = [x for x in self.skipped if x.startswith("log warning ")]
        undefined = [x for x in self.skipped if not x.startswith("log warning ")]
        lines += [f"  ! {x}" for x in allowed]  # allowed, never hidden
        if undefined:
            lines.append(f"  ({len(undefined)} undefined value(s) skipped, e.g. {undefined[0]})")
        return "\n".join(lines)

    def render(self) -> str:
        """The verdict as rich console markup (``format`` with colour)."""
        from rich.markup import escape

        text = escape(self.format())
        colour = "green" if self.passed else "red"
        first, _, rest = text.partition("\n")
        return f"[bold {colour}]{first}[/]" + (f"\n{rest}" if rest else "")

    def to_json(self) -> dict[str, Any]:
        """Machine-readable verdict: passed, checked, violations (with every field), skipped."""
        from dataclasses import asdict

        def clean(v: Any) -> Any:
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {
            "passed": self.passed,
            "checked": self.checked,
            "violations": [
                {k: clean(v) for k, v in asdict(x).items()}
                | {"kind": x.kind.value, "message": x.describe()}
                for x in self.violations
            ],
            "skipped": list(self.skipped),
        }

    def merge(self, other: GateResult) -> GateResult:
        return GateResult(
            self.violations + other.violations,
            self.checked + other.checked,
            self.skipped + other.skipped,
        )


def _fmt_level(v: Any) -> str:
    if isinstance(v, float) and v.is_integer():
        return f"{v:g}"
    return f"{v:g}" if isinstance(v, float) else str(v)
