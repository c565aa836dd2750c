"""Pure transport delay with the project's convention: output 0 before ``t = Td``, linear
interpolation between samples (MODELS.md "Conventions"); the step-by-step line ramps a jump at
``t = 0`` in over the step before ``Td`` so that its output is continuous in the delay.

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
    step before ``t = delay``; read at the first stage after ``t = delay``, as before, it moved in
    jumps of half a step, and with it the likelihood of an open-loop test). Reading needs the samples up to
    ``t - delay``, so a step-by-step integrator requires ``delay >= dt``.
    """

    def __init__(self, delay, dt):
        self.delay = delay
        self.dt = dt
        self.values = []

    def write(self, value):
        self.values.append(value)

    def read(self, t):
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
            value += frac * self.values[j + 1]
        return value
