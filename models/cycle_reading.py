"""Reading a limit cycle off a sampled signal: its crossings, periods, harmonics and features,
and the white noise on it.

Every measurement of a cycle in a sampled output, recorded or simulated, is one function here or
in :mod:`tvcid.models.cycle_settling` (where in a record the cycle is settled); the structure
search's targets, the calibration's likelihood terms, the loop's state on a recorded cycle and
the reports all read cycles through them.

Amplitude is ``(max - min)/2`` and frequency comes from mean crossings, as
``docs/models.md#conventions`` defines them for its reference cycles (a Schmitt trigger whose
hysteresis also clears the sensor noise; :func:`cycle_crossings`). A cycle with more than one
upward mean crossing per period is read at its fundamental (:func:`fundamental_crossings`).
Harmonics are Fourier coefficients over the whole periods between the first and last upward mean
crossing, integrated from one crossing to the other exactly (:func:`whole_period_harmonics`);
those of ``delta'`` are ``k*w0`` times those of ``delta`` (no numerical differentiation; paper 001
section 3 analyses the derivative's spectrum).

Measurements, by what they read:

* noise and crossings -- :func:`white_noise_sd`, :func:`upward_mean_crossings`,
  :func:`crossing_hysteresis`, :func:`cycle_crossings`, :func:`fundamental_crossings`,
  :func:`crossing_multiple`, :func:`peak_to_peak_sizes`;
* harmonics -- :func:`fourier_harmonics` (phase at the first sample),
  :func:`phase_free_harmonics` (phases referred to the first harmonic's),
  :func:`crossing_harmonics` (phase at a crossing), :func:`whole_period_harmonics` (over an
  exact span of whole periods);
* features -- :func:`limit_cycle_features` (a record's: raises without two whole periods),
  :func:`cycle_features` (named features of a noise-free simulated cycle, ``None`` without two
  whole periods), :func:`cycle_of` (frequency and phase-free harmonics of a simulated cycle,
  measured as its record's was), :func:`robust_amplitude` (a noisy record's amplitude).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "InsufficientPeriodsError",
    "LimitCycleFeatures",
    "NoCycleError",
    "N_HARMONICS",
    "crossing_harmonics",
    "crossing_hysteresis",
    "crossing_multiple",
    "cycle_crossings",
    "cycle_features",
    "cycle_of",
    "fourier_harmonics",
    "fundamental_crossings",
    "limit_cycle_features",
    "peak_to_peak_sizes",
    "phase_free_harmonics",
    "robust_amplitude",
    "upward_mean_crossings",
    "white_noise_sd",
    "whole_period_harmonics",
]

#: Hysteresis of the crossing detector, as a fraction of the half peak-to-peak amplitude.
CROSSING_HYSTERESIS = 0.1
#: ... and at least this many times the white noise's sd (:func:`white_noise_sd`), so that the
#: noise on a small cycle makes no crossings of its own.
NOISE_HYSTERESIS = 3.0
#: Harmonics of a cycle that the structure search measures and compares (:func:`cycle_of`).
N_HARMONICS = 7
#: Most upward mean crossings per period a cycle may have, and the tests that find them
#: (:func:`fundamental_crossings`).
MAX_CROSSINGS_PER_PERIOD = 3
UNEQUAL_INTERVALS = 0.05
REPEAT_RATIO = 0.3
SUBHARMONIC_FRACTION = 0.2
class InsufficientPeriodsError(ValueError):
    """The record does not hold the two whole periods a limit-cycle feature needs."""


class NoCycleError(ValueError):
    """A closed-loop recording shows no limit cycle (fewer than two whole periods)."""


@dataclass(frozen=True)
class LimitCycleFeatures:
    """Features of one limit cycle.

    Attributes
    ----------
    amplitude : float
        ``(max - min)/2`` over the window (rad).
    mean : float
        Mean over the whole periods (rad).
    frequency : float
        Fundamental (rad/s) from the mean period between upward mean crossings.
    period_jitter : float
        Standard deviation of the periods over their mean.
    harmonics : tuple of float
        Amplitudes of harmonics 1..n of ``delta`` (rad).
    derivative_harmonics : tuple of float
        Amplitudes of harmonics 1..n of ``delta'`` (rad/s).
    amplitude_drift : float
        ``(A2 - A1)/A`` between the second and first halves of the window.
    n_periods : int
        Whole periods used.
    """

    amplitude: float
    mean: float
    frequency: float
    period_jitter: float
    harmonics: tuple
    derivative_harmonics: tuple
    amplitude_drift: float
    n_periods: int

    @property
    def frequency_hz(self) -> float:
        return self.frequency / (2 * np.pi)

    def harmonic_ratio(self, k, derivative=True) -> float:
        """Amplitude of harmonic ``k`` over the fundamental (of ``delta'`` by default)."""
        h = self.derivative_harmonics if derivative else self.harmonics
        return h[k - 1] / h[0]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["harmonics"] = list(self.harmonics)
        d["derivative_harmonics"] = list(self.derivative_harmonics)
        d["frequency_hz"] = self.frequency_hz
        return d

    def to_json(self, **kwargs) -> str:
        return json.dumps(self.to_dict(), **kwargs)


def upward_mean_crossings(t, x, level, hysteresis):
    """Times where ``x`` crosses ``level`` upwards, with a Schmitt-trigger ``hysteresis``.

    A crossing counts once ``x`` has risen above ``level + hysteresis`` after being below
    ``level - hysteresis``; its time is the last linear-interpolated crossing of ``level`` before
    that, so noise near the level does not add crossings.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    state = np.where(x < level - hysteresis, -1, np.where(x > level + hysteresis, 1, 0))
    marked = np.flatnonzero(state)
    states = state[marked]
    # a run of "below" samples followed by an "above" one arms and fires the trigger
    fire = np.flatnonzero((states[:-1] == -1) & (states[1:] == 1))
    first_above = marked[fire + 1]
    ups = np.flatnonzero((x[:-1] < level) & (x[1:] >= level)) + 1  # x[k-1] < level <= x[k]
    k = ups[np.searchsorted(ups, first_above, side="right") - 1]  # last crossing before firing
    frac = (level - x[k - 1]) / (x[k] - x[k - 1])
    return t[k - 1] + frac * (t[k] - t[k - 1])


#: Variance of the ``order``-th difference of unit white noise: ``binomial(2 order, order)``.
_DIFFERENCE_VARIANCE = {1: 2.0, 2: 6.0, 3: 20.0, 4: 70.0}


def white_noise_sd(x, order=2) -> float:
    """Robust sd of white noise on a sampled signal: the median absolute deviation of its
    ``order``-th differences over ``sqrt(binomial(2 order, order))`` (white noise of sd s gives
    second differences of sd ``sqrt(6) s``, third differences ``sqrt(20) s``; a cycle sampled
    well above its frequency adds little, and its corners are few enough for the median to
    ignore). Higher orders suppress a smooth signal more (the weak-SINDy stage uses 3); 0 for a
    signal of ``order`` samples or fewer."""
    x = np.asarray(x, dtype=float)
    if x.size <= order:
        return 0.0
    d = np.diff(x, order)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(_DIFFERENCE_VARIANCE[order]))


def crossing_hysteresis(x, amplitude) -> float:
    """Hysteresis of the mean-crossing trigger for a cycle of half peak-to-peak ``amplitude``.

    ``CROSSING_HYSTERESIS * amplitude``, raised to ``NOISE_HYSTERESIS`` times the white noise's sd
    on ``x`` (:func:`white_noise_sd`), so that noise on a small cycle cannot fire the trigger. On a
    noise-free simulated cycle it is the amplitude term alone, as every caller that compares a
    simulation with a record needs.
    """
    return max(CROSSING_HYSTERESIS * float(amplitude), NOISE_HYSTERESIS * white_noise_sd(x))


def cycle_crossings(t, x, level=None):
    """The upward crossings of ``level`` (default the mean of ``x``) by a cycle ``x``, by the
    rule every comparison of a simulation with a record uses: :func:`upward_mean_crossings` with
    :func:`crossing_hysteresis` for the cycle's half peak-to-peak amplitude."""
    x = np.asarray(x, dtype=float)
    level = float(np.mean(x)) if level is None else float(level)
    return upward_mean_crossings(t, x, level, crossing_hysteresis(x, 0.5 * float(np.ptp(x))))


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


def fourier_harmonics(t, x, omega, n_harmonics):
    """Complex Fourier coefficients ``c_k = (2/N) sum_n (x_n - mean) exp(-i k omega (t_n - t_0))``,
    ``k = 1..n_harmonics``, of ``x`` sampled uniformly at ``t`` over whole periods of ``omega``.

    ``|c_k|`` is the k-th harmonic's amplitude. The powers ``z^k`` of ``z = exp(-i omega t)`` are
    built by repeated products: one complex exponential per sample instead of ``n_harmonics``
    (five to ten times faster; the rounding grows as ``k`` ulps).
    """
    z = np.exp(-1j * omega * (np.asarray(t, dtype=float) - t[0]))
    xc = np.asarray(x, dtype=float) - np.mean(x)
    c = np.empty(int(n_harmonics), dtype=complex)
    zk = z.copy()
    for j in range(c.size):
        c[j] = 2.0 / z.size * np.dot(zk, xc)
        zk *= z
    return c


def phase_free_harmonics(t, x, omega, n_harmonics=N_HARMONICS):
    """Complex harmonics 1..n of ``x`` at ``omega`` over ``t``, phases referred to the first's.

    ``c_k exp(-i k arg c_1)`` of :func:`fourier_harmonics`: invariant to a time shift of the
    cycle.
    """
    c = fourier_harmonics(t, x, omega, n_harmonics)
    k = np.arange(1, n_harmonics + 1)
    rot = np.exp(-1j * np.angle(c[0]))
    return c * rot**k


def crossing_harmonics(t, x, crossings, omega, n_harmonics):
    """Complex amplitudes ``a_k``, ``k = 1..n_harmonics``, of ``x``'s harmonics at ``omega`` over
    the samples between the first and the last of ``crossings``, at the phase of the first.

    ``a_k = (2/N) sum_n (x_n - mean) exp(-i k omega (t_n - crossings[0]))`` over the ``N`` samples
    with ``crossings[0] <= t_n < crossings[-1]``: ``x = mean + sum Re(a_k e^{i k omega (t -
    crossings[0])})`` there, so that the cycle's state at the crossing is a sum over ``a_k``
    (:meth:`tvcid.models.cycle_state.RecordedCycleState.from_cycle`).
    """
    ups = np.asarray(crossings, dtype=float)
    w = (t >= ups[0]) & (t < ups[-1])
    k = np.arange(1, n_harmonics + 1)
    basis = np.exp(-1j * np.outer(k, omega * (t[w] - ups[0])))
    return 2.0 / w.sum() * (basis @ (x[w] - np.mean(x[w])))


def whole_period_harmonics(t, x, start, end, n_periods, n_harmonics):
    """Complex Fourier coefficients of ``x`` over exactly ``n_periods`` periods from ``start`` to
    ``end`` (s): ``c_k = (2/T) int_start^end (x - mean) exp(-i k w (t - start)) dt``, ``T = end -
    start``, ``w = 2 pi n_periods / T``, ``k = 1..n_harmonics``.

    The trapezoid rule on the uniform samples, its two end pieces closed at ``start`` and ``end``
    with ``x`` interpolated linearly there. Summed over the samples between two crossings, a span
    that misses whole periods by up to a sample (:func:`fourier_harmonics` on them), a settled
    cycle's first harmonic moves by about ``h / (n_periods * period)`` of itself from one stretch
    to the next: 1e-4 of M002's over a 10 s window at 1 kHz, several times the record's noise
    sd of it. Over the exact span the trapezoid is spectrally accurate for a smooth periodic
    signal (``tests/test_features.py``).

    Parameters
    ----------
    t, x : array_like
        Uniform sample times (s) and values; ``start`` and ``end`` lie inside ``t``'s range.
    start, end : float
        The span's ends (e.g. two upward crossings).
    n_periods : int
        Whole periods between them.
    n_harmonics : int
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    span = float(end) - float(start)
    w = 2.0 * np.pi * int(n_periods) / span
    a = int(np.searchsorted(t, start, side="left"))  # first sample at or after start
    b = int(np.searchsorted(t, end, side="right")) - 1  # last sample at or before end
    a, b = max(a, 1), min(b, t.size - 2)
    ts, xs = t[a:b + 1], x[a:b + 1]

    def at(time, i):  # x linearly interpolated between samples i and i + 1
        f = (time - t[i]) / (t[i + 1] - t[i])
        return x[i] + f * (x[i + 1] - x[i])

    x0, x1 = at(start, a - 1), at(end, b)
    h = float(t[1] - t[0])
    # trapezoid weights on the interior samples, plus the end pieces' shares
    weights = np.full(ts.size, h)
    weights[0] = 0.5 * h + 0.5 * (ts[0] - start)
    weights[-1] = 0.5 * h + 0.5 * (end - ts[-1])
    ends_w = (0.5 * (ts[0] - start), 0.5 * (end - ts[-1]))
    mean = (np.dot(weights, xs) + ends_w[0] * x0 + ends_w[1] * x1) / span
    z = np.exp(-1j * w * (ts - start))
    z_end = np.exp(-1j * w * span)
    g = (xs - mean) * weights
    g0, g1 = ends_w[0] * (x0 - mean), ends_w[1] * (x1 - mean)
    c = np.empty(int(n_harmonics), dtype=complex)
    zk, zk_end = z.copy(), z_end
    for j in range(c.size):
        c[j] = 2.0 / span * (np.dot(zk, g) + g0 + zk_end * g1)
        zk *= z
        zk_end *= z_end
    return c


def limit_cycle_features(t, delta, n_harmonics=11) -> LimitCycleFeatures:
    """Features of the limit cycle in ``delta(t)``.

    Parameters
    ----------
    t : array_like
        Uniformly sampled, increasing times (s).
    delta : array_like
        Output (rad).
    n_harmonics : int
        Number of harmonics reported (default 11).

    Raises
    ------
    InsufficientPeriodsError
        When the window holds fewer than two whole periods (or no oscillation at all).
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(delta, dtype=float)
    if t.shape != x.shape or t.ndim != 1:
        raise ValueError("t and delta must be 1-D arrays of equal length")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
        raise ValueError("t or delta holds NaN or infinite values")
    span = t[-1] - t[0] if t.size else 0.0
    amplitude = 0.5 * (np.max(x) - np.min(x)) if x.size else 0.0
    if amplitude <= 0:
        raise InsufficientPeriodsError("no oscillation: the signal is constant over the window")
    level = float(np.mean(x))
    ups = cycle_crossings(t, x, level)
    if ups.size < 3:
        raise InsufficientPeriodsError(
            f"the window of {span:.4g} s holds {max(ups.size - 1, 0)} whole period(s) of the "
            "cycle; at least two are needed"
        )
    periods = np.diff(ups)
    period = float(np.mean(periods))
    w0 = 2 * np.pi / period
    sel = (t >= ups[0]) & (t < ups[-1])
    xs = x[sel]
    mean = float(np.mean(xs))
    k = np.arange(1, n_harmonics + 1)
    harmonics = np.abs(whole_period_harmonics(t, x, ups[0], ups[-1], ups.size - 1, n_harmonics))
    half = x.size // 2
    a1 = 0.5 * (np.max(x[:half]) - np.min(x[:half]))
    a2 = 0.5 * (np.max(x[half:]) - np.min(x[half:]))
    return LimitCycleFeatures(
        amplitude=float(amplitude),
        mean=mean,
        frequency=float(w0),
        period_jitter=float(np.std(periods) / period),
        harmonics=tuple(float(h) for h in harmonics),
        derivative_harmonics=tuple(float(h) for h in harmonics * k * w0),
        amplitude_drift=float((a2 - a1) / amplitude),
        n_periods=int(ups.size - 1),
    )


def cycle_features(t, x, names):
    """Named features of a noise-free simulated cycle, by :func:`limit_cycle_features`'s rules;
    ``None`` under two whole periods.

    ``names`` are ``"frequency"`` (from the mean period between the first and last upward
    crossing, :func:`cycle_crossings`), ``"amplitude"`` (``(max - min)/2``) and ``"Hk"`` (the
    k-th harmonic's amplitude over the whole periods between those crossings,
    :func:`whole_period_harmonics`). It reads only what ``names`` ask for, where
    :func:`limit_cycle_features` reads every feature of a record and raises without a cycle.
    """
    level = float(np.mean(x))
    c = cycle_crossings(t, x, level)
    if c.size < 3:
        return None
    period = (c[-1] - c[0]) / (c.size - 1)
    w0 = 2 * math.pi / period
    ks = [int(n[1:]) for n in names if n.startswith("H")]
    harm = {}
    if ks:
        coeffs = np.abs(whole_period_harmonics(t, x, c[0], c[-1], c.size - 1, max(ks)))
        harm = {f"H{k}": float(coeffs[k - 1]) for k in ks}
    out = []
    for n in names:
        if n == "frequency":
            out.append(w0)
        elif n == "amplitude":
            out.append(0.5 * float(np.max(x) - np.min(x)))
        else:
            out.append(harm[n])
    return np.asarray(out)


def cycle_of(t, x, multiple=None):
    """``(omega, harmonics, amplitude)`` of a noise-free simulated cycle, or ``None``: its
    frequency, its :func:`phase_free_harmonics` 1..``N_HARMONICS`` and ``(max - min)/2``.

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
        c = fundamental_crossings(c, peak_to_peak_sizes(t, x, c), signal=(t, x))
    else:
        c = c[::multiple]
    if c.size < 3:
        return None
    omega = 2 * math.pi * (c.size - 1) / (c[-1] - c[0])
    sel = (t >= c[0]) & (t < c[-1])
    return omega, phase_free_harmonics(t[sel], x[sel], omega), 0.5 * float(np.ptp(x))


def robust_amplitude(t, delta, bins=100):
    """``(max - min)/2`` of the cycle in a noisy record, from its period-folded mean.

    The raw ``(max - min)/2`` is biased upwards by the noise extremes (about 3.5 sd at 10 000
    samples). Folding the record over its period (from :func:`limit_cycle_features`) and
    averaging each of ``bins`` phase bins leaves the cycle's shape and divides the noise by the
    root of the samples per bin.
    """
    t = np.asarray(t, dtype=float)
    d = np.asarray(delta, dtype=float)
    period = 2 * np.pi / limit_cycle_features(t, d).frequency
    phase = np.floor(((t - t[0]) / period % 1.0) * bins).astype(int)
    means = np.bincount(phase, weights=d, minlength=bins) / np.maximum(
        np.bincount(phase, minlength=bins), 1)
    return 0.5 * float(np.max(means) - np.min(means))


def peak_to_peak_sizes(t, x, ups):
    """Peak-to-peak of ``x`` between consecutive crossings ``ups``."""
    idx = np.searchsorted(t, ups)
    return np.array([np.ptp(x[a:b]) if b > a else 0.0 for a, b in zip(idx[:-1], idx[1:])])
