"""Static and hysteretic nonlinear elements of the actuator, with their conventions named.

Every width is a *half* width. Paper 002 printed its backlash as the full width of a Simulink
"deadband" block; :func:`backlash_half_width_from_full` converts it. These numpy versions are the
vocabulary of the reference simulator, the describing functions and the SINDy library; the numba
kernel in :mod:`tvcid.models.kernel` inlines the same formulas.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "dead_zone",
    "saturation",
    "friction_offset",
    "sign_switch_average",
    "play_operator",
    "play_step",
    "backlash_half_width_from_full",
]


def dead_zone(q, half_width):
    """Dead zone ``DZ_z(q)``: 0 where ``|q| <= z``, else ``q - z*sign(q)``.

    Paper 002 eq. 3 (its describing function); ``docs/models.md#conventions``.

    Parameters
    ----------
    q : float or array_like
        Input signal.
    half_width : float
        Half width ``z`` (>= 0), in the units of ``q``.
    """
    q = np.asarray(q, dtype=float)
    return np.where(np.abs(q) <= half_width, 0.0, q - half_width * np.sign(q))


def saturation(q, level):
    """Saturation ``sat_s(q) = clip(q, -s, s)`` (paper 001 section 3, the band-pass loop limiter)."""
    return np.clip(np.asarray(q, dtype=float), -level, level)


def friction_offset(q, offset):
    """Friction offset ``FRIC(q) = q + off*sign(q)`` with ``sign(0) = 0``.

    Paper 001 section 3 models the spikes of the output derivative as a *negative* Coulomb friction,
    ``off = -0.0054``: the offset opposes the direction of the derivative.
    """
    q = np.asarray(q, dtype=float)
    return q + offset * np.sign(q)


def sign_switch_average(q_start, q_end, threshold):
    """Mean over one step of ``sign(DZ_z(q))`` with ``q`` linear from ``q_start`` to ``q_end``.

    The friction offset ``off*sign(q)`` jumps where ``q`` (after a velocity dead zone: where
    ``|q|`` crosses ``z``) changes side. RK4 samples it at the step's start, middle and end, so it
    places the jump at one of a few fixed fractions of the step and the limit cycle's period locks
    to the step grid (the features stop changing with the step or the parameters). The simulators
    replace RK4's weighted mean of the stage signs by this mean, the jump located by linear
    interpolation of ``q`` between the step's first and last stages (error O(dt^2)).

    Parameters
    ----------
    q_start, q_end : float
        The switching signal (before the velocity dead zone) at the step's first and last RK4
        stages.
    threshold : float
        ``z`` when the dead zone acts on the velocity signal, else 0.

    Returns
    -------
    float
        In [-1, 1]: the fraction of the step above ``threshold`` minus the fraction below
        ``-threshold``.
    """
    q_start, q_end, z = float(q_start), float(q_end), float(threshold)

    def fraction_above(a, b, c):  # of the step where a + (b - a) tau > c
        if a > c and b > c:
            return 1.0
        if a <= c and b <= c:
            return 0.0
        crossing = (c - a) / (b - a)
        return 1.0 - crossing if b > c else crossing

    return fraction_above(q_start, q_end, z) - fraction_above(-q_start, -q_end, z)


def play_step(memory, x, half_width):
    """One update of the play operator: ``b <- min(max(b, x - r), x + r)``.

    Parameters
    ----------
    memory : float
        The operator's state ``b`` before the update.
    x : float
        New input.
    half_width : float
        Half width ``r`` of the play (total play ``2r``).
    """
    return min(max(memory, x - half_width), x + half_width)


def play_operator(x, half_width, initial=0.0):
    """Backlash as a play operator applied along a sampled input ``x``.

    ``b_k = min(max(b_{k-1}, x_k - r), x_k + r)`` with ``b_{-1} = initial``. This is the rate
    independent hysteresis whose describing function is paper 002 eqs. 4-5 (there with ``f`` the
    half width).

    Parameters
    ----------
    x : array_like
        Input samples in time order.
    half_width : float
        Half width ``r`` (>= 0).
    initial : float, optional
        Memory before the first sample.

    Returns
    -------
    numpy.ndarray
        Output ``b`` with the shape of ``x``.
    """
    x = np.asarray(x, dtype=float)
    out = np.empty_like(x)
    b = float(initial)
    lo, hi = x - half_width, x + half_width
    for k in range(x.size):
        b = min(max(b, lo[k]), hi[k])
        out[k] = b
    return out


def backlash_half_width_from_full(full_width):
    """Half width ``r = f/2`` from paper 002's full width ``f`` (Simulink "deadband width")."""
    return 0.5 * full_width
