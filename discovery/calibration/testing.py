"""Test helpers: sample a known distribution through the calibration runner and check it.

Following emcee's own tests, the runner (:func:`.runner.run_ensemble`: moves, seeding, chunked
convergence checks, backends, pools) is validated on a distribution whose moments are known
before it is trusted with a simulator.
"""
from __future__ import annotations

import numpy as np

from .runner import run_ensemble

__all__ = ["GaussianLogProb", "sample_gaussian", "moment_errors"]


class GaussianLogProb:
    """Vectorised log density of N(mean, cov) (picklable, for pools)."""

    def __init__(self, mean, cov):
        self.mean = np.asarray(mean, dtype=float)
        self.cov = np.atleast_2d(np.asarray(cov, dtype=float))
        self.icov = np.linalg.inv(self.cov)

    def __call__(self, x):
        x = np.atleast_2d(x)
        d = x - self.mean
        q = np.einsum("ni,ij,nj->n", d, self.icov, d)
        return -0.5 * q


def sample_gaussian(mean, cov, n_walkers=16, max_steps=3000, seed=0, backend=None, moves=None,
                    pool=None, tau_factor=50.0, check_every=100):
    """Run the calibration runner on N(mean, cov); returns ``(flat samples, report, sampler)``."""
    mean = np.asarray(mean, dtype=float)
    ndim = mean.size
    lp = GaussianLogProb(mean, cov)
    sd = np.sqrt(np.diag(lp.cov))

    def initial(rng):
        return mean + 0.1 * sd * rng.standard_normal((n_walkers, ndim))

    sampler, report = run_ensemble(
        lp, initial, n_walkers, ndim, max_steps, seed=seed, backend=backend, moves=moves,
        pool=pool, tau_factor=tau_factor, check_every=check_every, warn=False,
    )
    tau = max(report.tau)
    burn = max(int(min(3 * tau, sampler.iteration // 2)), report.burn)
    thin = max(1, int(tau / 2))
    return sampler.get_chain(discard=burn, thin=thin, flat=True), report, sampler


def moment_errors(samples, mean, cov):
    """Errors of the sample mean (in sd) and of the sample sd and correlations (absolute)."""
    mean = np.asarray(mean, dtype=float)
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    sd = np.sqrt(np.diag(cov))
    m = samples.mean(axis=0)
    s = samples.std(axis=0)
    corr = np.corrcoef(samples, rowvar=False)
    true_corr = cov / np.outer(sd, sd)
    return {
        "mean_in_sd": np.abs(m - mean) / sd,
        "sd_relative": np.abs(s / sd - 1.0),
        "correlation": np.abs(np.atleast_2d(corr) - true_corr),
    }
