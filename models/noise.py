"""Band-limited white output noise (paper 000 section 4.3).

Paper 000 adds a Simulink "band-limited white noise" block to the actuator output, its power
matched to the flat 20-100 Hz floor of the measured spectrum. That block holds independent Gaussian
samples over a sample time ``Ts`` with variance ``power / Ts``; tvcid names the band
``1/(2 Ts)`` (Hz), so the variance is ``power * 2 * band``.
"""
from __future__ import annotations

import math

__all__ = ["band_limited_white_noise", "noise_std"]


def noise_std(power, band):
    """Standard deviation (rad) of the held samples for PSD height ``power`` over ``band`` Hz."""
    return math.sqrt(power * 2.0 * band)


def band_limited_white_noise(power, band, t_end, rng):
    """Held noise samples covering ``[0, t_end]``.

    Parameters
    ----------
    power : float
        PSD height (rad^2/Hz), two-sided in Simulink's convention.
    band : float
        Band (Hz); samples are held for ``1/(2*band)`` s.
    t_end : float
        Duration (s) to cover.
    rng : numpy.random.Generator
        Source of every draw.

    Returns
    -------
    numpy.ndarray
        Samples; sample ``i`` holds on ``[i, i+1) / (2*band)``.
    """
    n = int(math.floor(t_end * 2.0 * band)) + 2
    return noise_std(power, band) * rng.standard_normal(n)
