"""The actuator hypotheses of the three papers as frozen parameter dataclasses.

All four share one structure (``docs/models.md#the-actuator``)::

    e  = u - K * play_r(x)                         actuator error, backlash in the feedback
    y'' + K2 y' + K3 y = K1 * g(e)                 second-order block K1/(s^2 + K2 s + K3)
    w  = FRIC(h(v + p))                            integrator input
    x' = w,  delta = x (+ noise)                   integrator and output

with ``g = DZ_z`` and ``h = identity`` when the dead zone sits on the error (paper 002), or
``g = identity`` and ``h = DZ_z`` when it sits on the velocity-level signal (papers 001, 000). The
band-pass loop feeds ``p = sat_s(G * BP(w))`` back positively. The transport delay acts at one of
three named places (:class:`DelayPosition`). Structural choices are named enum fields, never
integers; :class:`ActuatorParams` is the general model and ``M002``, ``M001i``, ``M001f``, ``M000``
are its subclasses whose defaults are the papers' values.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from enum import Enum
from typing import ClassVar

__all__ = [
    "DelayPosition",
    "DeadZonePosition",
    "ActuatorParams",
    "M002",
    "M001i",
    "M001f",
    "M000",
    "HYPOTHESES",
    "UnknownHypothesisError",
    "hypothesis",
    "gains_from_abc",
    "params_from_dict",
    "UNITS",
    "parameter_unit",
]


class DelayPosition(str, Enum):
    """Where the transport delay ``Td`` acts (paper 000 section 4.2, paper 001 section 5.2)."""

    #: ``delta(t) = x(t - Td)``: outside the actuator loop (papers 002 and 001 initial).
    OUTPUT = "output"
    #: ``v(t) = y(t - Td)``: inside the loop, before the integral (paper 001 final).
    BEFORE_INTEGRATOR = "before_integrator"
    #: ``y'' = [K1 g(e) - K3 y - K2 y'](t - Td)``: before the first integrator (paper 000).
    BEFORE_FIRST_INTEGRATOR = "before_first_integrator"


class DeadZonePosition(str, Enum):
    """Which signal the dead zone acts on."""

    #: On the actuator error ``e``, before the second-order block (paper 002, Fig. 1).
    ERROR = "error"
    #: On the velocity-level signal ``y``, before the integrator (papers 001 and 000).
    VELOCITY = "velocity"


class UnknownHypothesisError(ValueError):
    """Raised for a hypothesis name that tvcid does not know."""


def gains_from_abc(a, b, c):
    """``(K1, K2, K3)`` of ``K1/(s^2 + K2 s + K3)`` from paper 000's integrator gains.

    Paper 000 section 4.1: ``A = K1/K2``, ``B = K2``, ``C = K3/K1``.
    """
    return a * b, b, c * a * b


#: Initial actuator position (rad) of the hypotheses whose paper prints no initial condition: at
#: rest with a null reference the loop would stay at its equilibrium, so the run starts displaced
#: by about one cycle amplitude (paper 000's C3 = 0.0052 is of the same size).
KICK_X0 = 5e-3

_NONNEGATIVE = (
    "dead_zone",
    "backlash",
    "delay",
    "bandpass_gain",
    "noise_power",
)
_POSITIVE = (
    "gain",
    "feedback_gain",
    "bandpass_saturation",
    "bandpass_low_hz",
    "bandpass_high_hz",
    "noise_band",
)


#: Fields whose default is infinite (open); strict JSON writes them as ``null``.
OPEN_FIELDS = ("bandpass_saturation",)

#: Unit of each numeric parameter of :class:`ActuatorParams` (the dead zone's depends on its
#: position: :func:`parameter_unit`).
UNITS = {
    "gain": "1/s^3", "damping": "1/s", "stiffness": "1/s^2", "feedback_gain": "1",
    "dead_zone": "rad", "backlash": "rad", "friction_offset": "rad/s", "delay": "s",
    "bandpass_gain": "1", "bandpass_saturation": "rad/s", "bandpass_low_hz": "Hz",
    "bandpass_high_hz": "Hz", "y0": "rad/s", "yd0": "rad/s^2", "x0": "rad",
    "noise_power": "rad^2/Hz", "noise_band": "Hz", "sigma": "rad",
}


def parameter_unit(name, dead_zone_position="error") -> str:
    """Unit of parameter ``name``: ``rad/s`` for a dead zone on the velocity signal, else
    :data:`UNITS` (``""`` for a name it does not know)."""
    if name == "dead_zone" and str(getattr(dead_zone_position, "value", dead_zone_position)) == "velocity":
        return "rad/s"
    return UNITS.get(name, "")


@dataclass(frozen=True)
class ActuatorParams:
    """General actuator model; the four hypotheses are subclasses with the papers' defaults.

    Parameters
    ----------
    gain : float
        ``K1`` (1/s^2 per rad of error), numerator of the second-order block ``K1/(s^2+K2 s+K3)``.
    damping : float
        ``K2`` (1/s).
    stiffness : float
        ``K3`` (1/s^2).
    feedback_gain : float
        ``K`` (dimensionless), gain of the backlash feedback path ``e = u - K*play_r(x)``.
    dead_zone : float
        Half width ``z`` of the dead zone (rad on the error, or rad/s on the velocity signal).
    dead_zone_position : DeadZonePosition
        Signal the dead zone acts on.
    backlash : float
        Half width ``r`` of the play operator (rad); total play ``2r``.
    friction_offset : float
        ``off`` in ``FRIC(q) = q + off*sign(q)`` (rad/s); negative opposes the motion (paper 001).
    delay : float
        Transport delay ``Td`` (s); output 0 before ``t = Td``; 0 disables it.
    delay_position : DelayPosition
        Where the delay acts.
    bandpass_gain : float
        Loop gain ``G`` of the positive band-pass feedback (paper 001 G, paper 000 F); 0 = no loop.
    bandpass_saturation : float
        Level ``s`` of the saturation after the gain (rad/s); ``inf`` for none (``None``, JSON
        ``null``, reads as ``inf``).
    bandpass_low_hz, bandpass_high_hz : float
        Pass band of the Butterworth filter (Hz).
    bandpass_order : int
        ``N`` of ``scipy.signal.butter(N, ..., 'bandpass', analog=True)``; 2 gives the papers'
        4th-order filter.
    y0, yd0, x0 : float
        Initial conditions of the three integrators: ``y(0)`` (rad/s), ``y'(0)`` (rad/s^2),
        ``x(0)`` (rad). Paper 000's C2, C1, C3.
    noise_power : float
        Height of the power spectral density of the band-limited white output noise (rad^2/Hz,
        Simulink convention: variance = power * 2 * band); 0 = no noise.
    noise_band : float
        Band of the noise (Hz); the noise is held over samples ``1/(2*band)`` long.
    noise_seed : int
        Seed of the ``numpy.random.Generator`` that draws the noise.
    """

    name: ClassVar[str] = "custom"

    gain: float
    damping: float
    stiffness: float
    dead_zone: float
    dead_zone_position: DeadZonePosition
    backlash: float
    delay: float
    delay_position: DelayPosition
    feedback_gain: float = 1.0
    friction_offset: float = 0.0
    bandpass_gain: float = 0.0
    bandpass_saturation: float = math.inf
    bandpass_low_hz: float = 9.0
    bandpass_high_hz: float = 10.0
    bandpass_order: int = 2
    y0: float = 0.0
    yd0: float = 0.0
    x0: float = 0.0
    noise_power: float = 0.0
    noise_band: float = 500.0
    noise_seed: int = 0

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "dead_zone_position":
                object.__setattr__(self, f.name, _enum(DeadZonePosition, value, f.name))
                continue
            if f.name == "delay_position":
                object.__setattr__(self, f.name, _enum(DelayPosition, value, f.name))
                continue
            if f.name in ("bandpass_order", "noise_seed"):
                if isinstance(value, float) and value.is_integer():
                    value = int(value)
                if not isinstance(value, int) or isinstance(value, bool):
                    raise ValueError(f"{f.name} must be an integer (got {value!r})")
                if f.name == "bandpass_order" and not 1 <= value <= 4:
                    raise ValueError(f"bandpass_order must be 1..4 (got {value})")
                if f.name == "noise_seed" and value < 0:
                    raise ValueError(f"noise_seed must be >= 0 (got {value})")
                object.__setattr__(self, f.name, value)
                continue
            if value is None and f.name in OPEN_FIELDS:  # JSON null: the open value
                value = math.inf
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"{f.name} must be a number (got {value!r})") from None
            if math.isnan(value):
                raise ValueError(f"{f.name} is NaN")
            if math.isinf(value) and f.name != "bandpass_saturation":
                raise ValueError(f"{f.name} must be finite (got {value})")
            if f.name in _NONNEGATIVE and value < 0:
                raise ValueError(f"{f.name} must be >= 0 (got {value})")
            if f.name in _POSITIVE and value <= 0:
                raise ValueError(f"{f.name} must be > 0 (got {value})")
            object.__setattr__(self, f.name, value)
        if self.bandpass_low_hz >= self.bandpass_high_hz:
            raise ValueError(
                f"bandpass_low_hz ({self.bandpass_low_hz}) must be below "
                f"bandpass_high_hz ({self.bandpass_high_hz})"
            )

    # -- derived views -------------------------------------------------------------------------
    @property
    def has_bandpass_loop(self) -> bool:
        """True when the band-pass feedback loop is present (``G > 0``)."""
        return self.bandpass_gain > 0.0

    @property
    def abc(self):
        """Paper 000's integrator gains ``(A, B, C)`` of the second-order block."""
        return self.gain / self.damping, self.damping, self.stiffness / self.gain

    def linear_block(self):
        """Numerator and denominator of the second-order block ``K1/(s^2 + K2 s + K3)``."""
        return [self.gain], [1.0, self.damping, self.stiffness]

    def linear_actuator(self):
        """Numerator and denominator of the actuator's linear part with its backlash loop closed.

        With the dead zone, backlash, friction and band-pass loop removed and no delay,
        ``delta/u = K1 / (s^3 + K2 s^2 + K3 s + K*K1)``: paper 002 eq. 9 with ``Z = F = 1`` and
        paper 001 eq. 1 (``305500/(s^3 + 202.1 s^2 + 14520 s + 326800)``).
        """
        return [self.gain], [1.0, self.damping, self.stiffness, self.feedback_gain * self.gain]

    def replace(self, **changes) -> "ActuatorParams":
        """A copy with some fields changed; an unknown field raises a ``ValueError`` naming it."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ValueError(
                f"unknown parameter(s) {', '.join(unknown)} for {self.name}; "
                f"known: {', '.join(sorted(known))}"
            )
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """Plain JSON-ready dictionary of every field (enums as their string values)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = value.value if isinstance(value, Enum) else value
        return out

    @classmethod
    def parameter_names(cls):
        """Names of every field, in declaration order."""
        return tuple(f.name for f in fields(cls))


