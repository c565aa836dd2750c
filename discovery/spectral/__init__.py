"""Spectral analysis of a limit-cycle record, as papers 001 and 000 did it.

* :mod:`.amplitude` -- one-sided amplitude spectrum of ``delta`` and of its derivative;
* :mod:`.reconstruction` -- low-pass reconstruction by IFFT below a cut-off (10 Hz default);
* :mod:`.harmonics` -- harmonic table with the harmonics raised above a smooth decay flagged;
* :mod:`.noise_floor` -- the flat floor over a band and the matching band-limited white noise.

Every function takes ``(t, delta)`` arrays or a :class:`tvcid.models.recording.Recording`.
"""
from .amplitude import AmplitudeSpectrum, amplitude_spectrum
from .harmonics import HarmonicTable, harmonic_table
from .noise_floor import NoiseFloor, model_noise_psd, noise_floor
from .reconstruction import (
    DEFAULT_CUTOFF_HZ,
    LowPassReconstruction,
    lowpass_reconstruction,
)
from .samples import SpectralInputError, UniformSamples, as_uniform_samples

__all__ = [
    "AmplitudeSpectrum",
    "DEFAULT_CUTOFF_HZ",
    "HarmonicTable",
    "LowPassReconstruction",
    "NoiseFloor",
    "SpectralInputError",
    "UniformSamples",
    "amplitude_spectrum",
    "as_uniform_samples",
    "harmonic_table",
    "lowpass_reconstruction",
    "model_noise_psd",
    "noise_floor",
]
