"""Likelihood terms: the likelihood of one recording each, behind one interface.

Two likelihoods for a closed-loop recording (:data:`LIKELIHOODS`):

* ``waveform``: phase-aligned output error (:class:`WaveformTerm`). The simulated cycle is shifted
  in time to the data (the shift is profiled out); the residuals over the window are independent
  Gaussians of sd ``sigma``.
* ``features``: limit-cycle features (frequency and the amplitudes of chosen harmonics, odd by
  default) as a Gaussian (:class:`FeatureTerm`), their covariance propagated from the sensor
  noise.

Open-loop recordings are compared sample by sample with no shift (:class:`OpenLoopTerm`; the
command sets the phase). A diverging, invalid or non-oscillating simulation gets ``-inf``, never
an exception.

Modules:

* :mod:`.base` -- :class:`LikelihoodTerm` (the interface every term implements), the
  discrepancy factors and the tempering by them;
* :mod:`.solver` -- the solver's error in an output-error likelihood, by step doubling;
* :mod:`.closed_loop` -- what the two closed-loop terms share (window, phase, simulator);
* :mod:`.waveform`, :mod:`.features`, :mod:`.open_loop` -- one term kind each;
* :mod:`.registry` -- :data:`LIKELIHOODS` and :func:`make_term`.
"""
from .base import (
    DISCREPANCY_P,
    LikelihoodTerm,
    features_inflation,
    residual_statistics,
    tempered,
    waveform_inflation,
)
from .closed_loop import MIN_AMPLITUDE_RATIO
from .features import (
    DEFAULT_FEATURES,
    SETTLING_FIT_GAIN,
    SETTLING_R2,
    SETTLING_SLOPE_SD,
    SETTLING_WINDOWS,
    FeatureTerm,
)
from .open_loop import EDGE_CHECK_REFINEMENT, OpenLoopTerm
from .registry import LIKELIHOODS, make_term
from .solver import (
    MAX_STEP_REFINEMENT,
    SOLVER_ERROR_FACTOR,
    SOLVER_LOAD_LIMIT,
    SOLVER_SPREAD_SAMPLES,
)
from .waveform import (
    PERIOD_MISMATCH_LIMIT,
    SETTLING_PERTURBATION,
    SETTLING_REFERENCE,
    IllPosedLikelihoodWarning,
    WaveformTerm,
)

__all__ = [
    "LikelihoodTerm",
    "WaveformTerm",
    "IllPosedLikelihoodWarning",
    "FeatureTerm",
    "OpenLoopTerm",
    "make_term",
    "LIKELIHOODS",
    "DEFAULT_FEATURES",
    "DISCREPANCY_P",
    "residual_statistics",
    "waveform_inflation",
    "tempered",
    "features_inflation",
    "SETTLING_SLOPE_SD",
    "SETTLING_R2",
    "SETTLING_WINDOWS",
    "SETTLING_FIT_GAIN",
    "SOLVER_ERROR_FACTOR",
    "SOLVER_SPREAD_SAMPLES",
    "SOLVER_LOAD_LIMIT",
    "MAX_STEP_REFINEMENT",
    "EDGE_CHECK_REFINEMENT",
    "MIN_AMPLITUDE_RATIO",
    "PERIOD_MISMATCH_LIMIT",
    "SETTLING_PERTURBATION",
    "SETTLING_REFERENCE",
]