def _enum(kind, value, field_name):
    if isinstance(value, kind):
        return value
    try:
        return kind(str(value).lower())
    except ValueError:
        choices = ", ".join(m.value for m in kind)
        raise ValueError(f"{field_name} must be one of {choices} (got {value!r})") from None


@dataclass(frozen=True)
class M002(ActuatorParams):
    """Paper 002 (describing-function identification), Fig. 1 and eq. 1.

    ``v'' + 370 v' + 34100 v = 37*34100 * DZ_zm(e)``, ``x' = v``, ``delta(t) = x(t - 7 ms)``.
    Dead zone ``zm = 1.2e-3`` rad and backlash printed as ``f = 4.364e-4`` rad (section 6), read as
    the full width, so the play half width is ``r = 2.182e-4`` rad (``docs/models.md#errata``: this
    reading gives 5.0e-3 rad at 8.6 rad/s as the paper's simulation).
    """

    name: ClassVar[str] = "M002"

    gain: float = 37.0 * 34100.0
    damping: float = 370.0
    stiffness: float = 34100.0
    dead_zone: float = 1.2e-3
    dead_zone_position: DeadZonePosition = DeadZonePosition.ERROR
    backlash: float = 0.5 * 4.364e-4
    delay: float = 7e-3
    delay_position: DelayPosition = DelayPosition.OUTPUT
    x0: float = KICK_X0


