"""Linear blocks: the Butterworth band-pass of the feedback loop, as a state-space model, and the
frequency response of the second-order block with its delay.

Paper 001 section 4 ("a 4th order Butterworth design, with frequencies between 9 and 10 Hz");
``docs/models.md#conventions`` fixes it as
``scipy.signal.butter(2, [2*pi*9, 2*pi*10], 'bandpass', analog=True)``.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import signal

__all__ = ["bandpass_transfer_function", "bandpass_state_space", "second_order_response",
           "MAX_BANDPASS_STATES"]

#: Largest band-pass state the kernel carries (order 4 -> 8 states).
MAX_BANDPASS_STATES = 8


@lru_cache(maxsize=64)
def bandpass_transfer_function(low_hz, high_hz, order=2):
    """Analog Butterworth band-pass ``(num, den)`` in ``s``; ``2*order`` poles.

    Cached (a harmonic-balance solve evaluates the same filter hundreds of times); the arrays
    are read-only."""
    num, den = signal.butter(order, [2 * np.pi * low_hz, 2 * np.pi * high_hz], "bandpass",
                             analog=True)
    for x in (num, den):
        x.setflags(write=False)
    return num, den


@lru_cache(maxsize=64)
def bandpass_state_space(low_hz, high_hz, order=2):
    """Band-pass as ``(A, B, C)`` with ``D = 0`` (the filter is strictly proper).

    Cached (batches pack the same filter many times); the arrays are read-only.

    Returns
    -------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n,)
    c : ndarray, shape (n,)
    """
    num, den = bandpass_transfer_function(low_hz, high_hz, order)
    a, b, c, d = signal.tf2ss(num, den)
    if abs(float(np.ravel(d)[0])) > 1e-12:
        raise ValueError("band-pass filter is not strictly proper")
    a, b, c = a.copy(), b.ravel().copy(), c.ravel().copy()
    for arr in (a, b, c):
        arr.setflags(write=False)
    return a, b, c


def second_order_response(gain, damping, stiffness, delay, inside, omega):
    """Frequency response of the second-order block and its transport delay
    (``docs/models.md#the-actuator``).

    ``inside`` (the delay before the first integrator, ``y'' = [K1 e - K2 y' - K3 y](t - Td)``):
    ``K1 / (s^2 e^{s Td} + K2 s + K3)``; otherwise (the delay before the integrator or at the
    output; with the nonlinearities left out both read as a delay after the block):
    ``K1 e^{-s Td} / (s^2 + K2 s + K3)``.

    Parameters
    ----------
    gain, damping, stiffness : float
        ``K1`` (1/s^2 per rad of error), ``K2`` (1/s), ``K3`` (1/s^2).
    delay : float
        ``Td`` (s).
    inside : bool
    omega : array_like
        Angular frequencies (rad/s).

    Returns
    -------
    ndarray of complex
    """
    s = 1j * np.asarray(omega, dtype=float)
    if inside:
        return gain / (s * s * np.exp(s * delay) + damping * s + stiffness)
    return gain * np.exp(-s * delay) / (s * s + damping * s + stiffness)
