"""Noise floor of a record over a band and the band-limited white noise that matches it.

Paper 000 section 4.3: the output spectrum is flat between 20 and 100 Hz (Fig. 11), and a
band-limited white noise block with its power "chosen to match the real data" is added to the
output. The model is :mod:`tvcid.models.noise`: held Gaussian samples of duration ``1/(2 band)`` and
variance ``power * 2 * band`` (Simulink's convention, ``power`` the two-sided PSD height in
rad^2/Hz).

Estimate: a Hann-windowed periodogram, one-sided PSD ``P_k = 2 |X_k|^2/(fs sum w^2)``, over the
bins of the band that lie between the harmonics of the cycle (farther than ``0.2 f0`` from every
multiple of the fundamental ``f0``); the floor is the *median* of ``P_k`` divided by ``ln 2`` (the
median of the exponential distribution of a periodogram bin), so neither the harmonics that fall
in the band nor a few stray peaks raise it. Match: the expected one-sided PSD of the model noise *as sampled* at ``fs``: with
``L = fs/(2 band)`` samples per hold (``L <= 1``: independent samples),

    S(f) = 2 power (2 band) / fs * F_L(2 pi f/fs),   F_L(x) = sin^2(L x/2) / (L sin^2(x/2))

(the Fejer kernel of a triangular autocorrelation; exact for integer ``L``, 1 for ``L <= 1``);
``power`` is the median over the band of ``P_k / S(f_k)`` for unit power, divided by ``ln 2``
(the model's shape is divided out bin by bin, so a noise band that rolls off inside the analysed
band is matched too).

What it measures is the floor of the record, which in closed loop is not only the injected noise:
the noise on ``delta`` is fed back through the controller and the actuator answers it coherently.
For M002 (controller A, a 30 s window) the matched power scatters around the injected one with
an sd of 4-6 % over noise seeds: seeds 0-9 all within 10 % (mean -1.0 % at 1e-11 rad^2/Hz in a
500 Hz band, -0.4 % at 4e-11 in a 100 Hz band; ``tests/test_spectrum.py``), seeds 0-29 within
9.3 % and, for one seed of the 100 Hz band, 16 %. For M000 (Table 1) the actuator's
coherent answer raises it by 11-18 % (controllers A and B, 4e-13 rad^2/Hz injected), although the
noise-free cycle's own floor is 1 % of it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvcid.models.cycle_reading import InsufficientPeriodsError

from .harmonics import whole_periods
from .samples import SpectralInputError, as_uniform_samples

__all__ = ["NoiseFloor", "noise_floor", "model_noise_psd", "DEFAULT_NOISE_BAND_HZ", "DEFAULT_FLOOR_BAND_HZ"]

#: Paper 000 Fig. 11: the flat part of the spectrum.
DEFAULT_FLOOR_BAND_HZ = (20.0, 100.0)
#: Default band of the matched noise (``ActuatorParams.noise_band``).
DEFAULT_NOISE_BAND_HZ = 500.0


def model_noise_psd(frequency_hz, power, noise_band, sample_rate):
    """Expected one-sided PSD (rad^2/Hz) of :mod:`tvcid.models.noise` noise sampled at ``sample_rate``."""
    f = np.asarray(frequency_hz, dtype=float)
    hold = sample_rate / (2.0 * noise_band)
    variance = power * 2.0 * noise_band
    if hold <= 1.0:
        return np.full(f.shape, 2.0 * variance / sample_rate)
    x = 2.0 * np.pi * f / sample_rate
    with np.errstate(invalid="ignore", divide="ignore"):
        fejer = np.sin(hold * x / 2.0) ** 2 / (hold * np.sin(x / 2.0) ** 2)
    fejer = np.where(np.abs(np.sin(x / 2.0)) < 1e-12, hold, fejer)
    return 2.0 * variance / sample_rate * fejer


@dataclass(frozen=True, eq=False)
class NoiseFloor:
    """Noise floor over a band and the matching band-limited white noise.

    Attributes
    ----------
    band_hz : (float, float)
    psd : float
        One-sided PSD level of the floor (rad^2/Hz).
    amplitude : float
        Median one-sided FFT amplitude (rad) over the band, as read off an amplitude spectrum.
    power : float
        ``noise_power`` (rad^2/Hz, Simulink convention) of :class:`tvcid.models.ActuatorParams` whose
        noise, with ``noise_band``, has this floor.
    noise_band : float
        Band (Hz) of the matched noise.
    std : float
        Standard deviation of the matched noise's held samples (rad).
    sample_rate : float
    frequency_hz, periodogram : ndarray
        The band's one-sided PSD bins, for plotting.
    """

    band_hz: tuple
    psd: float
    amplitude: float
    power: float
    noise_band: float
    std: float
    sample_rate: float
    frequency_hz: np.ndarray
    periodogram: np.ndarray

    def to_dict(self) -> dict:
        return {
            "band_hz": list(self.band_hz),
            "psd": self.psd,
            "amplitude": self.amplitude,
            "power": self.power,
            "noise_band": self.noise_band,
            "std": self.std,
            "sample_rate": self.sample_rate,
        }

    def plot(self, ax=None):
        """The band's periodogram and the floor. Creates a figure only when ``ax`` is None."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        ax.semilogy(self.frequency_hz, self.periodogram, color="0.6", lw=0.7, label="periodogram (Hann)")
        ax.axhline(self.psd, color="C3", label=f"floor {self.psd:.3g} rad^2/Hz -> power {self.power:.3g}")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("one-sided PSD (rad^2/Hz)")
        ax.legend()
        return ax


