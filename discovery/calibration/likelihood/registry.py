"""The likelihoods a calibration offers (:data:`LIKELIHOODS`) and the term of one recording
(:func:`make_term`): open-loop recordings always by their output error, closed-loop ones by the
likelihood asked for."""
from __future__ import annotations

from .features import DEFAULT_FEATURES, FeatureTerm
from .open_loop import OpenLoopTerm
from .waveform import WaveformTerm

__all__ = ["LIKELIHOODS", "make_term"]

LIKELIHOODS = ("waveform", "features")


def make_term(recording, likelihood, window, transient, dt, name=None, features=DEFAULT_FEATURES,
              rng=None):
    """The likelihood term of one recording (open-loop recordings always use the output error)."""
    if likelihood not in LIKELIHOODS:
        raise ValueError(f"unknown likelihood {likelihood!r}; choose one of {', '.join(LIKELIHOODS)}")
    if recording.kind == "open":
        return OpenLoopTerm(recording, window, transient, dt, name=name)
    if likelihood == "features":
        return FeatureTerm(recording, window, transient, dt, name=name, features=features, rng=rng)
    return WaveformTerm(recording, window, transient, dt, name=name)
