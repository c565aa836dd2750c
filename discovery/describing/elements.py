"""The nonlinear elements as callables on sampled signals, for the numeric describing function.

Each element wraps the function of :mod:`tvcid.models.nonlinearities` (the project's one definition of
each element and its width convention) and knows its analytic describing function from
:mod:`tvcid.discovery.describing.analytic` when one exists. A :class:`Chain` applies elements in order;
its describing function is computed numerically (a chain of memory elements has no closed form).
Elements act on samples in time order, so memory (the play operator) is carried along.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvcid.models.nonlinearities import dead_zone, friction_offset, play_operator, saturation

from . import analytic

__all__ = [
    "DeadZone",
    "Saturation",
    "Relay",
    "FrictionOffset",
    "PlayOperator",
    "Gain",
    "Chain",
]


@dataclass(frozen=True)
class DeadZone:
    """``DZ_z(q)`` with half width ``z`` (paper 002 eq. 3)."""

    half_width: float

    def __call__(self, q):
        return dead_zone(q, self.half_width)

    def analytic_df(self, amplitude):
        return analytic.dead_zone_df(amplitude, self.half_width)


@dataclass(frozen=True)
class Saturation:
    """``sat_s(q) = clip(q, -s, s)`` (paper 001 section 3)."""

    level: float

    def __call__(self, q):
        return saturation(q, self.level)

    def analytic_df(self, amplitude):
        return analytic.saturation_df(amplitude, self.level)


@dataclass(frozen=True)
class Relay:
    """Ideal relay ``level*sign(q)``, i.e. ``FRIC(q) - q`` with :func:`tvcid.models.nonlinearities.friction_offset`."""

    level: float

    def __call__(self, q):
        q = np.asarray(q, dtype=float)
        return friction_offset(q, self.level) - q

    def analytic_df(self, amplitude):
        return analytic.relay_df(amplitude, self.level)


@dataclass(frozen=True)
class FrictionOffset:
    """``FRIC(q) = q + off*sign(q)`` (paper 001 section 3; ``off < 0`` opposes the motion)."""

    offset: float

    def __call__(self, q):
        return friction_offset(q, self.offset)

    def analytic_df(self, amplitude):
        return analytic.friction_offset_df(amplitude, self.offset)


@dataclass(frozen=True)
class PlayOperator:
    """Backlash as the play operator of half width ``r`` (paper 002 eqs. 4-5); a memory element.

    Use ``PlayOperator.from_full_width(f)`` for paper 002's full-width reading of ``f``.
    """

    half_width: float
    initial: float = 0.0

    @classmethod
    def from_full_width(cls, full_width, initial=0.0):
        return cls(0.5 * float(full_width), initial)

    def __call__(self, x):
        return play_operator(x, self.half_width, self.initial)

    def analytic_df(self, amplitude):
        return analytic.backlash_df(amplitude, self.half_width)


@dataclass(frozen=True)
class Gain:
    """A static gain ``k*q`` (to build chains such as the feedback gain ``K`` before the play)."""

    gain: float

    def __call__(self, q):
        return self.gain * np.asarray(q, dtype=float)

    def analytic_df(self, amplitude):
        return np.full(np.shape(amplitude), float(self.gain))


@dataclass(frozen=True)
class Chain:
    """Elements applied in order: ``Chain((DeadZone(z), FrictionOffset(off)))`` is ``FRIC(DZ(q))``.

    A chain has no analytic describing function (``analytic_df`` returns None) except through the
    dedicated formulas of :mod:`tvcid.discovery.describing.analytic`; use
    :func:`tvcid.discovery.describing.numeric.numeric_df`.
    """

    elements: tuple

    def __post_init__(self):
        elements = tuple(self.elements)
        if not elements:
            raise ValueError("a Chain needs at least one element")
        for e in elements:
            if not callable(e):
                raise ValueError(f"chain element {e!r} is not callable")
        object.__setattr__(self, "elements", elements)

    def __call__(self, q):
        out = np.asarray(q, dtype=float)
        for element in self.elements:
            out = element(out)
        return out

    def analytic_df(self, amplitude):
        return None