def noise_floor(
    source, delta=None, band_hz=DEFAULT_FLOOR_BAND_HZ, noise_band=DEFAULT_NOISE_BAND_HZ, harmonic_guard=0.2
) -> NoiseFloor:
    """Noise floor of ``delta`` over ``band_hz`` and the matched band-limited white noise power.

    Parameters
    ----------
    source : tvcid.models.recording.Recording or array_like
        A recording, or ``t`` (s) with ``delta`` (rad).
    band_hz : (float, float)
        Band (Hz) where the spectrum is flat (default 20-100 Hz, paper 000 Fig. 11).
    noise_band : float
        ``noise_band`` (Hz) of the matched model noise (default 500).
    harmonic_guard : float
        Bins closer than ``harmonic_guard * f0`` to a multiple of the cycle's fundamental ``f0``
        are left out, so the harmonics of the limit cycle that fall in the band (and their
        leakage) do not raise the floor; 0, or a record without two whole periods, keeps all.

    Raises
    ------
    SpectralInputError
        When the band is empty, above the Nyquist frequency or holds fewer than 8 bins.
    """
    samples = as_uniform_samples(source, delta)
    low, high = (float(b) for b in band_hz)
    nyquist = 0.5 * samples.rate
    if not (0 <= low < high <= nyquist):
        raise SpectralInputError(
            f"band {low:g}-{high:g} Hz must satisfy 0 <= low < high <= Nyquist ({nyquist:.4g} Hz)"
        )
    if not (np.isfinite(noise_band) and noise_band > 0):
        raise SpectralInputError(f"noise_band must be > 0 (got {noise_band!r})")
    x = samples.delta - np.mean(samples.delta)
    n = x.size
    window = np.hanning(n)
    periodogram = 2.0 * np.abs(np.fft.rfft(x * window)) ** 2 / (samples.rate * np.sum(window ** 2))
    frequency = np.fft.rfftfreq(n, 1.0 / samples.rate)
    sel = (frequency >= low) & (frequency <= high) & (frequency > 0) & (frequency < nyquist)
    if harmonic_guard > 0:
        try:
            f0 = whole_periods(samples)[2]
        except InsufficientPeriodsError:
            f0 = None
        if f0 is not None:
            offset = np.abs(frequency / f0 - np.round(frequency / f0))
            between = sel & (offset >= harmonic_guard)
            if np.count_nonzero(between) >= 8:
                sel = between
    if np.count_nonzero(sel) < 8:
        raise SpectralInputError(
            f"band {low:g}-{high:g} Hz holds {np.count_nonzero(sel)} FFT bins of the "
            f"{n / samples.rate:.3g} s record; need at least 8 (longer record or wider band)"
        )
    psd = float(np.median(periodogram[sel]) / np.log(2.0))
    amplitude_spectrum = 2.0 * np.abs(np.fft.rfft(x)) / n
    unit = model_noise_psd(frequency[sel], 1.0, noise_band, samples.rate)
    power = float(np.median(periodogram[sel] / unit) / np.log(2.0))
    return NoiseFloor(
        (low, high), psd, float(np.median(amplitude_spectrum[sel])), power, float(noise_band),
        float(np.sqrt(power * 2.0 * noise_band)), samples.rate, frequency[sel], periodogram[sel],
    )
