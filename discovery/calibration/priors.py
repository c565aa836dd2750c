"""Priors declared per parameter, and the sampling coordinates they define.

Every prior is a bounded box: :class:`Uniform` samples the parameter itself, :class:`LogUniform`
samples its natural logarithm (the default for widths: dead zone, backlash, saturation, noise). The
sampler works in these *internal* coordinates, where every prior is flat inside its bounds; this
also makes the dead-zone/backlash ridge, a power law ``zm ~ f^a``, close to a straight line that
differential-evolution moves follow.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Prior",
    "Uniform",
    "LogUniform",
    "SIGMA",
    "WIDTH_PARAMETERS",
    "default_prior",
    "parse_prior",
]

#: Name of the sensor-noise standard deviation (rad), the one parameter that is not a field of
#: :class:`models.ActuatorParams`.
SIGMA = "sigma"

#: Parameters that are widths or levels, given log-uniform priors by default.
WIDTH_PARAMETERS = ("dead_zone", "backlash", "bandpass_saturation", "noise_power", SIGMA)


@dataclass(frozen=True)
class Prior:
    """A bounded flat prior; subclasses choose the coordinate in which it is flat.

    Parameters
    ----------
    low, high : float
        Bounds of the parameter in its natural unit, ``low < high``.
    """

    low: float
    high: float

    log = False

    def __post_init__(self):
        for name in ("low", "high"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"prior bound {name} must be a number (got {value!r})") from None
            if not math.isfinite(value):
                raise ValueError(f"prior bound {name} must be finite (got {value})")
            object.__setattr__(self, name, value)
        if not self.low < self.high:
            raise ValueError(
                f"prior bounds reversed or empty: low ({self.low:g}) must be below high "
                f"({self.high:g})"
            )

    # internal <-> natural -------------------------------------------------------------------
    def to_internal(self, value):
        return np.asarray(value, dtype=float)

    def to_natural(self, value):
        return np.asarray(value, dtype=float)

    @property
    def internal_bounds(self):
        return float(self.to_internal(self.low)), float(self.to_internal(self.high))

    def log_prob_internal(self, z):
        """Log density in internal coordinates: constant inside the bounds, ``-inf`` outside."""
        lo, hi = self.internal_bounds
        z = np.asarray(z, dtype=float)
        return np.where((z >= lo) & (z <= hi), -math.log(hi - lo), -np.inf)

    def sample_internal(self, rng, size):
        lo, hi = self.internal_bounds
        return rng.uniform(lo, hi, size)

    def describe(self) -> dict:
        return {"kind": type(self).__name__, "low": self.low, "high": self.high}


@dataclass(frozen=True)
class Uniform(Prior):
    """Flat in the parameter on ``[low, high]``."""


@dataclass(frozen=True)
class LogUniform(Prior):
    """Flat in ``ln(parameter)`` on ``[ln low, ln high]``; needs ``0 < low``."""

    log = True

    def __post_init__(self):
        super().__post_init__()
        if self.low <= 0:
            raise ValueError(f"a log-uniform prior needs low > 0 (got {self.low:g})")

    def to_internal(self, value):
        return np.log(np.asarray(value, dtype=float))

    def to_natural(self, value):
        return np.exp(np.asarray(value, dtype=float))


def default_prior(name, value, dt=None) -> Prior:
    """The prior tvcid uses when none is declared, centred on the starting ``value``.

    Widths (:data:`WIDTH_PARAMETERS`) get a log-uniform prior over a factor 5 either side; the
    delay a uniform prior on ``[max(value/2, 2 dt), 2 value]``; any other parameter a uniform one
    over a factor 2 either side. A parameter whose starting value is 0 needs a declared prior.
    """
    value = float(value)
    if value == 0.0:
        raise ValueError(
            f"parameter {name!r} starts at 0, so no default prior can be centred on it; "
            f"declare one (e.g. --prior {name}=LOW:HIGH)"
        )
    if name in WIDTH_PARAMETERS:
        if value < 0:
            raise ValueError(f"width {name!r} must be > 0 for a log-uniform prior (got {value})")
        return LogUniform(value / 5.0, value * 5.0)
    if name == "delay":
        low = value / 2.0 if dt is None else max(value / 2.0, 2.0 * dt)
        if low >= 2.0 * value:
            raise ValueError(
                f"delay starts at {value:.3g} s, too close to the step (2 dt = {2.0 * dt:.3g} s) for a "
                "default prior; declare one and a start inside it (e.g. --prior delay=0.001:0.01)"
            )
        return Uniform(low, 2.0 * value)
    a, b = value / 2.0, value * 2.0
    return Uniform(min(a, b), max(a, b))


def parse_prior(text) -> tuple:
    """``"name=low:high"`` or ``"name=low:high:log"`` -> ``(name, Prior)`` (CLI form)."""
    if "=" not in text:
        raise ValueError(f"--prior expects name=low:high[:log], got {text!r}")
    name, spec = (s.strip() for s in text.split("=", 1))
    parts = [p.strip() for p in spec.split(":")]
    if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] not in ("log", "lin")):
        raise ValueError(f"--prior expects name=low:high[:log|lin], got {text!r}")
    try:
        low, high = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"--prior bounds must be numbers, got {text!r}") from None
    cls = LogUniform if (len(parts) == 3 and parts[2] == "log") else Uniform
    return name, cls(low, high)
