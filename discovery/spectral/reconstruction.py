"""Low-pass reconstruction by inverse FFT (paper 001 section 3, Figs. 4 and 5).

Paper 001 ignores the HWIL output's content above 10 Hz, rebuilds the output from the FFT bins
below 10 Hz by IFFT to see its shape without noise, and from that the derivative (the signal
before the integrator) where the friction spikes show. Here the derivative is the IFFT
of ``j 2 pi f X(f)`` over the same bins.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .samples import SpectralInputError, as_uniform_samples

__all__ = ["LowPassReconstruction", "lowpass_reconstruction", "DEFAULT_CUTOFF_HZ"]

#: Paper 001 section 3: "frequencies above 10Hz could be ignored".
DEFAULT_CUTOFF_HZ = 10.0


@dataclass(frozen=True, eq=False)
class LowPassReconstruction:
    """The record rebuilt from its FFT bins at or below ``cutoff_hz``.

    Attributes
    ----------
    t : ndarray
    delta : ndarray
        Reconstructed output (rad), mean included.
    derivative : ndarray
        Reconstructed ``delta'`` (rad/s).
    original : ndarray
        The input samples.
    cutoff_hz : float
    """

    t: np.ndarray
    delta: np.ndarray
    derivative: np.ndarray
    original: np.ndarray
    cutoff_hz: float

    def plot(self, ax=None, signal="delta"):
        """The reconstruction (and the original for ``signal="delta"``) against time."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        if signal == "delta":
            ax.plot(self.t, self.original, color="0.7", lw=0.8, label="record")
            ax.plot(self.t, self.delta, label=f"IFFT below {self.cutoff_hz:g} Hz")
            ax.set_ylabel("delta (rad)")
        elif signal == "derivative":
            ax.plot(self.t, self.derivative, label=f"derivative, IFFT below {self.cutoff_hz:g} Hz")
            ax.set_ylabel("delta' (rad/s)")
        else:
            raise ValueError(f"signal must be 'delta' or 'derivative' (got {signal!r})")
        ax.set_xlabel("t (s)")
        ax.legend()
        return ax


def lowpass_reconstruction(source, delta=None, cutoff_hz=DEFAULT_CUTOFF_HZ) -> LowPassReconstruction:
    """Rebuild ``delta`` and ``delta'`` from the FFT bins at or below ``cutoff_hz`` (default 10 Hz).

    Parameters
    ----------
    source : tvcid.models.recording.Recording or array_like
        A recording, or ``t`` (s) with ``delta`` (rad).
    cutoff_hz : float
        Highest frequency kept (Hz); must lie between the bin spacing and the Nyquist frequency.
    """
    samples = as_uniform_samples(source, delta)
    n = samples.delta.size
    nyquist = 0.5 * samples.rate
    resolution = samples.rate / n
    cutoff_hz = float(cutoff_hz)
    if not (resolution <= cutoff_hz < nyquist):
        raise SpectralInputError(
            f"cutoff_hz {cutoff_hz:g} must lie between the bin spacing {resolution:.4g} Hz and the "
            f"Nyquist frequency {nyquist:.4g} Hz"
        )
    spectrum = np.fft.rfft(samples.delta)
    frequency = np.fft.rfftfreq(n, 1.0 / samples.rate)
    spectrum[frequency > cutoff_hz] = 0.0
    rebuilt = np.fft.irfft(spectrum, n)
    derivative = np.fft.irfft(2j * np.pi * frequency * spectrum, n)
    return LowPassReconstruction(samples.t, rebuilt, derivative, samples.delta, cutoff_hz)
