"""Where in a record a limit cycle is settled: its stationary tail, the size of each period, and
whether the tail is still settling.

A record may start with a transient or on another attractor, and a cycle born near its
bifurcation may still grow at the record's end. The structure search compares only the settled
tail (:func:`stationary_tail`), and a tail that still settles (:func:`settles`) as the transient
it is; the calibration's feature likelihood tests its pieces for the same exponential approach
(:func:`settling_gain`). Crossings, harmonics and features are read as
:mod:`tvcid.models.cycle_reading` reads them.
"""
from __future__ import annotations

import math

import numpy as np

from .cycle_reading import (
    NoCycleError,
    crossing_hysteresis,
    fourier_harmonics,
    fundamental_crossings,
    peak_to_peak_sizes,
    upward_mean_crossings,
    white_noise_sd,
)

__all__ = [
    "MIN_SETTLING_CROSSINGS",
    "SETTLING_GAIN",
    "SETTLING_MIN_PIECES",
    "TAIL_TOLERANCE",
    "period_sizes",
    "settles",
    "settling_gain",
    "stationary_tail",
]

#: Relative peak-to-peak change that ends a record's stationary tail (:func:`stationary_tail`).
TAIL_TOLERANCE = 0.15
#: A tail whose size per two periods an exponential approach fits this much better than a
#: constant is still settling (:func:`settles`; below the calibration's 100 for feature pieces:
#: a drawn truth's 12 s record still 13 % under its cycle scores 42).
SETTLING_GAIN = 25.0
#: ... from at least this many crossings (two periods to start from, then six to compare).
MIN_SETTLING_CROSSINGS = 9
#: Pieces of a record :func:`settling_gain` needs at least (three parameters and three degrees
#: of freedom).
SETTLING_MIN_PIECES = 6


def _two_period_sizes(t, x, ups):
    """Peak-to-peak of ``x`` over each two consecutive periods (over each one when there are
    fewer than three): lobes that alternate (a beat with a held controller) do not read as a
    change of size, a change of attractor does."""
    p2p = peak_to_peak_sizes(t, x, ups)
    return np.maximum(p2p[:-1], p2p[1:]) if ups.size >= 4 else p2p


def stationary_tail(t, d, name="recording"):
    """The end of a record over which the cycle's amplitude is settled.

    A record may start with a transient or on another attractor (paper 000's small cycle: the
    bundled controller-B record holds a 2.6e-4 rad cycle for 14 s before the large one). Periods
    are taken between upward mean crossings, read at the fundamental
    (:func:`fundamental_crossings`); walking back from the end, the tail keeps every period whose
    peak-to-peak amplitude over it and the next period is within ``TAIL_TOLERANCE`` of the median
    of the last five.

    Returns
    -------
    t, d : ndarray
        The tail.
    ups : ndarray
        Upward mean crossings in it (at least three).

    Raises
    ------
    NoCycleError
        When the record's end holds fewer than two whole periods.
    """
    half = t >= 0.5 * (t[0] + t[-1])
    amp = 0.5 * float(np.ptp(d[half]))
    level = float(np.mean(d[half]))
    ups = (upward_mean_crossings(t, d, level, crossing_hysteresis(d[half], amp)) if amp > 0
           else np.zeros(0))
    ups = fundamental_crossings(ups, peak_to_peak_sizes(t, d, ups), signal=(t, d))
    if ups.size < 3:
        raise NoCycleError(
            f"{name}: no limit cycle in the record ({max(ups.size - 1, 0)} whole periods in its "
            "second half; at least two are needed)")
    p2p = _two_period_sizes(t, d, ups)
    ref = float(np.median(p2p[-5:]))
    first = p2p.size - 1
    while first > 0 and abs(p2p[first - 1] / ref - 1.0) <= TAIL_TOLERANCE:
        first -= 1
    ups = ups[first:]
    if ups.size < 3:
        raise NoCycleError(f"{name}: the cycle's amplitude never settles (two whole periods alike "
                           "are needed at the end of the record)")
    sel = t >= ups[0] - 0.5 * (ups[1] - ups[0])
    return t[sel], d[sel], ups


def period_sizes(t, x, ups):
    """First-harmonic amplitude of ``x`` over each period between consecutive crossings ``ups``
    (a size that sensor noise does not bias, unlike the peak-to-peak)."""
    idx = np.searchsorted(t, ups)  # as peak_to_peak_sizes: the samples in [ups[j], ups[j + 1])
    out = np.empty(ups.size - 1)
    for j, (a, b) in enumerate(zip(idx[:-1], idx[1:])):
        omega = 2 * math.pi / (ups[j + 1] - ups[j])
        out[j] = abs(fourier_harmonics(t[a:b], x[a:b], omega, 1)[0])
    return out


def settling_gain(centres, values, noise_var) -> float:
    """How much better ``a + b exp((c_last - c) / T)`` fits a record's piece features than a
    constant: the chi-square gain at the best time constant ``T`` of a grid, in units of the
    fit's residual variance where that exceeds the noise (a two-mode settling is not one
    exponential). 0 with fewer than :data:`SETTLING_MIN_PIECES` pieces.

    ``centres`` (s, increasing), ``values`` (the pieces' feature), ``noise_var`` (each piece's
    feature variance under sensor noise).
    """
    c = np.asarray(centres, dtype=float)
    f = np.asarray(values, dtype=float)
    w = 1.0 / np.maximum(np.asarray(noise_var, dtype=float), 1e-300)
    n = c.size
    if n < SETTLING_MIN_PIECES or not np.all(np.isfinite(f)):
        return 0.0
    chi_constant = float(np.sum(w * (f - np.sum(w * f) / np.sum(w)) ** 2))
    best = math.inf
    for T in np.geomspace(0.25 * (c[1] - c[0]), c[-1] - c[0], 200):
        X = np.stack([np.ones(n), np.exp((c[-1] - c) / T)], axis=1)
        A = X.T @ (X * w[:, None])
        if np.linalg.cond(A) > 1e12:
            continue
        beta = np.linalg.solve(A, X.T @ (w * f))
        best = min(best, float(np.sum(w * (f - X @ beta) ** 2)))
    if not math.isfinite(best):
        return 0.0
    return (chi_constant - best) / max(1.0, best / (n - 3))


def settles(t, d, ups) -> bool:
    """True when the cycle of the tail ``(t, d)`` (upward mean crossings ``ups``) is still settling.

    Its peak-to-peak over each two periods follows an exponential approach that fits
    ``SETTLING_GAIN`` better than a constant (:func:`settling_gain`, the calibration's test of
    the same thing), in units of the sensor noise estimated from the record
    (:func:`white_noise_sd`), over at least ``MIN_SETTLING_CROSSINGS`` crossings. A cycle born
    near its bifurcation grows slowly, by a per cent or two per period after tens of seconds; its
    tail then sits well under the settled cycle, which a comparison with the settled cycle reads
    as a wrong linear block.
    """
    if ups.size < MIN_SETTLING_CROSSINGS:
        return False
    p2p = _two_period_sizes(t, d, ups)
    noise_var = max((2.0 * white_noise_sd(d)) ** 2, 1e-30 * float(np.max(p2p)) ** 2)
    with np.errstate(over="ignore", invalid="ignore"):
        gain = settling_gain(ups[1:-1], p2p, np.full(p2p.size, noise_var))
    return bool(gain >= SETTLING_GAIN)
