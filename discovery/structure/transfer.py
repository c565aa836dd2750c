"""Starts carried from one structure to another: a structure's optimum as the start of another.

* :func:`delay_moved` -- the delay moved to another place, the linear block changed so that its
  frequency response matches (to first order, :func:`first_order_moved`, then by least squares);
* :func:`transferred` -- any structure's parameters as a start for another (the delay moved, a
  dead zone moved between error and velocity in rad of error, components removed or added);
* :func:`reduced_values` and :func:`widened_values` -- the values a nested structure keeps from
  its parent, and those a larger structure starts its absent parts at.

Used by :mod:`.structure_search`'s stages and by tests that start at a drawn truth.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq, least_squares

from tvcid.models.hypotheses import DeadZonePosition, DelayPosition
from tvcid.models.linear import second_order_response

__all__ = ["delay_moved", "first_order_moved", "reduced_values", "transferred",
           "widened_values", "MATCHED_BAND", "MATCHED_RANGE"]

#: Band over which :func:`delay_moved` matches the moved block's frequency response, in units of
#: the block's natural frequency ``sqrt(K3)``: the limit cycles (2-10 Hz) and the open-loop tests'
#: edges ring below it (M000: 19 Hz).
MATCHED_BAND = (0.05, 1.5)
#: Factor within which each coefficient of the moved block stays of the given one's.
MATCHED_RANGE = 10.0


def delay_moved(params, position):
    """``params`` with the delay moved to ``position`` and the linear block changed to match.

    Inside the second-order block's loop (``before_first_integrator``,
    ``y'' = [K1 e - K2 y' - K3 y](t - Td)``) the block is ``K1 / (s^2 e^{s Td} + K2 s + K3)``;
    after it, ``K1 e^{-s Td} / (s^2 + K2 s + K3)`` (:func:`tvcid.models.linear.second_order_response`).
    The moved block is the one whose frequency response matches the given one over
    ``MATCHED_BAND`` of the given block's natural frequency ``sqrt(K3)`` (log gain and phase, least
    squares), started from the first-order match (:func:`first_order_moved`), which alone fails
    where ``K2 Td`` is not small. The two outer positions
    (before the integrator, at the output) share the block.
    """
    inner = DelayPosition.BEFORE_FIRST_INTEGRATOR
    if (params.delay_position is inner) == (position is inner):
        return params.replace(delay_position=position)
    start = first_order_moved(params, position)
    if not params.delay > 0:
        return start
    omega = np.geomspace(MATCHED_BAND[0], MATCHED_BAND[1], 48) * math.sqrt(params.stiffness)
    target = second_order_response(params.gain, params.damping, params.stiffness, params.delay,
                                   params.delay_position is inner, omega)

    def mismatch(x):
        k1, k2, k3, td = np.exp(x)
        ratio = second_order_response(k1, k2, k3, td, position is inner, omega) / target
        return np.concatenate([np.log(np.abs(ratio)), np.angle(ratio)])

    # within MATCHED_RANGE of the given block: a resonant inner block (long delay) has no outer
    # match, and the fit would drift off with every coefficient growing together
    source = np.log([params.gain, params.damping, params.stiffness, params.delay])
    lo, hi = source - math.log(MATCHED_RANGE), source + math.log(MATCHED_RANGE)
    x0 = np.clip(np.log([start.gain, start.damping, start.stiffness, start.delay]), lo, hi)
    fit = least_squares(mismatch, x0, bounds=(lo, hi), xtol=1e-10, ftol=1e-12)
    if not (np.all(np.isfinite(fit.x)) and fit.cost < 0.5 * float(np.sum(mismatch(x0) ** 2))):
        return start
    k1, k2, k3, td = map(float, np.exp(fit.x))
    return start.replace(gain=k1, damping=k2, stiffness=k3, delay=td)


def first_order_moved(params, position):
    """:func:`delay_moved` to first order in ``s Td``.

    With ``D = 1 + K2 Td`` of the outer form, ``K1, K3`` inside are the outer ones over ``D``,
    ``K2`` inside is ``(K2 + K3 Td) / D`` and the delay inside is ``Td / D``.
    """
    inner = DelayPosition.BEFORE_FIRST_INTEGRATOR
    k1, k2, k3, td = params.gain, params.damping, params.stiffness, params.delay
    if position is inner:  # outer -> inner
        d = 1.0 + k2 * td
        return params.replace(gain=k1 / d, damping=(k2 + k3 * td) / d, stiffness=k3 / d,
                              delay=td / d, delay_position=position)
    # inner -> outer: the D whose outer block maps onto this inner one (K2 outer = (D - 1) / Td)
    def mismatch(d):
        return k2 * d - (d - 1.0) / (td * d) - k3 * td * d * d

    if td <= 0 or mismatch(1.0) <= 0 or mismatch(20.0) >= 0:
        return params.replace(delay_position=position)
    d = brentq(mismatch, 1.0, 20.0)
    return params.replace(gain=k1 * d, damping=(d - 1.0) / (td * d), stiffness=k3 * d,
                          delay=td * d, delay_position=position)


def transferred(params, structure):
    """Another structure's ``params`` as a start for ``structure``.

    The delay is moved with :func:`delay_moved`; a dead zone moved between the error and the
    velocity signal keeps its threshold in rad of error (``z_error = (z - off) / g0``, ``g0 = K1/K3``
    the second-order block's static gain, the search coordinate ``log_c_e``); a component removed
    leaves the moving threshold as it was (:func:`reduced_values`), one added starts small
    (:func:`widened_values`; the band-pass loop at gain 40 and a saturation of 5e-4 rad of error).
    """
    p = delay_moved(params, structure.delay_position)
    g0 = p.gain / p.stiffness
    values = reduced_values(p, structure)
    moving = values.get("dead_zone", p.dead_zone - p.friction_offset)
    if p.dead_zone_position is not structure.dead_zone_position:
        if structure.dead_zone_position is DeadZonePosition.VELOCITY:
            values["dead_zone"] = moving * g0
        else:
            values["dead_zone"] = moving / g0
        values["friction_offset"] = 0.0
    elif not structure.friction:
        values["friction_offset"] = 0.0
    if structure.bandpass and p.bandpass_gain == 0.0:
        values.update(bandpass_gain=40.0, bandpass_saturation=5e-4 * g0)
    start = structure.to_params(p, **values)
    return structure.to_params(start, **widened_values(start, structure))


def reduced_values(params, s):
    """Start values for nested ``s`` from its parent's ``params``: the moving threshold kept."""
    values = {}
    if not s.friction and params.friction_offset != 0.0:
        values["dead_zone"] = params.dead_zone - params.friction_offset
    return values


def widened_values(p, s):
    """A nested proposal as a start for a larger structure: small values for its absent parts."""
    extra = {}
    if s.backlash and p.backlash == 0.0:
        extra["backlash"] = 1e-5
    if s.friction and p.friction_offset == 0.0:
        extra["friction_offset"] = -0.1 * p.dead_zone
    return extra
