"""Linear compensators in series with the PD controller, and the vehicle's bending mode.

The HWIL loop of paper 002 (section 1) closes the attitude loop through a PD controller; the
designer's question that motivates the paper is what a lead filter (to shape the limit cycle) and a
notch filter (for the bending mode) do to the cycle. The controller is therefore

``u = -Kp (1 + Kd s) F(s) theta_m``,

with ``F(s)`` a proper transfer function (:class:`TransferFunction`, unit DC gain for the named
blocks) and ``theta_m`` the sensed attitude: the rigid vehicle ``mu/s^2`` plus, optionally, a
lightly damped bending mode in parallel (:class:`BendingMode`). A controller known only as a
transfer function ``C(s)`` is ``Kp = 1``, ``Kd = 0``, ``F = C``; ``C`` must then be proper, as any
realisable controller is (the PD's derivative comes from the sensed rate, not from ``F``).

Frequencies are in rad/s throughout, as the limit cycle's frequency is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BendingMode", "ImproperTransferFunctionError", "TransferFunction"]


class ImproperTransferFunctionError(ValueError):
    """A transfer function whose numerator degree exceeds its denominator's."""


def _coefficients(name, values) -> tuple:
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a list of numbers, got {values!r}") from None
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a non-empty list of numbers, got {values!r}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has a non-finite coefficient: {arr.tolist()}")
    nonzero = np.flatnonzero(arr)
    if nonzero.size == 0:
        raise ValueError(f"{name} is all zeros")
    return tuple(float(v) for v in arr[nonzero[0]:])


@dataclass(frozen=True)
class TransferFunction:
    """A proper SISO transfer function ``num(s)/den(s)``, coefficients highest power first.

    Parameters
    ----------
    num, den : sequence of float
        Polynomial coefficients in ``s`` (highest power first); leading zeros are dropped.
    name : str
        What the block is (``"lead"``, ``"notch"``, ``"series"``, ``"tf"``), for reports.

    Raises
    ------
    ImproperTransferFunctionError
        When ``len(num) > len(den)``: a controller cannot differentiate its input.
    """

    num: tuple
    den: tuple
    name: str = "tf"

    def __post_init__(self):
        num = _coefficients("controller numerator", self.num)
        den = _coefficients("controller denominator", self.den)
        if len(num) > len(den):
            raise ImproperTransferFunctionError(
                f"controller transfer function is improper (numerator degree {len(num) - 1} > "
                f"denominator degree {len(den) - 1}): give a proper F(s); the PD's derivative is "
                "Kd, taken from the sensed rate"
            )
        scale = den[0]
        object.__setattr__(self, "num", tuple(v / scale for v in num))
        object.__setattr__(self, "den", tuple(v / scale for v in den))

    # -- named blocks -------------------------------------------------------------------------
    @classmethod
    def lead(cls, zero, pole):
        """Lead (``zero < pole``) or lag (``zero > pole``) ``(1 + s/zero)/(1 + s/pole)``, unit DC gain.

        Parameters
        ----------
        zero, pole : float
            Corner frequencies (rad/s), > 0. The peak phase, at ``sqrt(zero*pole)``, is
            ``asin((pole - zero)/(pole + zero))``.
        """
        zero, pole = _positive("lead zero", zero), _positive("lead pole", pole)
        return cls((1.0 / zero, 1.0), (1.0 / pole, 1.0), name="lead" if zero < pole else "lag")

    @classmethod
    def notch(cls, frequency, damping=0.5, depth=0.1):
        """Notch ``(s^2 + 2 depth*damping w s + w^2)/(s^2 + 2 damping w s + w^2)``, unit DC gain.

        Parameters
        ----------
        frequency : float
            Notch centre ``w`` (rad/s), > 0.
        damping : float
            Damping of the notch's poles (sets its width), > 0.
        depth : float
            Gain at the centre, in [0, 1).
        """
        w = _positive("notch frequency", frequency)
        zeta = _positive("notch damping", damping)
        depth = float(depth)
        if not (0.0 <= depth < 1.0):
            raise ValueError(f"notch depth must be in [0, 1) (got {depth})")
        return cls((1.0, 2 * depth * zeta * w, w * w), (1.0, 2 * zeta * w, w * w), name="notch")

    @classmethod
    def from_dict(cls, spec) -> "TransferFunction":
        """Build from a sidecar's ``compensator`` value: ``{"num": [...], "den": [...]}``,
        ``{"lead": [zero, pole]}``, ``{"notch": [frequency, damping, depth]}``, or a list of
        these in series."""
        if isinstance(spec, (list, tuple)):
            if not spec:
                raise ValueError("compensator list is empty")
            return cls.series(*(cls.from_dict(s) for s in spec))
        if not isinstance(spec, dict):
            raise ValueError(f"compensator must be an object or a list of objects, got {spec!r}")
        keys = set(spec) - {"name"}
        if keys == {"num", "den"}:
            return cls(spec["num"], spec["den"], name=str(spec.get("name", "tf")))
        if keys == {"lead"}:
            return cls.lead(*_args("lead", spec["lead"], 2, least=2))
        if keys == {"lag"}:
            return cls.lead(*_args("lag", spec["lag"], 2, least=2))
        if keys == {"notch"}:
            return cls.notch(*_args("notch", spec["notch"], 3))
        raise ValueError(
            f"compensator {spec!r}: expected keys num and den, or one of lead, lag, notch"
        )

    def to_dict(self) -> dict:
        return {"num": list(self.num), "den": list(self.den), "name": self.name}

    @classmethod
    def series(cls, *blocks):
        """The product of ``blocks`` (applied one after the other)."""
        if not blocks:
            raise ValueError("series needs at least one block")
        num, den = np.array([1.0]), np.array([1.0])
        for b in blocks:
            num, den = np.polymul(num, b.num), np.polymul(den, b.den)
        names = "*".join(b.name for b in blocks)
        return cls(tuple(num), tuple(den), name=names)

    # -- responses and realisations -----------------------------------------------------------
    @property
    def order(self) -> int:
        return len(self.den) - 1

    def response(self, frequency):
        """``F(jw)`` at ``frequency`` (rad/s)."""
        s = 1j * np.asarray(frequency, dtype=float)
        return np.polyval(self.num, s) / np.polyval(self.den, s)

    def dc_gain(self) -> float:
        if self.den[-1] == 0:
            return math.inf
        return self.num[-1] / self.den[-1]

    def state_space(self):
        """Controllable canonical form ``(A, B, C, D)`` with ``x' = A x + B v``, ``F v = C x + D v``."""
        n = self.order
        den = np.asarray(self.den)
        num = np.zeros(n + 1)
        num[n + 1 - len(self.num):] = self.num
        d = num[0]
        c = (num[1:] - d * den[1:])[::-1]
        a = np.zeros((n, n))
        if n:
            a[:-1, 1:] = np.eye(n - 1)
            a[-1, :] = -den[1:][::-1]
        b = np.zeros(n)
        if n:
            b[-1] = 1.0
        return a, b, c, float(d)

    def discretise(self, sample_rate):
        """Tustin (bilinear) realisation at ``sample_rate`` (Hz): ``(Ad, Bd, Cd, Dd)`` with
        ``x[k+1] = Ad x[k] + Bd v[k]``, ``F v[k] = Cd x[k] + Dd v[k]``, as a digital controller
        would run it."""
        a, b, c, d = self.state_space()
        n = a.shape[0]
        if n == 0:
            return a, b, c, d
        h = 1.0 / _positive("sample_rate", sample_rate)
        eye = np.eye(n)
        inv = np.linalg.inv(eye - 0.5 * h * a)
        ad = inv @ (eye + 0.5 * h * a)
        bd = inv @ b * h
        cd = c @ inv
        dd = d + 0.5 * h * float(c @ inv @ b)
        return ad, bd, cd, dd

    def discrete_response(self, frequency, sample_rate):
        """Frequency response of :meth:`discretise` at ``z = exp(jw/sample_rate)``."""
        z = np.exp(1j * np.asarray(frequency, dtype=float) / sample_rate)
        h = 1.0 / sample_rate
        s = 2.0 / h * (z - 1.0) / (z + 1.0)
        return np.polyval(self.num, s) / np.polyval(self.den, s)


