"""Analytic first-harmonic describing functions of the actuator's elements.

Convention: for the input ``A sin(wt)`` an element's output has the first harmonic
``b1 sin(wt) + a1 cos(wt)``; its describing function is the complex gain ``N = (b1 + j a1)/A``
(paper 002 eq. 2), so a phase lag gives a negative imaginary part. Every width is a *half* width,
as in :mod:`tvcid.models.nonlinearities`; paper 002's backlash ``f`` is converted with
``full_width=`` (``docs/models.md#conventions``).

All functions accept scalars or arrays of amplitudes and return float (static odd elements) or
complex (play operator) arrays of the same shape.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "dead_zone_df",
    "saturation_df",
    "relay_df",
    "friction_offset_df",
    "dead_zone_friction_df",
    "backlash_df",
    "inverse_dead_zone_df",
]


def _amplitude(amplitude):
    a = np.asarray(amplitude, dtype=float)
    if np.any(~np.isfinite(a)) or np.any(a <= 0):
        raise ValueError(f"amplitude must be finite and > 0 (got {amplitude!r})")
    return a


def _width(name, value):
    value = float(value)
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0 (got {value!r})")
    return value


def _saturation_shape(ratio):
    """``(2/pi)(asin(rho) + rho sqrt(1 - rho^2))`` for ``rho = min(ratio, 1)``."""
    rho = np.minimum(ratio, 1.0)
    return (2.0 / np.pi) * (np.arcsin(rho) + rho * np.sqrt(1.0 - rho * rho))


def dead_zone_df(amplitude, half_width):
    """Describing function of the dead zone ``DZ_z`` (paper 002 eq. 3).

    ``N(A) = 1 - (2/pi)(asin(z/A) + (z/A) sqrt(1 - (z/A)^2))`` for ``A > z``, 0 for ``A <= z``.
    Real, increasing from 0 to 1.

    Parameters
    ----------
    amplitude : float or array_like
        Input amplitude ``A`` (> 0).
    half_width : float
        Half width ``z`` (>= 0).
    """
    a = _amplitude(amplitude)
    z = _width("half_width", half_width)
    return 1.0 - _saturation_shape(z / a)


def inverse_dead_zone_df(gain):
    """The ratio ``z/A`` at which the dead-zone describing function equals ``gain`` (0 < gain < 1).

    Used by paper 002's eqs. 3 and 18 to turn a required dead-zone gain into the width ``zm``.
    """
    from scipy.optimize import brentq

    gain = float(gain)
    if not 0.0 < gain < 1.0:
        raise ValueError(
            f"a dead zone's describing function lies in (0, 1); the required gain {gain:.6g} "
            "cannot be met by any dead zone"
        )
    return brentq(lambda rho: 1.0 - _saturation_shape(rho) - gain, 0.0, 1.0, xtol=1e-15, rtol=1e-15)


def saturation_df(amplitude, level):
    """Describing function of the saturation ``sat_s``: 1 for ``A <= s``, else
    ``(2/pi)(asin(s/A) + (s/A) sqrt(1 - (s/A)^2))`` (Slotine and Li 1991, section 5.3)."""
    a = _amplitude(amplitude)
    s = float(level)
    if not s > 0:
        raise ValueError(f"saturation level must be > 0 (got {level!r})")
    return _saturation_shape(s / a)


def relay_df(amplitude, level):
    """Describing function of the ideal relay ``level*sign(q)``: ``4 level/(pi A)``."""
    a = _amplitude(amplitude)
    return 4.0 * float(level) / (np.pi * a)


def friction_offset_df(amplitude, offset):
    """Describing function of the friction offset ``FRIC(q) = q + off*sign(q)`` (paper 001
    section 3): ``1 + 4 off/(pi A)``; below 1 for the paper's negative offset, negative for
    ``A < 4|off|/pi``."""
    return 1.0 + relay_df(amplitude, offset)


def dead_zone_friction_df(amplitude, half_width, offset):
    """Describing function of the chain ``FRIC(DZ_z(q))`` (paper 001 Fig. 8, before the integral).

    ``off*sign(DZ_z(q))`` is a relay that switches only outside the dead zone, so
    ``N = N_DZ(A) + (4 off/(pi A)) sqrt(1 - (z/A)^2)`` for ``A > z`` and 0 otherwise.
    """
    a = _amplitude(amplitude)
    z = _width("half_width", half_width)
    rho = np.minimum(z / a, 1.0)
    return dead_zone_df(a, z) + 4.0 * float(offset) / (np.pi * a) * np.sqrt(1.0 - rho * rho)


def backlash_df(amplitude, half_width=None, *, full_width=None):
    """Describing function of the backlash as a play operator (paper 002 eqs. 4-5).

    With ``beta = 2r/A - 1`` and ``r`` the half width, for ``A > r``::

        Re N = (1/pi) (pi/2 - asin(beta) - beta sqrt(1 - beta^2))      (b1/A, eq. 5)
        Im N = (4r/(pi A)) (r/A - 1)                                   (a1/A, eq. 5)

    and ``N = 0`` for ``A <= r`` (the output stays still). Paper 002's eq. 5 is written with its
    ``f`` as this half width; its section 6 value ``f = 4.364e-4`` reproduces the paper's simulated
    cycle only as a *full* width (``docs/models.md#errata``), so pass exactly one of ``half_width``
    or ``full_width`` and say which.

    Parameters
    ----------
    amplitude : float or array_like
        Input amplitude ``A`` (> 0).
    half_width : float, optional
        Half width ``r`` (>= 0); total play ``2r``.
    full_width : float, optional
        Total play ``2r`` (Simulink "deadband width", paper 002's reading of ``f``).

    Returns
    -------
    complex ndarray
    """
    if (half_width is None) == (full_width is None):
        raise ValueError("give exactly one of half_width or full_width for the backlash")
    r = _width("half_width", half_width) if full_width is None else 0.5 * _width("full_width", full_width)
    a = _amplitude(amplitude)
    ratio = np.minimum(r / a, 1.0)
    beta = 2.0 * ratio - 1.0
    real = (np.pi / 2.0 - np.arcsin(beta) - beta * np.sqrt(np.maximum(1.0 - beta * beta, 0.0))) / np.pi
    imag = (4.0 * ratio / np.pi) * (ratio - 1.0)
    return real + 1j * imag