@dataclass(frozen=True)
class M001i(ActuatorParams):
    """Paper 001 initial model, section 2 and eq. 1.

    ``y'' + 202.1 y' + 14520 y = 305500 e``, ``x' = DZ_0.0092(y)``, ``K = 326800/305500 = 1.0697``,
    ``r = 1.1625e-4`` rad, ``delta(t) = x(t - 5.6 ms)``. The dead zone acts on the velocity-level
    signal (``docs/models.md#m001i``: at the transfer-function input 0.0092 gives a 0.15 rad cycle).
    """

    name: ClassVar[str] = "M001i"

    gain: float = 305500.0
    damping: float = 202.1
    stiffness: float = 14520.0
    feedback_gain: float = 1.0697
    dead_zone: float = 0.0092
    dead_zone_position: DeadZonePosition = DeadZonePosition.VELOCITY
    backlash: float = 1.1625e-4
    delay: float = 5.6e-3
    delay_position: DelayPosition = DelayPosition.OUTPUT
    x0: float = KICK_X0


@dataclass(frozen=True)
class M001f(ActuatorParams):
    """Paper 001 final model, section 4 (Fig. 8) and section 5 values.

    ``y`` as in :class:`M001i`; ``v(t) = y(t - 1.7 ms)``; ``w = FRIC(DZ_0.0083(v + p))``;
    ``x' = w``; ``delta = x``; ``p = sat_0.015(48 * BP(w))`` with the 9-10 Hz 4th-order Butterworth
    band-pass, positive feedback, friction offset -0.0054.
    """

    name: ClassVar[str] = "M001f"

    gain: float = 305500.0
    damping: float = 202.1
    stiffness: float = 14520.0
    feedback_gain: float = 1.0697
    dead_zone: float = 0.0083
    dead_zone_position: DeadZonePosition = DeadZonePosition.VELOCITY
    backlash: float = 1.1625e-4
    delay: float = 1.7e-3
    delay_position: DelayPosition = DelayPosition.BEFORE_INTEGRATOR
    friction_offset: float = -0.0054
    bandpass_gain: float = 48.0
    bandpass_saturation: float = 0.015
    x0: float = KICK_X0


