"""Input of the spectral functions: ``(t, delta)`` arrays or a :class:`tvcid.models.recording.Recording`.

Recordings are read with :func:`tvcid.models.recording.load_recording` (the only reader of recording
files); this module only checks that a record can be Fourier-analysed: uniformly sampled, finite,
long enough.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvcid.models.recording import Recording

__all__ = ["SpectralInputError", "UniformSamples", "as_uniform_samples"]

#: Largest relative spread of the sample steps accepted as uniform sampling.
UNIFORM_TOLERANCE = 1e-6


class SpectralInputError(ValueError):
    """A record cannot be analysed (too short, not uniformly sampled, non-finite); the message
    names the culprit."""


@dataclass(frozen=True, eq=False)
class UniformSamples:
    """A uniformly sampled signal: ``t`` (s), ``delta`` (rad), ``rate`` (Hz)."""

    t: np.ndarray
    delta: np.ndarray
    rate: float

    @property
    def duration(self) -> float:
        return self.t.size / self.rate


def as_uniform_samples(source, delta=None, min_samples=8) -> UniformSamples:
    """``(t, delta)`` from a Recording (``delta`` must then be None) or from two arrays.

    Raises
    ------
    SpectralInputError
        For unequal lengths, NaN or infinite values, fewer than ``min_samples`` samples or
        non-uniform sampling.
    """
    if isinstance(source, Recording):
        if delta is not None:
            raise SpectralInputError("give either a Recording or the arrays (t, delta), not both")
        t, x = source.t, source.delta
        name = str(source.path) if source.path is not None else "recording"
    else:
        if delta is None:
            raise SpectralInputError(
                f"expected a tvcid.models.recording.Recording or the arrays (t, delta); got {type(source).__name__} alone"
            )
        t, x = source, delta
        name = "record"
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1 or t.shape != x.shape:
        raise SpectralInputError(f"{name}: t and delta must be 1-D arrays of equal length (got {t.shape} and {x.shape})")
    if t.size < min_samples:
        raise SpectralInputError(f"{name}: {t.size} samples; at least {min_samples} are needed")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
        raise SpectralInputError(f"{name}: t or delta holds NaN or infinite values")
    steps = np.diff(t)
    step = float(np.mean(steps))
    if step <= 0 or np.max(np.abs(steps - step)) > UNIFORM_TOLERANCE * step + 1e-12:
        raise SpectralInputError(
            f"{name}: spectral analysis needs uniformly sampled t (steps range from "
            f"{steps.min():.6g} to {steps.max():.6g} s); resample first"
        )
    return UniformSamples(t, x, 1.0 / step)
