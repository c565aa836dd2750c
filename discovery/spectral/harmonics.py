"""Harmonic table of a limit cycle and the harmonics raised above a smooth decay (paper 001 s. 3).

Paper 001 (Fig. 7) compared the FFT of the HWIL output's derivative with the model's: the model's
harmonics decayed steadily, the real actuator's rose between 9 and 10 Hz, "especially around the
seventh harmonic (9.57 Hz)", which led to the band-pass feedback loop. This module puts that
reading into numbers:

* the fundamental from upward mean crossings (:func:`tvcid.models.cycle_reading.upward_mean_crossings`, the
  project's frequency convention), the record trimmed to whole periods so every harmonic falls on
  an FFT bin (``N_periods`` bins per harmonic);
* for harmonic ``k`` the one-sided FFT amplitude at ``k f0`` (largest of the bins within one of
  ``k N_periods``), of ``delta`` or of ``delta'`` (``2 pi f`` times that of ``delta``);
* a harmonic is *raised* when it is at least ``min_ratio`` of the fundamental and exceeds
  ``raise_factor`` (default 3) times its smooth-decay value: the geometric mean of its same-parity
  neighbours ``k-2`` and ``k+2`` (only ``k-2`` for the last one). At controller A the derivative's
  7th harmonic of M001f is 5.8 times that mean (flagged, 9.57 Hz); without the band-pass loop it is
  1.1, and no harmonic of M002 exceeds 1.2. M000 with Table 1's loop (F 72, saturation 0.01) sits in
  between: its 7th is 2.2 times its neighbours' mean but only 0.08 of the fundamental (0.45 for
  M001f), which ``docs/models.md#reference-limit-cycles`` calls "not raised"; lower ``raise_factor``
  to 2 to flag it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvcid.models.cycle_reading import (
    InsufficientPeriodsError,
    cycle_crossings,
)

from .samples import as_uniform_samples

__all__ = ["HarmonicTable", "harmonic_table", "whole_periods"]


def whole_periods(samples):
    """``(selection, n_periods, f0_hz)``: the samples between the first and last upward mean
    crossing, their number of whole periods and the fundamental.

    Raises
    ------
    InsufficientPeriodsError
        When fewer than two whole periods are present.
    """
    t, x = samples.t, samples.delta
    amplitude = 0.5 * (np.max(x) - np.min(x))
    if amplitude <= 0:
        raise InsufficientPeriodsError("no oscillation: the record is constant")
    ups = cycle_crossings(t, x)
    if ups.size < 3:
        raise InsufficientPeriodsError(
            f"the record of {t[-1] - t[0]:.4g} s holds {max(ups.size - 1, 0)} whole period(s) of "
            "the cycle; a harmonic table needs at least two"
        )
    n_periods = ups.size - 1
    f0 = n_periods / (ups[-1] - ups[0])
    first = int(np.searchsorted(t, ups[0]))
    n = int(round((ups[-1] - ups[0]) * samples.rate))
    return slice(first, first + n), n_periods, f0


@dataclass(frozen=True, eq=False)
class HarmonicTable:
    """Harmonics ``1..n`` of a limit cycle.

    Attributes
    ----------
    harmonic : ndarray of int
    frequency_hz : ndarray
    amplitude : ndarray
        rad (``delta``) or rad/s (``derivative``).
    ratio : ndarray
        Amplitude over the fundamental's.
    smooth_decay : ndarray
        Geometric mean of the same-parity neighbours (NaN where undefined).
    raised : ndarray of bool
        Raised above the smooth decay (see the module docstring).
    signal : str
    fundamental_hz : float
    n_periods : int
    raise_factor, min_ratio : float
    """

    harmonic: np.ndarray
    frequency_hz: np.ndarray
    amplitude: np.ndarray
    ratio: np.ndarray
    smooth_decay: np.ndarray
    raised: np.ndarray
    signal: str
    fundamental_hz: float
    n_periods: int
    raise_factor: float
    min_ratio: float

    @property
    def raised_harmonics(self) -> tuple:
        """Numbers of the raised harmonics."""
        return tuple(int(k) for k in self.harmonic[self.raised])

    def rows(self) -> list:
        """One JSON-ready dict per harmonic."""
        return [
            {
                "harmonic": int(k),
                "frequency_hz": float(f),
                "amplitude": float(a),
                "ratio": float(r),
                "raised": bool(flag),
            }
            for k, f, a, r, flag in zip(self.harmonic, self.frequency_hz, self.amplitude, self.ratio, self.raised)
        ]

    def plot(self, ax=None):
        """Harmonic amplitudes (bars), raised ones in red, smooth-decay values as crosses."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        colors = ["C3" if flag else "C0" for flag in self.raised]
        ax.bar(self.frequency_hz, self.amplitude, width=0.3 * self.fundamental_hz, color=colors)
        ax.plot(self.frequency_hz, self.smooth_decay, "kx", label="smooth decay (neighbours)")
        for k, f, a in zip(self.harmonic, self.frequency_hz, self.amplitude):
            if k in self.raised_harmonics:
                ax.annotate(f"H{k} {f:.2f} Hz", (f, a), textcoords="offset points", xytext=(0, 4), ha="center")
        ax.set_yscale("log")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("amplitude of " + ("delta' (rad/s)" if self.signal == "derivative" else "delta (rad)"))
        ax.legend()
        return ax


