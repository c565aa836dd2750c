"""tvcid.discovery.calibration: Bayesian calibration of a hypothesis with emcee.

* :class:`Calibration` -- sklearn-style estimator: posterior over any subset of a hypothesis'
  parameters (plus the sensor-noise sd ``sigma``) given closed-loop and open-loop recordings,
  with a phase-aligned waveform or a limit-cycle-features likelihood;
* :func:`run_ensemble` -- the small sampling core (emcee, HDF checkpoints, resume, stopping at
  ``N > 50 tau``), usable with any log-probability;
* :class:`Posterior`, :class:`PosteriorPredictive`, :func:`compare` -- summaries, corner/trace/
  predictive plots, ArviZ export, WAIC and BIC;
* :mod:`.ridge` -- the dead-zone/backlash ridge of a single limit cycle and its shrinkage.
"""
from tvcid.models.recording import load_recordings

from .backend import CheckpointBackend
from .calibration import Calibration
from .checks import PredictiveCheck, predictive_check
from .likelihood import (
    DEFAULT_FEATURES,
    LIKELIHOODS,
    IllPosedLikelihoodWarning,
)
from .posterior import ModelComparison, Posterior, PosteriorPredictive, compare
from .priors import SIGMA, LogUniform, Prior, Uniform, default_prior, parse_prior
from .runner import ConvergenceReport, ConvergenceWarning, default_moves, run_ensemble

__all__ = [
    "PredictiveCheck",
    "predictive_check",
    "Calibration",
    "CheckpointBackend",
    "ConvergenceReport",
    "ConvergenceWarning",
    "DEFAULT_FEATURES",
    "IllPosedLikelihoodWarning",
    "LIKELIHOODS",
    "LogUniform",
    "ModelComparison",
    "Posterior",
    "PosteriorPredictive",
    "Prior",
    "SIGMA",
    "Uniform",
    "compare",
    "default_moves",
    "default_prior",
    "load_recordings",
    "parse_prior",
    "run_ensemble",
]