@dataclass(frozen=True)
class BendingMode:
    """A lightly damped bending mode seen by the attitude sensor, in parallel with ``mu/s^2``.

    The sensed attitude is ``theta_m = theta + q`` with
    ``q'' = -2 damping frequency q' - frequency^2 q + gain frequency^2 delta``, i.e. the vehicle
    ``theta_m/delta = mu/s^2 + gain w^2/(s^2 + 2 damping w s + w^2)``.

    Parameters
    ----------
    frequency : float
        Natural frequency ``w`` (rad/s), > 0.
    damping : float
        Damping ratio, > 0 (lightly damped: ~0.005-0.05).
    gain : float
        Sensed rotation per rad of nozzle deflection at low frequency (rad/rad).
    """

    frequency: float
    damping: float
    gain: float

    def __post_init__(self):
        object.__setattr__(self, "frequency", _positive("bending frequency", self.frequency))
        object.__setattr__(self, "damping", _positive("bending damping", self.damping))
        gain = float(self.gain)
        if not math.isfinite(gain):
            raise ValueError(f"bending gain must be finite (got {self.gain})")
        object.__setattr__(self, "gain", gain)

    def response(self, frequency):
        """``gain w^2/(s^2 + 2 damping w s + w^2)`` at ``s = j frequency``."""
        s = 1j * np.asarray(frequency, dtype=float)
        w = self.frequency
        return self.gain * w * w / (s * s + 2 * self.damping * w * s + w * w)

    @classmethod
    def from_dict(cls, spec) -> "BendingMode":
        if not isinstance(spec, dict) or set(spec) != {"frequency", "damping", "gain"}:
            raise ValueError(
                f"bending must be an object with keys frequency, damping, gain; got {spec!r}"
            )
        return cls(**spec)

    def to_dict(self) -> dict:
        return {"frequency": self.frequency, "damping": self.damping, "gain": self.gain}


def _positive(name, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number (got {value!r})") from None
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be > 0 (got {value})")
    return v


def _args(name, values, n, least=1):
    if not isinstance(values, (list, tuple)) or not (least <= len(values) <= n):
        count = f"{n}" if least == n else f"{least} to {n}"
        raise ValueError(f"{name} takes a list of {count} numbers, got {values!r}")
    return values
