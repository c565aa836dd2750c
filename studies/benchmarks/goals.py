"""What every benchmark shares at its end: its goals, one line each, its exit status, its JSON.

Every benchmark command ends by printing each goal it has as one line,
``goal <what>: <measured> (<target>) met`` or ``... NOT met`` (:meth:`Goal.line`), against
figures measured in the same run, and exits with :func:`report`'s status: 0 when every goal is
met, 1 otherwise.

A speed goal is stated in seconds on the 2-core development machine and checked as a ratio
(:meth:`Goal.speed`): the wall time over the batch kernel's reference cost measured in the same
run (:func:`kernel_reference`), so that a slower machine is told from a slower program. The
target is the goal's seconds over :data:`NOMINAL_REFERENCE`, the reference's cost at which those
seconds are read.

The JSON a benchmark writes is strict: :func:`tvcid.models.strict_json.write_json` writes NaN and infinities as ``null``
(``json`` would write the tokens ``NaN`` and ``Infinity``, which are not JSON).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

#: The reference's cost (wall seconds per simulated second, :func:`kernel_reference`) at which a
#: speed goal's seconds are read, a definition rather than a measurement: a goal of ``S``
#: seconds is met when the run's wall time is at most ``S / NOMINAL_REFERENCE`` reference
#: seconds, on whatever machine and load.
NOMINAL_REFERENCE = 2e-4


def kernel_reference(repeats=3) -> float:
    """Best wall time (s) per simulated second of a 64-run closed-loop batch of M000 at 5e-4 s.

    The unit of the speed goals (:meth:`Goal.speed`): a wall time over this is the number of
    simulated seconds the kernel's batch would have run in it on the same machine at that time.
    """
    from tvcid.models import CONTROLLER_A, hypothesis, simulate_batch

    sets = [hypothesis("M000").replace(backlash=1e-4 * (1 + 0.01 * i)) for i in range(64)]
    simulate_batch(sets[:2], CONTROLLER_A, 1.0, dt=5e-4, rate=None)  # compile / load the cache
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        simulate_batch(sets, CONTROLLER_A, 10.0, dt=5e-4, rate=None)
        best = min(best, (time.perf_counter() - t0) / (64 * 10.0))
    return best


def _number(value, fmt):
    return "none" if value is None else fmt.format(value)


@dataclass(frozen=True)
class Goal:
    """One goal of a benchmark: a measured value against a lower and/or an upper bound.

    Attributes
    ----------
    what : str
        What is measured, as printed after ``goal``.
    measured : float or None
        The value; ``None`` or a non-finite value (nothing measured) is never met.
    low, high : float or None
        Bounds, inclusive; ``None`` is unbounded on that side.
    fmt : str
        Format of the value and the bounds, e.g. ``"{:.0%}"``.
    shown, target : str or None
        The value and the target as printed, where more than the formatted numbers is said
        (seconds beside a ratio, counts beside a fraction).
    """

    what: str
    measured: float | None
    low: float | None = None
    high: float | None = None
    fmt: str = "{:.3g}"
    shown: str | None = None
    target: str | None = None

    @classmethod
    def at_least(cls, what, measured, low, fmt="{:.3g}", **kw) -> "Goal":
        return cls(what, measured, low=low, fmt=fmt, **kw)

    @classmethod
    def at_most(cls, what, measured, high, fmt="{:.3g}", **kw) -> "Goal":
        return cls(what, measured, high=high, fmt=fmt, **kw)

    @classmethod
    def count(cls, what, hits, n, need=None) -> "Goal":
        """``hits`` of ``n`` against ``need`` of them (default all; none counted is not met)."""
        need = n if need is None else need
        return cls(what, hits if n else None, low=max(need, 1), fmt="{:d}",
                   shown=f"{hits} of {n}", target="all" if need == n else f">= {need} of {n}")

    @classmethod
    def flag(cls, what, value: bool, yes="yes", no="no") -> "Goal":
        """A yes/no goal: met when ``value`` is true (``yes`` and ``no`` as printed)."""
        return cls(what, float(bool(value)), low=1.0, shown=yes if value else no, target="yes")

    @classmethod
    def speed(cls, what, seconds, reference, goal_seconds) -> "Goal":
        """Wall time ``seconds`` against ``goal_seconds``, judged in reference seconds: the
        ratio to ``reference`` (:func:`kernel_reference`, measured in the same run) against
        ``goal_seconds / NOMINAL_REFERENCE``."""
        ratio = None if seconds is None or not reference else seconds / reference
        budget = goal_seconds / NOMINAL_REFERENCE
        shown = ("none" if ratio is None else
                 f"{seconds:.3g} s = {ratio:.3g} reference seconds at "
                 f"{1e3 * reference:.3g} ms per simulated second")
        target = (f"<= {goal_seconds:.3g} s = {budget:.3g} reference seconds at "
                  f"{1e3 * NOMINAL_REFERENCE:.3g} ms")
        return cls(what, ratio, high=budget, shown=shown, target=target)

    @property
    def met(self) -> bool:
        v = self.measured
        if v is None or not math.isfinite(v):
            return False
        return (self.low is None or v >= self.low) and (self.high is None or v <= self.high)

    def target_text(self) -> str:
        if self.target is not None:
            return self.target
        if self.low is not None and self.high is not None:
            return f"{self.fmt.format(self.low)} to {self.fmt.format(self.high)}"
        if self.low is not None:
            return f">= {self.fmt.format(self.low)}"
        return f"<= {self.fmt.format(self.high)}"

    def value_text(self) -> str:
        return self.shown if self.shown is not None else _number(self.measured, self.fmt)

    def verdict(self) -> str:
        return "met" if self.met else "NOT met"

    def text(self) -> str:
        """``<what>: <measured> (<target>) met`` or ``... NOT met``."""
        return f"{self.what}: {self.value_text()} ({self.target_text()}) {self.verdict()}"

    def line(self) -> str:
        """``goal <what>: <measured> (<target>) met`` or ``... NOT met``."""
        return f"goal {self.text()}"

    def to_dict(self) -> dict:
        return {"what": self.what, "measured": self.measured, "low": self.low, "high": self.high,
                "met": self.met, "line": self.line()}


def report(goals, file=None) -> int:
    """Print every goal's line; the exit status: 0 if all are met, 1 if any is not.

    A benchmark without goals says so and exits 0.
    """
    file = sys.stdout if file is None else file
    if not goals:
        print("goals: none stated", file=file, flush=True)
        return 0
    for g in goals:
        print(g.line(), file=file, flush=True)
    return 0 if all(g.met for g in goals) else 1
