"""One-sided amplitude spectrum of the actuator output and of its derivative (paper 001 section 3,
Figs. 7, 11, 12; paper 000 Fig. 11).

``A_k = 2 |X_k| / N`` for ``0 < f_k < fs/2`` (``|X_0|/N`` at DC) with ``X = FFT(delta)``, so a
sinusoid of amplitude ``a`` on a bin reads ``a``. The derivative's spectrum is ``2 pi f A_k``
(spectral differentiation: paper 001 reconstructs the signal before the integrator without
differencing noisy samples).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .samples import as_uniform_samples

__all__ = ["AmplitudeSpectrum", "amplitude_spectrum"]


@dataclass(frozen=True, eq=False)
class AmplitudeSpectrum:
    """One-sided amplitude spectrum.

    Attributes
    ----------
    frequency_hz : ndarray
    amplitude : ndarray
        rad for ``delta``, rad/s for its derivative.
    signal : str
        ``"delta"`` or ``"derivative"``.
    """

    frequency_hz: np.ndarray
    amplitude: np.ndarray
    signal: str

    def band(self, low_hz, high_hz):
        """``(frequency_hz, amplitude)`` restricted to ``low_hz <= f <= high_hz``."""
        sel = (self.frequency_hz >= low_hz) & (self.frequency_hz <= high_hz)
        return self.frequency_hz[sel], self.amplitude[sel]

    def plot(self, ax=None, max_hz=None, **kwargs):
        """Amplitude against frequency (log amplitude). Creates a figure only when ``ax`` is None."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        f, a = (self.frequency_hz, self.amplitude) if max_hz is None else self.band(0.0, max_hz)
        ax.semilogy(f[1:], a[1:], label=kwargs.pop("label", self.signal), **kwargs)
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("|FFT| of " + ("delta' (rad/s)" if self.signal == "derivative" else "delta (rad)"))
        ax.legend()
        return ax


def amplitude_spectrum(source, delta=None, derivative=False, detrend=True) -> AmplitudeSpectrum:
    """One-sided amplitude spectrum of ``delta`` (or of ``delta'`` with ``derivative=True``).

    Parameters
    ----------
    source : tvcid.models.recording.Recording or array_like
        A recording, or the times ``t`` (s) with ``delta`` given as the second argument.
    delta : array_like, optional
        Output samples (rad) when ``source`` is ``t``.
    derivative : bool
        Spectrum of the derivative, ``2 pi f`` times that of ``delta``.
    detrend : bool
        Remove the mean first.
    """
    samples = as_uniform_samples(source, delta)
    x = samples.delta - np.mean(samples.delta) if detrend else samples.delta
    n = x.size
    spectrum = np.abs(np.fft.rfft(x)) / n
    spectrum[1:] *= 2.0
    if n % 2 == 0:
        spectrum[-1] *= 0.5  # the Nyquist bin is not doubled
    frequency = np.fft.rfftfreq(n, 1.0 / samples.rate)
    if derivative:
        spectrum = 2.0 * np.pi * frequency * spectrum
    return AmplitudeSpectrum(frequency, spectrum, "derivative" if derivative else "delta")
