"""The interface of a likelihood term, and what the terms share.

A term is the likelihood of one recording (:class:`LikelihoodTerm`); the log posterior adds the
terms' log-likelihoods up (:class:`tvcid.discovery.calibration.log_posterior.LogPosterior`). Shared here:
the residuals' statistics and the discrepancy
factors at the maximum a posteriori (:func:`waveform_inflation`, :func:`features_inflation`), and
the tempering by which a term's log-likelihood is divided by its factor (:func:`tempered`).
"""
from __future__ import annotations

import abc
import math

import numpy as np

__all__ = [
    "LikelihoodTerm",
    "residual_statistics",
    "waveform_inflation",
    "tempered",
    "features_inflation",
    "DISCREPANCY_P",
]

_LOG_2PI = math.log(2 * math.pi)

#: Tail probability beyond which the misfit at the maximum a posteriori counts as model
#: discrepancy (and inflates the likelihood's covariance).
DISCREPANCY_P = 0.05


class LikelihoodTerm(abc.ABC):
    """The likelihood of one recording, vectorised over parameter sets.

    What every term implements; :class:`tvcid.discovery.calibration.calibration.Calibration` and the log
    posterior use terms through it. A diverging, invalid or non-oscillating simulation gets
    ``-inf``, never an exception.

    Every term also sets ``name`` (the record's), ``recording``, ``kind`` (``"waveform"`` or
    ``"features"``: how it compares the record), ``sigma_hat`` (the record's noise sd,
    :func:`tvcid.models.cycle_reading.white_noise_sd`), ``tau`` and ``data`` (the compared
    samples' times from the window's start, and their values), ``n`` (the number of samples), ``dt`` (the step it was given),
    ``simulator`` (after :meth:`setup`), ``warm_start`` and ``inflation`` (the discrepancy factor
    its log-likelihood is divided by, :func:`tempered`; 1 until the calibration sets it at the
    maximum a posteriori).
    """

    kind: str

    @abc.abstractmethod
    def setup(self, start_params, warm_start=True):
        """Build the simulator for runs around ``start_params`` (an ``ActuatorParams``), warm
        started on a reference cycle unless ``warm_start`` is false; returns ``self``."""

    @abc.abstractmethod
    def loglike(self, param_sets, sigma, pointwise=False):
        """Log-likelihood of each parameter set at noise sd ``sigma`` (one per set), tempered by
        :attr:`inflation`: ``(n_sets,)``, or per compared number ``(n_sets, k)`` when
        ``pointwise``; ``-inf`` for a run that is invalid, diverges or does not oscillate."""

    @abc.abstractmethod
    def discrepancy(self, params, sigma) -> float:
        """The discrepancy factor of the misfit at ``params`` and noise sd ``sigma``
        (:func:`waveform_inflation` or :func:`features_inflation`); 1 for a right model."""

    @abc.abstractmethod
    def refine_at(self, params):
        """The solver's error measured again at ``params`` (the maximum a posteriori), the
        step refined where the record needs it; returns ``self``."""

    @abc.abstractmethod
    def describe(self) -> dict:
        """What the term compares, as JSON-ready values (name, kind, samples, noise, ...)."""


def residual_statistics(residuals, sigma):
    """``(n, variance ratio, lag-1 autocorrelation)`` of the finite residuals, mean removed;
    the ratio is ``mean r^2 / sigma^2`` (NaN for fewer than two residuals)."""
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    n = r.size
    if n < 2:
        return n, math.nan, math.nan
    r = r - np.mean(r)
    ss = float(np.sum(r * r))
    rho = float(np.sum(r[1:] * r[:-1])) / ss if ss > 0 else 0.0
    return n, ss / n / float(sigma) ** 2, rho


def waveform_inflation(residuals, sigma) -> float:
    """Discrepancy factor of an output-error likelihood (its log-likelihood is divided by it,
    :func:`tempered`).

    At the maximum a posteriori a right model leaves the sensor's white noise; a wrong or slightly
    wrong one (or a solver whose step error shows at switching events) leaves a structured misfit,
    larger than the noise and correlated over many samples, which a white-noise likelihood reads
    as thousands of independent confirmations (needle posteriors). The factor is the product of
    the misfit's excess over the noise, ``mean r^2 / sigma^2``, and the residuals' integrated
    autocorrelation time ``tau`` (samples per independent one; emcee's estimator with Sokal's
    window, c = 5): a generalised-Bayes tempering by what the residuals really hold. Each factor
    counts only beyond what a white residual gives by chance (``3 sqrt(2/n)`` for the variance
    ratio, ``10 / sqrt(n)`` for ``tau``; factor 1 on 20 of 20 white records of 4000 samples,
    ``tests/test_calibration_mismatch.py``), so a right model keeps 1.
    """
    from emcee.autocorr import integrated_time

    n, ratio, _ = residual_statistics(residuals, sigma)
    if n < 10 or not sigma > 0 or not ratio > 0:
        return 1.0
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    tau = float(integrated_time(r - np.mean(r), c=5, tol=0, quiet=True)[0])
    excess = ratio if ratio > 1.0 + 3.0 * math.sqrt(2.0 / n) else 1.0
    samples_per_independent = min(tau, float(n)) if tau > 1.0 + 10.0 / math.sqrt(n) else 1.0
    return float(excess * samples_per_independent)


def tempered(loglike, inflation):
    """A generalised-Bayes (tempered) log-likelihood: ``loglike / inflation``.

    For a fixed noise sd this is the same as inflating the noise variance by ``inflation``; where
    the noise sd is sampled it is not: an inflated variance ``sigma^2 f`` is undone by a sampled
    ``sigma`` that shrinks by ``sqrt(f)`` (its maximum is at ``sigma^2 f = RSS / n``), so the
    physical parameters would keep their width, the reported noise sd would be ``sqrt(f)`` too
    small, and the features terms that follow the sampled sd
    (:attr:`.features.FeatureTerm.noise_from_sigma`) would be narrowed by ``f``. Tempered,
    ``sigma`` keeps its maximum at the sensor noise and the factor widens the physical parameters'
    posterior (``tests/test_calibration_mismatch.py``: the noise sd's maximum stays within 2 % and
    the physical parameter's curvature is divided by ``f``).
    """
    return loglike / float(inflation)


def features_inflation(whitened) -> float:
    """Discrepancy factor of a features likelihood (its log-likelihood is divided by it,
    :func:`tempered`).

    ``1 + (chi2 - q) / k`` for the ``k`` whitened residuals at the maximum a posteriori, where
    ``q`` is the ``1 - DISCREPANCY_P`` quantile of a chi-square with ``k`` degrees of freedom; 1
    when ``chi2 <= q``. Only the misfit beyond what sensor noise makes in all but
    ``DISCREPANCY_P`` of records counts, so the factor starts from 1 at the test's threshold
    instead of jumping to ``q / k`` (2.2 for five features), and tends to ``chi2 / k`` for a large
    misfit. The test's false alarms on right models (one record in twenty by construction) then
    cost little.
    """
    from scipy.stats import chi2 as chi2_dist

    z = np.asarray(whitened, dtype=float)
    if not np.all(np.isfinite(z)):
        return 1.0
    k, chi2 = z.size, float(np.sum(z * z))
    q = float(chi2_dist.ppf(1.0 - DISCREPANCY_P, k))
    return 1.0 + (chi2 - q) / k if chi2 > q else 1.0
