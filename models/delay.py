"""Pure transport delay with the project's convention: output 0 before ``t = Td``, linear
interpolation between samples (``docs/models.md#conventions``); the step-by-step line ramps a jump
at ``t = 0`` in over the step before ``Td`` so that its output is continuous in the delay.

Papers 002 (7 ms at the output), 001 (5.6 ms at the output, then 1.7 ms before the integrator) and
000 (before the first integrator, section 4.2) all use it; the numba kernel inlines the same rule.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["DelayLine", "transport_delay"]


def transport_delay(t, signal, delay):
    """``signal(t - delay)`` on the sample times ``t``: 0 before ``t[0] + delay``, linear between.

    Parameters
    ----------
    t : array_like
        Increasing sample times (s).
    signal : array_like
        Samples of the signal at ``t``.
    delay : float
        Delay ``Td >= 0`` (s).
    """
    if not (math.isfinite(delay) and delay >= 0):
        raise ValueError(f"delay must be a finite number >= 0 (got {delay!r})")
    t = np.asarray(t, dtype=float)
    return np.interp(t - delay, t, np.asarray(signal, dtype=float), left=0.0)


class DelayLine:
    """Transport delay of a signal written one grid point at a time (uniform step ``dt``).

    ``read(t)`` returns the written signal at ``t - delay``, linearly interpolated between the
    written samples and a 0 one step before the first (the line is empty before ``t = 0``), so
    that the output is continuous in the delay (a jump at ``t = 0`` reaches the output over the
    step before ``t = delay``; read at the first stage after ``t = delay`` it would move in jumps of
    half a step, and with it the likelihood of an open-loop test). Reading needs the samples up to
    ``t - delay``, so a step-by-step integrator requires ``delay >= dt``.

    A signal that jumps at a grid point (a controller held at 200 Hz, seen before the first
    integrator) is written with its value just before the jump (``left``): the line then
    interpolates towards that value and jumps at the point's delayed time, instead of spreading
    the jump over the step before it (half a step early in effect: M000 held at 200 Hz would read a
    cycle 2 % small at 5e-4 s). ``read(t, share)`` also averages the jump over ``[t - share,
    t + share]``, an RK4 stage's share of the step (``dt/6`` at a node, ``dt/3`` at the midpoint),
    so that the integral of the delayed jump is exact wherever it falls in the step (as
    :meth:`tvcid.models.experiments.OpenLoop.solver_command` does for a command's edges).
    """

    def __init__(self, delay, dt):
        self.delay = delay
        self.dt = dt
        self.values = []
        self.lefts = []

    def write(self, value, left=None):
        self.values.append(value)
        self.lefts.append(value if left is None else left)

    def read(self, t, share=0.0):
        tau = (t - self.delay) / self.dt
        if abs(tau - round(tau)) < 1e-9:
            tau = float(round(tau))
        if tau <= -1.0:
            return 0.0
        if tau < 0:  # between the line's 0 before t = 0 and the first sample: continuous in delay
            return (1.0 + tau) * self.values[0]
        j = int(math.floor(tau))
        frac = tau - j
        value = (1.0 - frac) * self.values[j]
        if frac > 0:
            value += frac * self.lefts[j + 1]
        w = share / self.dt
        if w > 0:
            # the jump at a node inside the share, averaged over it (the point sees one side)
            if frac < w:
                value -= (self.values[j] - self.lefts[j]) * (w - frac) / (2.0 * w)
            if frac > 0 and frac + w > 1.0:
                value += (self.values[j + 1] - self.lefts[j + 1]) * (frac + w - 1.0) / (2.0 * w)
        return value
