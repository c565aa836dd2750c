"""Where a calibration's chain starts: the maximum a posteriori, the discrepancy factors there,
the Laplace approximation and the walkers around it (:class:`StartSearch`).

From the start values a Nelder-Mead search finds the maximum a posteriori; where a recording's
misfit there suggests a local optimum, a differential evolution over the prior box, restarts
along the principal axes (:meth:`StartSearch._polish`) and short ensemble runs
(:meth:`StartSearch._scout`) look for a better one. The discrepancy factors are set at the
maximum found; the walkers are placed around it (a ball with each axis' sd, or along the principal
axes of the Hessian), and the Laplace approximation there starts the independence move
(:mod:`.moves`). The numerical pieces (optimisers, curvature) are in :mod:`.optimum`.
"""
from __future__ import annotations

import json
import math

import numpy as np

from .backend import H5_GROUP, CheckpointBackend
from .optimum import (
    _axis_scales,
    _global_start,
    _hessian,
    _nelder_mead,
    _nelder_mead_from,
    _principal_axes,
    _profile_sigma,
    _quasi_newton,
    _simplex,
    bounded_laplace_covariance,
    laplace_covariance,
)

__all__ = ["StartSearch", "START_OPTIMIZERS", "POLISH_RESTARTS"]

#: The local searches of the maximum a posteriori (``Calibration(start_optimizer=...)``).
START_OPTIMIZERS = ("nelder-mead", "quasi-newton")

#: Restarts of the local search while its optimum leaves a discrepancy
#: (:meth:`StartSearch._polish`), the default of ``Calibration(polish_restarts=...)`` ...
POLISH_RESTARTS = 3
#: ... each kept only if it gains more than this (nats).
POLISH_GAIN = 0.1
#: Steps of the short ensemble run that looks for a better maximum where the one found leaves a
#: discrepancy factor over 1 (:meth:`StartSearch._scout`) ...
SCOUT_STEPS = 60
#: ... and how many of its most probable points are compared with that maximum; at most
#: ``SCOUT_ROUNDS`` runs, each from the last one's better point.
SCOUT_CANDIDATES = 24
SCOUT_ROUNDS = 3
#: Misfit (as a discrepancy inflation) beyond which the local optimum is checked globally.
SUSPECT_INFLATION = 10.0
#: Walkers' starting points at which, beside the maximum a posteriori, a features record's
#: solver correction is measured (:meth:`StartSearch._set_solver_correction`).
SOLVER_CHECK_WALKERS = 8



class NoFiniteStartError(RuntimeError):
    """No starting point of the walkers has a finite posterior: around the start, some
    recording's run fails or shows no cycle the likelihood can compare."""


