"""A calibration's importance stage: adaptive importance sampling from the start's Laplace
approximation before any chain, checkpointed round by round.

A part of :class:`tvcid.discovery.calibration.calibration.Calibration` (as
:class:`.start.StartSearch` and :class:`.moves.LaplaceAdaptation` are): it reads ``importance``
(points per round; 0 switches the stage off), ``importance_rounds`` (at most), ``laplace_``,
``log_posterior_``, ``terms_``, ``seed``, ``n_walkers`` and ``backend``, and sets
``importance_``. Where the run's ratios are reliable
(:meth:`.importance.ImportanceRun.reliable`) it is the posterior; elsewhere the chain starts from
its points (:meth:`_walkers_from_importance`) instead of a ball about the maximum.
"""
from __future__ import annotations

import json

import numpy as np

from .backend import H5_GROUP, CheckpointBackend
from .importance import START_SCALE, StudentT, adaptive_importance

__all__ = ["ImportanceStage", "IMPORTANCE_ROUNDS", "IMPORTANCE_TARGET_ESS"]

#: Rounds of importance sampling at most before the chain takes over.
IMPORTANCE_ROUNDS = 5
#: Effective points an importance run needs to stand as the posterior: a 90 % interval's ends
#: then move by about 0.03 of its width from one run to the next (a Gaussian's 5 % quantile has a
#: standard error of ``sqrt(0.05 * 0.95 / ess) / phi(1.645)`` sd).
IMPORTANCE_TARGET_ESS = 300
_GROUP = "importance"


class ImportanceStage:
    """Importance sampling of a calibration's posterior (:mod:`.importance`)."""

    def _importance_usable(self) -> bool:
        """The stage is on and the start has a proposal for it: the Laplace approximation the
        move trusts (share > 0), or the curvature with its principal sds held within the prior
        (``importance_cov``, :func:`.optimum.bounded_laplace_covariance`)."""
        info = getattr(self, "laplace_", None)
        return bool(getattr(self, "importance", 0)) and bool(info) \
            and (float(info.get("share", 1.0)) > 0.0 or "importance_cov" in info)

    def record_log_likelihoods(self, z) -> np.ndarray:
        """Each recording's untempered log-likelihood ``(m, r)`` at the points ``z`` (sampling
        coordinates, inside the prior), its simulations counted in the log posterior's cost."""
        from .log_posterior import term_size
        from .posterior import _uninflated

        lp = self.log_posterior_
        cuts = np.cumsum([0] + [term_size(t) for t in lp.terms])
        lp.account(z.shape[0])  # pointwise() runs every record once per point
        with _uninflated(self):
            pw = lp.pointwise(z)
        return np.column_stack([pw[:, a:b].sum(axis=1) for a, b in zip(cuts[:-1], cuts[1:])])

    def _run_importance(self):
        """Run or resume the stage; sets ``importance_`` (the run) and returns the points this
        call simulated."""
        lp = self.log_posterior_
        info = self.laplace_
        cov = info["cov"] if float(info.get("share", 1.0)) > 0.0 else info["importance_cov"]
        start = StudentT(np.asarray(info["mean"], dtype=float),
                         np.asarray(cov, dtype=float) * START_SCALE**2)
        temperature = [float(np.max(t.inflation)) for t in self.terms_]
        stored = self._stored_importance()

        def rng_of_round(j):
            return np.random.default_rng([int(self.seed), 13, j])

        def save(j, proposal, z, lpr, ll):
            if self.backend is None:
                return
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                g = f.require_group(H5_GROUP).require_group(_GROUP)
                r = g.create_group(f"round-{j}")
                r.attrs["proposal"] = json.dumps(proposal.to_dict())
                for name, data in (("points", z), ("log_prior", lpr), ("log_lik", ll)):
                    r.create_dataset(name, data=data)

        self.importance_, new = adaptive_importance(
            lp.log_prior, self.record_log_likelihoods, temperature, start, rng_of_round,
            int(self.importance), int(self.importance_rounds), IMPORTANCE_TARGET_ESS, stored=stored,
            save=save)
        return new

    def _stored_importance(self) -> list:
        """The rounds a checkpoint holds, in order (none without a backend)."""
        if self.backend is None or not self._has_importance():
            return []
        out = []
        with CheckpointBackend(str(self.backend), name="mcmc").open("r") as f:
            g = f[H5_GROUP][_GROUP]
            for j in range(len(g)):
                r = g[f"round-{j}"]
                out.append((StudentT.from_dict(json.loads(r.attrs["proposal"])),
                            r["points"][()], r["log_prior"][()], r["log_lik"][()]))
        return out

    def _has_importance(self) -> bool:
        """The checkpoint holds at least one importance round."""
        from pathlib import Path

        if self.backend is None or not Path(self.backend).exists():
            return False
        with CheckpointBackend(str(self.backend), name="mcmc").open("r") as f:
            return H5_GROUP in f and _GROUP in f[H5_GROUP] and len(f[H5_GROUP][_GROUP]) > 0

    def _walkers_from_importance(self, rng):
        """``n_walkers`` distinct points of the run drawn by their weights, or None when fewer
        carry weight; the Laplace move's proposal refitted to the run."""
        run = self.importance_
        idx = run.distinct(rng, self.n_walkers)
        if idx is None:
            return None
        fitted = StudentT.fit(run.points, run.log_weights, run.proposals[-1], scale=1.0)
        self.laplace_ = {**self.laplace_, "mean": np.asarray(fitted.mean).tolist(),
                         "cov": np.atleast_2d(fitted.cov).tolist()}
        return run.points[idx]
