"""The log posterior over a subset of a hypothesis' parameters, vectorised over walkers."""
from __future__ import annotations

import numpy as np

from tvcid.discovery.threads import thread_map
from tvcid.models.hypotheses import ActuatorParams

from .priors import SIGMA

__all__ = ["LogPosterior", "CALIBRATABLE_EXCLUDED", "check_parameter_names"]

#: Threads simulating the likelihood terms of one evaluation concurrently: the recordings of one
#: point (the start's searches) would otherwise keep one core busy, and a batch's simulation of
#: one recording overlaps the feature extraction of another (the speed-ups on M000's four
#: recordings: ``python -m tvcid.studies.benchmarks.likelihood_threads``).
TERM_THREADS = 4

#: Fields that are structural choices or describe the in-loop noise forcing, not calibratable.
CALIBRATABLE_EXCLUDED = (
    "dead_zone_position", "delay_position", "bandpass_order", "noise_seed", "noise_power",
    "noise_band",
)


def check_parameter_names(names, params: ActuatorParams):
    """Validate the chosen parameter names against the hypothesis; returns them as a tuple."""
    names = tuple(str(n).strip() for n in names)
    if not names:
        raise ValueError("choose at least one parameter to calibrate")
    if len(set(names)) != len(names):
        raise ValueError(f"parameter names repeat: {', '.join(names)}")
    known = set(params.parameter_names())
    allowed = sorted((known - set(CALIBRATABLE_EXCLUDED)) | {SIGMA})
    for n in names:
        if n in CALIBRATABLE_EXCLUDED:
            raise ValueError(f"parameter {n!r} of {params.name} cannot be calibrated "
                             "(a structural choice or the in-loop noise)")
        if n not in known and n != SIGMA:
            raise ValueError(
                f"unknown parameter {n!r} for hypothesis {params.name}; choose from "
                f"{', '.join(allowed)}"
            )
    return names


class LogPosterior:
    """``log p(theta | data)`` in internal coordinates, for a batch of points at once.

    Parameters
    ----------
    base : ActuatorParams
        The hypothesis with every non-sampled parameter at its fixed value.
    names : tuple of str
        Sampled parameters (fields of ``base`` and possibly ``"sigma"``).
    priors : dict name -> Prior
    terms : list
        Likelihood terms (:mod:`.likelihood`), one per recording.
    sigma : float
        Sensor-noise sd used when ``"sigma"`` is not sampled.
    """

    def __init__(self, base, names, priors, terms, sigma):
        self.base = base
        self.names = tuple(names)
        self.priors = [priors[n] for n in self.names]
        self.terms = list(terms)
        self.sigma = float(sigma)
        self._phys = [i for i, n in enumerate(self.names) if n != SIGMA]
        self._sigma_index = self.names.index(SIGMA) if SIGMA in self.names else None
        #: points evaluated so far (each runs one simulation per recording)
        self.n_points = 0
        self._seconds = 0.0
        self._steps = 0.0

    @property
    def simulated_seconds(self) -> float:
        """Seconds simulated so far: every evaluated point runs each recording's simulator once
        (transient and window in closed loop, the whole record in open loop), at the length
        the simulator had then, plus the runs :meth:`account` was told of."""
        return self._seconds

    @property
    def simulated_steps(self) -> float:
        """RK4 steps taken so far (the cost :attr:`simulated_seconds` does not see: a record
        whose step was halved costs twice per simulated second)."""
        return self._steps

    def account(self, n_runs, terms=None):
        """Count ``n_runs`` runs of each of ``terms`` (default all) in the simulated cost."""
        for t in self.terms if terms is None else terms:
            sim = getattr(t, "simulator", None)
            if sim is not None:
                self._seconds += n_runs * float(sim.t_end)
                self._steps += n_runs * float(sim.t_end) / float(sim.dt)

    def account_seconds(self, seconds, dt):
        """Count a run of ``seconds`` at step ``dt`` outside the terms' own simulators (a check's
        longer run)."""
        self._seconds += float(seconds)
        self._steps += float(seconds) / float(dt)

    def natural(self, z):
        """Internal -> natural coordinates, ``(n, ndim)``."""
        z = np.atleast_2d(np.asarray(z, dtype=float))
        return np.column_stack([p.to_natural(z[:, j]) for j, p in enumerate(self.priors)])

    def internal(self, x):
        x = np.atleast_2d(np.asarray(x, dtype=float))
        return np.column_stack([p.to_internal(x[:, j]) for j, p in enumerate(self.priors)])

    def log_prior(self, z):
        z = np.atleast_2d(np.asarray(z, dtype=float))
        lp = np.zeros(z.shape[0])
        for j, p in enumerate(self.priors):
            lp = lp + p.log_prob_internal(z[:, j])
        return lp

    def params_for(self, x_row):
        """The ActuatorParams of one natural-coordinate row, or ``None`` if invalid."""
        try:
            return self.base.replace(**{self.names[j]: float(x_row[j]) for j in self._phys})
        except ValueError:
            return None

    def sigmas(self, x):
        if self._sigma_index is None:
            return np.full(x.shape[0], self.sigma)
        return x[:, self._sigma_index]

    def _prepare(self, z):
        z = np.atleast_2d(np.asarray(z, dtype=float))
        lp = self.log_prior(z)
        ok = np.isfinite(lp) & np.all(np.isfinite(z), axis=1)
        x = np.full_like(z, np.nan)
        x[ok] = self.natural(z[ok]) if ok.any() else x[ok]
        sets = [self.params_for(x[i]) if ok[i] else None for i in range(z.shape[0])]
        return lp, x, sets

    def __call__(self, z):
        single = np.ndim(z) == 1
        lp, x, sets = self._prepare(z)
        valid = np.array([s is not None for s in sets])
        self.n_points += int(valid.sum())
        self.account(int(valid.sum()))
        total = np.where(valid, lp, -np.inf)
        if valid.any():
            idx = np.flatnonzero(valid)
            sub = [sets[i] for i in idx]
            sig = self.sigmas(x[idx])
            ll = np.zeros(idx.size)
            parts = thread_map("terms", TERM_THREADS, lambda t: t.loglike(sub, sig), self.terms)
            for part in parts:  # in the terms' order: the sum does not depend on the threads
                ll = ll + part
            total[idx] = total[idx] + ll
        total = np.where(np.isnan(total), -np.inf, total)
        return float(total[0]) if single else total

    def pointwise(self, z):
        """Pointwise log-likelihoods ``(n, n_obs)`` over all terms (for WAIC)."""
        _, x, sets = self._prepare(z)
        valid = [i for i, s in enumerate(sets) if s is not None]
        sig = self.sigmas(x[valid]) if valid else np.zeros(0)

        def block(term):
            out = np.full((len(sets), term_size(term)), -np.inf)
            if valid:
                out[valid] = term.loglike([sets[i] for i in valid], sig, pointwise=True)
            return out

        return np.concatenate(thread_map("terms", TERM_THREADS, block, self.terms), axis=1)

    def log_likelihood(self, z):
        z = np.atleast_2d(z)
        return self(z) - self.log_prior(z)


def term_size(term):
    return len(term.features) if getattr(term, "kind", "") == "features" else term.n
