"""A controller setting by named values, so that a grid can vary any one of them.

:class:`tvcid.models.ClosedLoop` holds the compensator as a transfer function; a map over a lead's
corner or a notch's centre needs the named values the filter was built from.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from tvcid.models.controllers import BendingMode, TransferFunction
from tvcid.models.experiments import ClosedLoop

__all__ = ["GRID_KEYS", "ControllerSetting", "parse_grid"]

#: Controller values a map can vary.
GRID_KEYS = ("kp", "kd", "mu", "lead_zero", "lead_pole", "notch_frequency", "notch_damping",
             "notch_depth")


@dataclass(frozen=True)
class ControllerSetting:
    """``u = -Kp (1 + Kd s) F(s) theta_m`` by named values (see :mod:`tvcid.models.controllers`).

    Parameters
    ----------
    kp, kd, mu : float
        PD gain, derivative time (s), vehicle effectiveness (1/s^2).
    sample_rate : float or None
        Controller rate (Hz, zero-order hold), ``None`` for continuous.
    lead_zero, lead_pole : float or None
        Corners (rad/s) of a lead/lag ``(1 + s/zero)/(1 + s/pole)``; both or neither.
    notch_frequency, notch_damping, notch_depth : float or None
        Centre (rad/s), pole damping and centre gain of a notch; frequency set or not.
    bending : BendingMode or None
    compensator : TransferFunction or None
        Any further proper compensator, in series after the named blocks.
    """

    kp: float
    kd: float
    mu: float
    sample_rate: float | None = None
    lead_zero: float | None = None
    lead_pole: float | None = None
    notch_frequency: float | None = None
    notch_damping: float = 0.5
    notch_depth: float = 0.1
    bending: BendingMode | None = None
    compensator: TransferFunction | None = None

    def __post_init__(self):
        if (self.lead_zero is None) != (self.lead_pole is None):
            raise ValueError("a lead needs both lead_zero and lead_pole (rad/s)")
        self.closed_loop()  # validate every value now, with the model's own messages

    @classmethod
    def from_closed_loop(cls, loop: ClosedLoop) -> "ControllerSetting":
        return cls(kp=loop.kp, kd=loop.kd, mu=loop.mu, sample_rate=loop.sample_rate,
                   bending=loop.bending, compensator=loop.compensator)

    def blocks(self) -> list:
        out = []
        if self.lead_zero is not None:
            out.append(TransferFunction.lead(self.lead_zero, self.lead_pole))
        if self.notch_frequency is not None:
            out.append(TransferFunction.notch(self.notch_frequency, self.notch_damping,
                                              self.notch_depth))
        if self.compensator is not None:
            out.append(self.compensator)
        return out

    def closed_loop(self, theta0=0.0, thetad0=0.0) -> ClosedLoop:
        blocks = self.blocks()
        comp = None if not blocks else (blocks[0] if len(blocks) == 1
                                        else TransferFunction.series(*blocks))
        return ClosedLoop(kp=self.kp, kd=self.kd, mu=self.mu, sample_rate=self.sample_rate,
                          theta0=theta0, thetad0=thetad0, compensator=comp, bending=self.bending)

    def settling_time(self, time_constants=8.0, cap=30.0) -> float:
        """Seconds for the slowest compensator or bending-mode state to settle from zero:
        ``time_constants`` over the smallest decay rate of their poles (at most ``cap``; 0 for
        a plain PD)."""
        import numpy as np

        rates = []
        for block in self.blocks():
            poles = np.roots(block.den) if len(block.den) > 1 else np.array([])
            rates.extend(-poles.real)
        if self.bending is not None:
            rates.append(self.bending.damping * self.bending.frequency)
        if not rates:
            return 0.0
        slowest = min(rates)
        return cap if slowest <= time_constants / cap else time_constants / slowest

    def replace(self, **values) -> "ControllerSetting":
        unknown = sorted(set(values) - set(GRID_KEYS) - {"sample_rate", "bending"})
        if unknown:
            raise ValueError(f"unknown controller value(s) {', '.join(unknown)}; "
                             f"a grid can vary {', '.join(GRID_KEYS)}")
        return dataclasses.replace(self, **values)

    def to_dict(self) -> dict:
        out = {"kp": self.kp, "kd": self.kd, "mu": self.mu, "sample_rate": self.sample_rate}
        for k in ("lead_zero", "lead_pole"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        if self.notch_frequency is not None:
            out.update(notch_frequency=self.notch_frequency, notch_damping=self.notch_damping,
                       notch_depth=self.notch_depth)
        if self.bending is not None:
            out["bending"] = self.bending.to_dict()
        if self.compensator is not None:
            out["compensator"] = self.compensator.to_dict()
        return out


def parse_grid(text) -> tuple:
    """``"kp=2:12:20"`` -> ``("kp", array of 20 values from 2 to 12)``.

    Raises
    ------
    ValueError
        For an unknown key, a malformed range, or fewer than two points.
    """
    import numpy as np

    key, sep, spec = str(text).partition("=")
    key = key.strip()
    if not sep or key not in GRID_KEYS:
        raise ValueError(f"--grid {text!r}: expected KEY=LO:HI:N with KEY one of "
                         f"{', '.join(GRID_KEYS)}")
    parts = spec.split(":")
    try:
        lo, hi, n = float(parts[0]), float(parts[1]), int(parts[2])
        if len(parts) != 3:
            raise IndexError
    except (IndexError, ValueError):
        raise ValueError(f"--grid {text!r}: expected KEY=LO:HI:N (two numbers and a count)") from None
    if n < 2:
        raise ValueError(f"--grid {text!r}: a grid needs at least 2 points (got {n}); use "
                         f"--{key.replace('_', '-')} for one setting")
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo == hi:
        raise ValueError(f"--grid {text!r}: LO and HI must be finite and different")
    return key, np.linspace(lo, hi, n)
