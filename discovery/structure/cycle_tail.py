"""What a closed-loop record's cycle is measured on: its stationary tail, its crossings, its
phase-free harmonics, and whether it still settles.

A record may start with a transient or on another attractor; its end holds the cycle that the
targets (:mod:`.targets`) compare with simulations. The frequency comes from upward mean
crossings as docs/models.md#conventions measures it, with a Schmitt trigger against sensor noise;
a cycle with more than one crossing per period is read at its fundamental.
"""
from __future__ import annotations

import math

import numpy as np

from tvcid.discovery.calibration.likelihood import estimate_noise
from tvcid.discovery.calibration.likelihood.features import settling_gain
from tvcid.models.features import (
    crossing_hysteresis,
    cycle_crossings,
    fourier_harmonics,
    upward_mean_crossings,
)

__all__ = [
    "NoCycleError",
    "N_HARMONICS",
    "phase_free_harmonics",
    "fundamental_crossings",
    "crossing_multiple",
    "stationary_tail",
    "period_sizes",
    "settles",
    "cycle_of",
]

#: Harmonics of a cycle that are measured and compared.
N_HARMONICS = 7
#: Most upward mean crossings per period a cycle may have, and the tests that find them
#: (:func:`fundamental_crossings`).
MAX_CROSSINGS_PER_PERIOD = 3
UNEQUAL_INTERVALS = 0.05
REPEAT_RATIO = 0.3
SUBHARMONIC_FRACTION = 0.2
#: Relative peak-to-peak change that ends a record's stationary tail.
TAIL_TOLERANCE = 0.15
#: A tail whose size per two periods an exponential approach fits this much better than a
#: constant is still settling (:func:`settles`; below the calibration's 100 for feature pieces:
#: a drawn truth's 12 s record still 13 % under its cycle scores 42).
SETTLING_GAIN = 25.0
#: ... from at least this many crossings (two periods to start from, then six to compare).
MIN_SETTLING_CROSSINGS = 9


class NoCycleError(ValueError):
    """A closed-loop recording shows no limit cycle (fewer than two whole periods)."""


def phase_free_harmonics(t, x, omega, n_harmonics=N_HARMONICS):
    """Complex harmonics 1..n of ``x`` at ``omega`` over ``t``, phases referred to the first's.

    ``c_k exp(-i k arg c_1)``: invariant to a time shift of the cycle.
    """
    c = fourier_harmonics(t, x, omega, n_harmonics)
    k = np.arange(1, n_harmonics + 1)
    rot = np.exp(-1j * np.angle(c[0]))
    return c * rot**k


def fundamental_crossings(ups, sizes=None, max_multiple=MAX_CROSSINGS_PER_PERIOD, signal=None):
    """Every m-th of the upward mean crossings ``ups``, m the crossings per period of the cycle.

    A cycle may cross its mean upwards more than once per period (a period-2 cycle with a large
    and a small lobe, seen with a controller held at 200 Hz); then the intervals between
    crossings, or the peak-to-peak ``sizes`` of the signal within them, repeat with period m and
    their average is not the cycle. m > 1 is taken only when either differs by more than
    ``UNEQUAL_INTERVALS`` from one interval to the next (a cycle that merely wanders, as the
    band-pass loop's, varies ~1 %) and repeats at lag m: the spread of ``v[j+m] - v[j]`` under
    ``REPEAT_RATIO`` of the spread of ``v`` (about sqrt(2) for values that vary at random), and,
    when ``signal = (t, x)`` is given, its harmonic at the m-fold period is at least
    ``SUBHARMONIC_FRACTION`` of the largest.
    """
    ups = np.asarray(ups, dtype=float)
    series = [np.diff(ups)] + ([np.asarray(sizes, dtype=float)] if sizes is not None else [])
    series = [v for v in series if v.size >= 4 and np.std(v) > UNEQUAL_INTERVALS * np.mean(v)]
    for m in range(2, max_multiple + 1):
        for v in series:
            if v.size >= 2 * m + 1 and np.std(v[m:] - v[:-m]) < REPEAT_RATIO * np.std(v):
                if signal is not None and not _subharmonic_present(*signal, ups[::m]):
                    return ups
                return ups[::m]
    return ups


def crossing_multiple(t, x, ups):
    """Upward mean crossings per period of ``x`` between its fundamental crossings ``ups``."""
    every = cycle_crossings(t, x)
    inside = np.count_nonzero((every >= ups[0] - 1e-9) & (every < ups[-1] - 1e-9))
    return max(1, int(round(inside / (ups.size - 1))))