class StartSearch:
    """The start of a calibration's chain: a part of
    :class:`tvcid.discovery.calibration.calibration.Calibration`.

    Reads the estimator's set-up (``log_posterior_``, ``terms_``, ``names_``, ``start_``,
    ``n_walkers``, ``backend`` and the options ``optimize_start``, ``start_optimizer``,
    ``features_fallback``, ``discrepancy``, ``global_search``, ``polish_restarts``, ``spread``,
    ``laplace_move``) and uses its per-record steps (``_fall_back_slow``, ``_refine_steps_at``,
    ``_chooses_transient``, ``_choose_transients``).
    Sets ``map_start_``, ``inflation_``, ``laplace_`` and ``initial_axes_``.
    """

    def _initial(self, rng):
        """The walkers' starting points (internal coordinates, ``(n_walkers, ndim)``).

        In order: the maximum a posteriori from the start values (:meth:`_maximum`; searched again
        with the features where a waveform record falls back to them at that maximum), each
        output-error term's step checked there, the discrepancy factors set there (and, while
        some factor is over 1, :meth:`_scout` rounds for a better maximum), the walkers around
        it, the Laplace move's start, each waveform record's transient and each features term's
        start imprint (after which the factors are measured again against the widened
        covariance)."""
        lp = self.log_posterior_
        z0 = lp.internal(np.array([[self.start_[n] for n in self.names_]]))[0]
        if self.optimize_start:
            z0 = self._maximum(lp, z0, rng)
        if self.features_fallback and self._fall_back_slow(lp, z0) and self.optimize_start:
            z0 = self._maximum(lp, z0, rng)  # the features' own maximum, from the waveform's
        self.map_start_ = dict(zip(self.names_, lp.natural(z0)[0].tolist()))
        self._refine_steps_at(self.map_start_)
        if self.discrepancy:
            self._set_inflation(lp, z0)
            for _ in range(SCOUT_ROUNDS if self.global_search else 0):
                # each round from the last one's better point
                better = self._scout(lp, z0, rng) if max(self.inflation_) > 1.0 else None
                if better is None:
                    break
                z0 = better
                self.map_start_ = dict(zip(self.names_, lp.natural(z0)[0].tolist()))
                self._refine_steps_at(self.map_start_)
                self._set_inflation(lp, z0)
        scale = _axis_scales(lp, z0)
        axes = np.diag(0.5 * scale)
        hess = _hessian(lp, z0, scale) if (self.spread == "hessian" or self.laplace_move) else None
        if self.spread == "hessian":
            axes = _principal_axes(lp, z0, scale, hess)
        self.laplace_ = None
        if self.laplace_move:
            self._start_laplace(lp, z0, hess, axes)
        self.initial_axes_ = axes
        out = self._walkers_around(lp, z0, axes, rng)
        if out is None:
            raise NoFiniteStartError("could not place the walkers where the posterior is finite")
        if self._chooses_transient():
            self._choose_transients(lp, z0, axes, out, rng)
        corrected = self._set_solver_correction(lp, z0, out)
        if (self._set_transient_variance(lp, out) or corrected) and self.discrepancy:
            self._set_inflation(lp, z0)  # measured against the widened covariance
        return out

    def _maximum(self, lp, z0, rng):
        """The maximum a posteriori from ``z0`` (internal coordinates): Nelder-Mead, then, where
        a recording still shows a misfit, the global search and restarts (:meth:`_polish`)."""
        z0 = _profile_sigma(lp, z0, self.names_)
        if self.start_optimizer == "quasi-newton":
            end = _quasi_newton(lp, z0, _axis_scales(lp, z0))
            end = _nelder_mead(lp, _simplex(end, lp), 50 * len(z0))
        else:
            end = _nelder_mead(lp, _simplex(z0, lp), 150 * len(z0))
        if np.isfinite(lp(end)):
            z0 = _profile_sigma(lp, end, self.names_)
        # owed with or without the discrepancy term: the search finds the mode, the term only
        # tempers the likelihood there
        searched = self.global_search and self._suspect_optimum(lp, z0)
        if searched:
            z0 = _global_start(lp, z0, int(rng.integers(2**31)), self.names_)
        if self.discrepancy:
            z0, factors = self._polish(lp, z0)
            if self.global_search and not searched and max(factors) > 1.0:
                # still a misfit: a local optimum or a wrong model; the global search
                # tells them apart
                z0, _ = self._polish(lp, _global_start(lp, z0, int(rng.integers(2**31)),
                                                       self.names_))
        return z0

    def _suspect_optimum(self, lp, z0) -> bool:
        """The local search's optimum misfits some recording by over ``SUSPECT_INFLATION`` times
        its noise, or has no finite posterior (a start without a cycle, where Nelder-Mead cannot
        move): a local optimum or a wrong model; either way a global search is owed before the
        discrepancy inflation is measured there."""
        return (not np.isfinite(lp(z0))
                or max(self._inflations_at(lp, z0)) > SUSPECT_INFLATION)

    def _polish(self, lp, z0):
        """Nelder-Mead restarted along the principal axes at its optimum while that optimum
        leaves some recording a discrepancy factor over 1 and the restart gains over
        ``POLISH_GAIN`` nats (at most ``polish_restarts`` times); ``(z0, factors there)``.

        On a ridge an axis-aligned simplex stops short of the maximum, and the misfit there
        would read as model discrepancy; a right model at its maximum keeps 1, so a restart is
        owed only while the factor is over 1.
        """
        ndim = len(z0)
        factors = self._inflations_at(lp, z0)
        for _ in range(self.polish_restarts):
            if max(factors) <= 1.0:
                break
            scale = _axis_scales(lp, z0)
            hess = _hessian(lp, z0, scale)
            axes = _principal_axes(lp, z0, scale, hess)
            if self.start_optimizer == "quasi-newton":
                end = _quasi_newton(lp, z0, scale, hess)
                end = _nelder_mead(lp, np.vstack([end, end[None, :] + axes.T]), 50 * ndim)
            else:
                end = _nelder_mead(lp, np.vstack([z0, z0[None, :] + axes.T]), 100 * ndim)
            before = float(np.ravel(lp(z0))[0])
            if not float(np.ravel(lp(end))[0]) > before + POLISH_GAIN:
                break
            z0 = _profile_sigma(lp, end, self.names_)
            factors = self._inflations_at(lp, z0)
        return z0, factors

    def _scout(self, lp, z0, rng):
        """A better maximum than ``z0`` found by a short ensemble run, or None.

        Where the searches stop short of the maximum, a right model's factor there reads as a
        wrong model's. ``SCOUT_STEPS`` steps of DE moves under the inflated likelihood (wide, so the
        walkers roam) from around ``z0``; their best points are compared with ``z0`` without the
        inflation, and the best, polished, is returned if it gains over ``POLISH_GAIN`` nats.
        """
        import emcee

        ndim = len(z0)
        scale = _axis_scales(lp, z0)
        start = self._walkers_around(lp, z0, _principal_axes(lp, z0, scale, _hessian(lp, z0, scale)),
                                     rng)
        if start is None:
            return None
        sampler = emcee.EnsembleSampler(self.n_walkers, ndim, lp, vectorize=True,
                                        moves=[(emcee.moves.DEMove(), 0.8),
                                               (emcee.moves.DESnookerMove(), 0.2)])
        sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
        sampler.run_mcmc(start, SCOUT_STEPS, progress=False)
        flat, logp = sampler.get_chain(flat=True), sampler.get_log_prob(flat=True)
        candidates = flat[np.argsort(logp)[::-1][:SCOUT_CANDIDATES]]
        kept = [t.inflation for t in self.terms_]
        for t in self.terms_:  # compared on the searches' own objective
            t.inflation = 1.0
        try:
            values = np.asarray(lp(candidates), dtype=float)
            before = float(np.ravel(lp(z0))[0])
            if not np.nanmax(values) > before + POLISH_GAIN:
                return None
            z = _nelder_mead_from(lp, candidates[int(np.nanargmax(values))])
            z, _ = self._polish(lp, _profile_sigma(lp, z, self.names_))
            return z if float(np.ravel(lp(z))[0]) > before + POLISH_GAIN else None
        finally:
            for t, v in zip(self.terms_, kept):
                t.inflation = v

    def _inflations_at(self, lp, z0) -> list:
        """Each term's discrepancy inflation at ``z0`` (inf everywhere if ``z0`` is invalid)."""
        x = lp.natural(z0)[0]
        params = lp.params_for(x)
        if params is None:
            return [math.inf] * len(self.terms_)
        sigma = float(lp.sigmas(x[None, :])[0])
        return [float(t.discrepancy(params, sigma)) for t in self.terms_]

    def _set_inflation(self, lp, z0):
        """Each term's discrepancy inflation at ``z0`` (the MAP), kept in the checkpoint."""
        self.inflation_ = [v if math.isfinite(v) else 1.0 for v in self._inflations_at(lp, z0)]
        for term, value in zip(self.terms_, self.inflation_):
            term.inflation = value
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(H5_GROUP).attrs["inflation"] = json.dumps(self.inflation_)

    def _walkers_around(self, lp, z0, axes, rng):
        """``n_walkers`` points ``z0 + axes @ N(0, 1)`` where the posterior is finite (the first
        ones drawn, in at most 100 batches), or None."""
        found = []
        for _ in range(100):
            trial = z0 + rng.standard_normal((self.n_walkers, len(z0))) @ axes.T
            found.extend(trial[np.isfinite(lp(trial))])
            if len(found) >= self.n_walkers:
                return np.asarray(found[: self.n_walkers])
        return None

    def _start_laplace(self, lp, z0, hess, axes):
        """``laplace_`` at the start: the Laplace approximation at ``z0`` where it can serve as a
        proposal (:func:`laplace_covariance`), else the move idle (share 0) until its first refit
        to the chain (:meth:`_adapt_laplace`), which keeps it only if it would be accepted often
        enough. Idle covers a curvature not resolved at an optimum not quite reached and a
        maximum on a prior bound or on a ridge the prior cuts, where the Hessian cannot be had."""
        cov = laplace_covariance(lp, z0, hess)
        if cov is not None:
            self.laplace_ = {"mean": z0.tolist(), "cov": cov.tolist()}
        else:
            self.laplace_ = {"mean": z0.tolist(), "cov": (axes @ axes.T).tolist(), "share": 0.0}
            proposal = bounded_laplace_covariance(hess, axes @ axes.T)
            if proposal is not None:  # the importance stage's first proposal (not the move's)
                self.laplace_["importance_cov"] = proposal.tolist()

    def _set_solver_correction(self, lp, z0, z) -> bool:
        """Each features term's solver correction
        (:meth:`.likelihood.features.FeatureTerm.solver_correction`) measured again over the
        maximum a posteriori ``z0`` and ``SOLVER_CHECK_WALKERS`` of the walkers' starting points
        ``z`` (internal coordinates), their median; the points (natural coordinates, kept in
        :attr:`solver_check_points_`) and the corrections kept in the checkpoint; True if any
        term has one.

        The check at the maximum alone can fall on a point special for the step: the change
        jumps from point to point (:meth:`.likelihood.features.FeatureTerm.solver_correction`)."""
        terms = [t for t in self.terms_ if hasattr(t, "solver_correction")]
        if not terms:
            return False
        rows = np.linspace(0, len(z) - 1, min(SOLVER_CHECK_WALKERS, len(z))).round().astype(int)
        x = lp.natural(np.vstack([z0[None, :], z[np.unique(rows)]]))
        kept = [(row, p) for row, p in zip(x, (lp.params_for(row) for row in x)) if p is not None]
        if not kept:
            return False
        self.solver_check_points_ = [dict(zip(self.names_, row.tolist())) for row, _ in kept]
        sets = [p for _, p in kept]
        for term in terms:
            term.correct_over(sets, term.warm_start is not None)
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                group = f.require_group(H5_GROUP)
                group.attrs["solver_check_points"] = json.dumps(self.solver_check_points_)
                g = group.require_group("solver_correction")
                for term in terms:
                    if term.name in g:
                        del g[term.name]
                    g.create_dataset(term.name, data=np.vstack([term.solver_bias, term.solver_var]))
        return True

    def _set_transient_variance(self, lp, z) -> bool:
        """Each features term's start imprint
        (:meth:`.likelihood.features.FeatureTerm.transient_variance`)
        over the walkers' starting points ``z``, kept in the checkpoint; True if any is nonzero.

        The waveform term has none: its imprint is correlated over the window, which a
        per-sample variance would not cover."""
        terms = [t for t in self.terms_ if hasattr(t, "transient_variance")]
        if not terms:
            return False
        x = lp.natural(z)
        sets = [p for p in (lp.params_for(row) for row in x) if p is not None]
        for term in terms:
            term.set_transient_variance(term.transient_variance(sets))
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                g = f.require_group(H5_GROUP).require_group("transient_var")
                for term in terms:
                    if term.name in g:
                        del g[term.name]
                    g.create_dataset(term.name, data=term.transient_var)
        return any(np.any(t.transient_var > 0) for t in terms)