@dataclass(frozen=True)
class M000(ActuatorParams):
    """Paper 000 final model, section 5, Fig. 12 and Table 1.

    ``y'' = B*[A*(e - C*y) - y'](t - Td)`` (delay before the first integrator), then as in
    :class:`M001f`. Table 1: A = 1511.6 (printed 15116, a misplaced decimal point that diverges),
    B = 202.1, C = 0.0475, dead zone 0.0083, backlash 1.1625e-4, delay 1.7e-3, friction offset
    -0.0054, saturation 0.01, F = 72 (band-pass loop gain), K = 1.0697; initial conditions
    C1 = y'(0) = 0.1, C2 = y(0) = 0.1, C3 = x(0) = 0.0052 (Fig. 13).
    """

    name: ClassVar[str] = "M000"

    gain: float = 1511.6 * 202.1
    damping: float = 202.1
    stiffness: float = 0.0475 * 1511.6 * 202.1
    feedback_gain: float = 1.0697
    dead_zone: float = 0.0083
    dead_zone_position: DeadZonePosition = DeadZonePosition.VELOCITY
    backlash: float = 1.1625e-4
    delay: float = 1.7e-3
    delay_position: DelayPosition = DelayPosition.BEFORE_FIRST_INTEGRATOR
    friction_offset: float = -0.0054
    bandpass_gain: float = 72.0
    bandpass_saturation: float = 0.01
    y0: float = 0.1
    yd0: float = 0.1
    x0: float = 0.0052


HYPOTHESES = {cls.name: cls for cls in (M002, M001i, M001f, M000)}


def hypothesis(name: str, **overrides) -> ActuatorParams:
    """The hypothesis called ``name`` (case-insensitive) with its paper defaults and ``overrides``.

    Raises
    ------
    UnknownHypothesisError
        If ``name`` is not one of M002, M001i, M001f, M000.
    """
    by_lower = {key.lower(): cls for key, cls in HYPOTHESES.items()}
    cls = by_lower.get(str(name).lower())
    if cls is None:
        raise UnknownHypothesisError(
            f"unknown hypothesis {name!r}; choose one of {', '.join(HYPOTHESES)}"
        )
    return cls().replace(**overrides) if overrides else cls()


def params_from_dict(name: str, parameters: dict) -> ActuatorParams:
    """Rebuild a parameter object from a name and :meth:`ActuatorParams.to_dict` output.

    ``name`` is a hypothesis name or ``"custom"`` (the general :class:`ActuatorParams`); this is how
    a recording's sidecar (keys ``hypothesis`` and ``parameters``) is turned back into a model.
    ``None`` (JSON ``null``, as tvcid's strict JSON writes an infinite value) stands for the open
    value of a field whose default is infinite (``bandpass_saturation``: no saturation), as in
    :class:`ActuatorParams` itself.
    """
    if str(name).lower() == ActuatorParams.name:
        known = set(ActuatorParams.parameter_names())
        unknown = sorted(set(parameters) - known)
        if unknown:
            raise ValueError(f"unknown parameter(s) {', '.join(unknown)} for custom")
        return ActuatorParams(**parameters)
    return hypothesis(name, **parameters)