def _subharmonic_present(t, x, ups):
    """True when the cycle measured between crossings ``ups`` has a real first harmonic.

    A period-1 cycle whose lobes merely alternate a little (beating with a controller's hold)
    repeats at lag 2 too, but its harmonic at half its frequency is small: measured at that
    half, its features would hang on a first harmonic made of noise and drift.
    """
    w = (t >= ups[0]) & (t < ups[-1])
    if w.sum() < 8:
        return False
    omega = 2 * math.pi * (ups.size - 1) / (ups[-1] - ups[0])
    c = np.abs(phase_free_harmonics(t[w], x[w], omega))
    return bool(c[0] >= SUBHARMONIC_FRACTION * np.max(c))


def _sizes(t, x, ups):
    """Peak-to-peak of ``x`` between consecutive crossings ``ups``."""
    idx = np.searchsorted(t, ups)
    return np.array([np.ptp(x[a:b]) if b > a else 0.0 for a, b in zip(idx[:-1], idx[1:])])


def _two_period_sizes(t, x, ups):
    """Peak-to-peak of ``x`` over each two consecutive periods (over each one when there are
    fewer than three): lobes that alternate (a beat with a held controller) do not read as a
    change of size, a change of attractor does."""
    p2p = _sizes(t, x, ups)
    return np.maximum(p2p[:-1], p2p[1:]) if ups.size >= 4 else p2p


def stationary_tail(t, d, name="recording"):
    """The end of a record over which the cycle's amplitude is settled.

    A record may start with a transient or on another attractor (paper 000's small cycle: the
    bundled controller-B record holds a 2.6e-4 rad cycle for 14 s before the large one). Periods
    are taken between upward mean crossings; walking back from the end, the tail keeps every
    period whose peak-to-peak amplitude over it and the next period is within ``TAIL_TOLERANCE``
    of the median of the last five.

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
    ups = fundamental_crossings(ups, _sizes(t, d, ups), signal=(t, d))
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
    idx = np.searchsorted(t, ups)  # as _sizes: the samples in [ups[j], ups[j + 1])
    out = np.empty(ups.size - 1)
    for j, (a, b) in enumerate(zip(idx[:-1], idx[1:])):
        omega = 2 * math.pi / (ups[j + 1] - ups[j])
        out[j] = abs(fourier_harmonics(t[a:b], x[a:b], omega, 1)[0])
    return out


def settles(t, d, ups) -> bool:
    """True when the cycle of the tail ``(t, d)`` (upward mean crossings ``ups``) is still settling.

    Its peak-to-peak over each two periods follows an exponential approach that fits
    ``SETTLING_GAIN`` better than a constant, in units of the sensor noise estimated from the
    record (:func:`tvcid.discovery.calibration.likelihood.features.settling_gain`, the calibration's
    test of the same thing), over at least ``MIN_SETTLING_CROSSINGS`` crossings. A cycle born
    near its bifurcation grows slowly, by a per cent or two per period after tens of seconds; its
    tail then sits well under the settled cycle, which a comparison with the settled cycle reads
    as a wrong linear block.
    """
    if ups.size < MIN_SETTLING_CROSSINGS:
        return False
    p2p = _two_period_sizes(t, d, ups)
    noise_var = max((2.0 * estimate_noise(d)) ** 2, 1e-30 * float(np.max(p2p)) ** 2)
    with np.errstate(over="ignore", invalid="ignore"):
        gain = settling_gain(ups[1:-1], p2p, np.full(p2p.size, noise_var))
    return bool(gain >= SETTLING_GAIN)


def cycle_of(t, x, multiple=None):
    """``(omega, harmonics, amplitude)`` of a noise-free simulated cycle, or ``None``.

    ``multiple``: upward mean crossings per period, as the record's cycle was measured
    (:func:`crossing_multiple`); ``None`` decides from ``x`` itself. A simulation compared with a
    record must be measured the same way: a cycle whose lobes alternate a little (a controller
    held at 200 Hz) is read as period 1 over a long record and as period 2 over a short simulated
    window, and a decision taken afresh per run would turn a small change of a parameter into a
    jump of the features by a factor of two.
    """
    level = float(np.mean(x))
    # the record's crossings are counted with the same Schmitt trigger (a flat stretch of the
    # cycle near its mean must not add crossings on one side only)
    c = cycle_crossings(t, x, level)
    if multiple is None:
        c = fundamental_crossings(c, _sizes(t, x, c), signal=(t, x))
    else:
        c = c[::multiple]
    if c.size < 3:
        return None
    omega = 2 * math.pi * (c.size - 1) / (c[-1] - c[0])
    sel = (t >= c[0]) & (t < c[-1])
    return omega, phase_free_harmonics(t[sel], x[sel], omega), 0.5 * float(np.ptp(x))