def harmonic_table(
    source, delta=None, n_harmonics=11, derivative=True, raise_factor=3.0, min_ratio=0.01
) -> HarmonicTable:
    """Harmonic table of the limit cycle in a record (see the module docstring).

    Parameters
    ----------
    source : tvcid.models.recording.Recording or array_like
        A recording, or ``t`` (s) with ``delta`` (rad).
    n_harmonics : int
        Harmonics reported (default 11).
    derivative : bool
        Table of ``delta'`` (default, as paper 001 Fig. 7) or of ``delta``.
    raise_factor : float
        How far above the smooth decay a harmonic must be to be flagged (default 3).
    min_ratio : float
        Harmonics below this fraction of the fundamental are never flagged (noise, the even
        harmonics of a symmetric cycle).

    Raises
    ------
    InsufficientPeriodsError
        When the record holds fewer than two whole periods.
    """
    samples = as_uniform_samples(source, delta)
    if int(n_harmonics) < 1:
        raise ValueError(f"n_harmonics must be >= 1 (got {n_harmonics})")
    n_harmonics = int(n_harmonics)
    sel, n_periods, f0 = whole_periods(samples)
    x = samples.delta[sel]
    x = x - np.mean(x)
    n = x.size
    spectrum = 2.0 * np.abs(np.fft.rfft(x)) / n
    harmonic = np.arange(1, n_harmonics + 1)
    if harmonic[-1] * f0 >= 0.5 * samples.rate:
        raise ValueError(
            f"harmonic {n_harmonics} ({n_harmonics * f0:.4g} Hz) is above the Nyquist frequency "
            f"{0.5 * samples.rate:.4g} Hz; ask for fewer harmonics"
        )
    amplitude = np.empty(n_harmonics)
    for i, k in enumerate(harmonic):
        centre = int(round(k * f0 * n / samples.rate))
        window = spectrum[max(centre - 1, 1): centre + 2]
        amplitude[i] = window.max()
    frequency = harmonic * f0
    if derivative:
        amplitude = 2.0 * np.pi * frequency * amplitude
    ratio = amplitude / amplitude[0]
    smooth = np.full(n_harmonics, np.nan)
    for i, k in enumerate(harmonic):
        if k < 3:
            continue
        neighbours = [amplitude[i - 2]] + ([amplitude[i + 2]] if i + 2 < n_harmonics else [])
        smooth[i] = float(np.exp(np.mean(np.log(np.maximum(neighbours, 1e-300)))))
    with np.errstate(invalid="ignore"):
        raised = (ratio >= min_ratio) & (amplitude > raise_factor * smooth)
    return HarmonicTable(
        harmonic, frequency, amplitude, ratio, smooth, raised,
        "derivative" if derivative else "delta", float(f0), int(n_periods), float(raise_factor), float(min_ratio),
    )
