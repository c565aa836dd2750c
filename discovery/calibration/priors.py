"""Priors declared per parameter, and the sampling coordinates they define.

Every prior is a bounded box: :class:`Uniform` samples the parameter itself, :class:`LogUniform`
samples its natural logarithm (the default for widths: dead zone, backlash, saturation, noise). The
sampler works in these *internal* coordinates, where every prior is flat inside its bounds; this
also makes the dead-zone/backlash ridge, a power law ``zm ~ f^a``, close to a straight line that
differential-evolution moves follow. A log-uniform prior can also be sampled in the parameter
itself (``linear=True``, the density then carries the ``1/x`` Jacobian): where the identifiable
combination is a difference, as the dead zone minus the friction offset of the velocity forms
(docs/models.md#what-a-recording-pins), the ridge is a straight line there and a strongly curved one in ``ln x``
(:func:`ridge_coordinates`).
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
    "step_under_delay",
    "ridge_coordinates",
]

#: Name of the sensor-noise standard deviation (rad), the one parameter that is not a field of
#: :class:`tvcid.models.ActuatorParams`.
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

    def in_linear_coordinate(self) -> "Prior":
        """The same density, sampled in the parameter itself."""
        return self


@dataclass(frozen=True)
class Uniform(Prior):
    """Flat in the parameter on ``[low, high]``."""


@dataclass(frozen=True)
class LogUniform(Prior):
    """Flat in ``ln(parameter)`` on ``[ln low, ln high]``; needs ``0 < low``.

    ``linear`` samples the parameter itself instead of its logarithm (same density: the internal
    log density is ``-ln x - ln ln(high/low)``).
    """

    linear: bool = False

    def __post_init__(self):
        super().__post_init__()
        if self.low <= 0:
            raise ValueError(f"a log-uniform prior needs low > 0 (got {self.low:g})")
        object.__setattr__(self, "linear", bool(self.linear))

    @property
    def log(self):
        return not self.linear

    def to_internal(self, value):
        value = np.asarray(value, dtype=float)
        return value if self.linear else np.log(value)

    def to_natural(self, value):
        value = np.asarray(value, dtype=float)
        return value if self.linear else np.exp(value)

    def log_prob_internal(self, z):
        if not self.linear:
            return super().log_prob_internal(z)
        z = np.asarray(z, dtype=float)
        inside = (z >= self.low) & (z <= self.high)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(inside, -np.log(np.where(inside, z, 1.0))
                            - math.log(math.log(self.high / self.low)), -np.inf)

    def sample_internal(self, rng, size):
        return self.to_internal(np.exp(rng.uniform(math.log(self.low), math.log(self.high), size)))

    def describe(self) -> dict:
        d = super().describe()
        if self.linear:
            d["coordinate"] = "linear"
        return d

    def in_linear_coordinate(self) -> "LogUniform":
        return LogUniform(self.low, self.high, linear=True)


#: Halvings of a default step that :func:`step_under_delay` takes at most (5e-4 s down to
#: 3.1e-5 s: every simulation 16 times as long).
MAX_DELAY_HALVINGS = 4


def step_under_delay(floor, dt, max_halvings=MAX_DELAY_HALVINGS) -> float:
    """The RK4 step ``dt`` halved until one step fits under ``floor`` (s), a delay prior's floor.

    The kernel stores the delayed signal on the step grid and interpolates it linearly between
    grid points, so it needs ``delay >= dt``: a shorter delay is refused (``tvcid.models.simulate``) and
    a walker proposing one gets a likelihood of ``-inf``. One step is all it needs: at 5e-4 s, the
    step's error in the cycle's features and in an open-loop square's waveform against a step of
    3.1e-5 s is the same for a delay of one step as for eight, at every delay position
    (``tests/test_kernel_vs_reference.py::test_step_error_does_not_grow_as_the_delay_nears_one_step``).
    Halved, not shrunk to fit, so that the step still divides the records' sample interval; a
    floor at or above ``dt`` keeps ``dt`` (no cost where the prior does not need it).

    Raises
    ------
    ValueError
        When ``floor`` is not above 0 or needs more than ``max_halvings`` halvings.
    """
    floor, step = float(floor), float(dt)
    for _ in range(int(max_halvings) + 1):
        if floor >= step * (1.0 - 1e-9):  # the kernel's own tolerance on a whole number of steps
            return step
        step /= 2.0
    raise ValueError(
        f"delay prior's floor ({floor:.3g} s) is below the finest default step "
        f"({dt / 2 ** int(max_halvings):.3g} s), the kernel's shortest delay; raise the floor "
        "or give the step (--dt)"
    )


def default_prior(name, value, dt=None) -> Prior:
    """The prior tvcid uses when none is declared, centred on the starting ``value``.

    Widths (:data:`WIDTH_PARAMETERS`) get a log-uniform prior over a factor 5 either side; the
    delay a uniform prior on ``[max(value/2, dt), 2 value]``, one step being the kernel's shortest
    delay (:func:`step_under_delay`; a start below one step is refused, and
    :class:`~tvcid.discovery.calibration.Calibration`'s default step is halved until one step fits under
    ``value/2``); any other parameter a uniform one over a factor 2 either side. A parameter whose
    starting value is 0 needs a declared prior.
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
        low = value / 2.0 if dt is None else max(value / 2.0, dt)
        if low > value:
            raise ValueError(
                f"delay starts at {value:.3g} s, below one step (dt = {dt:.3g} s), the kernel's "
                "shortest delay; declare a prior and a start inside it "
                "(e.g. --prior delay=0.001:0.01) or a smaller --dt"
            )
        return Uniform(low, 2.0 * value)
    a, b = value / 2.0, value * 2.0
    return Uniform(min(a, b), max(a, b))


#: Pairs ``(width, offset)`` whose identifiable combination is a difference ``width - offset``:
#: the velocity-form dead zone and the friction offset (docs/models.md#what-a-recording-pins: while the actuator
#: moves, ``w = v - (z - off) sign(v)``; a limit cycle pins ``z - off`` and barely the rest).
DIFFERENCE_RIDGES = (("dead_zone", "friction_offset"),)


def ridge_coordinates(priors, names, params) -> dict:
    """``priors`` with each width of a :data:`DIFFERENCE_RIDGES` pair sampled in linear
    coordinates when both of the pair are sampled (and, for the dead zone, it acts on the velocity
    signal), so that the ridge is straight for the affine-invariant moves (in ``(ln z, off)``
    the ridge ``z - off = const`` bows many times its own thickness).
    """
    out = dict(priors)
    for width, offset in DIFFERENCE_RIDGES:
        if width not in out or offset not in out:
            continue
        if width == "dead_zone" and getattr(getattr(params, "dead_zone_position", None),
                                            "value", "velocity") != "velocity":
            continue
        out[width] = out[width].in_linear_coordinate()
    return out


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
