"""A calibration's nested-sampling stage: the posterior by nested sampling over the start's
proposal (:mod:`.nested`), where the importance stage's ratios are not reliable.

A part of :class:`tvcid.discovery.calibration.calibration.Calibration` (as
:class:`.importance_stage.ImportanceStage` is): it reads ``nested`` (live points; 0 switches the
stage off), ``laplace_``, ``log_posterior_``, ``terms_``, ``seed`` and ``backend``, and sets
``nested_``. The reference is the start's Laplace approximation, widened by
:data:`.nested.REFERENCE_SCALE`; where the start has none, the curvature held to the walkers'
starting ball (the importance stage's first proposal), else that ball itself. Where the run is
reliable (:meth:`.nested.NestedRun.reliable`) it is the posterior; elsewhere the chain starts
from its points.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .nested import REFERENCE_SCALE, AxisReference, nested_sample

__all__ = ["NestedStage", "NESTED_TARGET_ESS", "NESTED_MAX_CALLS"]

#: Effective points a nested run stops at and needs to stand as the posterior (as the
#: importance stage's :data:`.importance_stage.IMPORTANCE_TARGET_ESS`, with a margin: the
#: weights within a shell vary more than an adapted proposal's).
NESTED_TARGET_ESS = 600
#: Likelihood calls of a nested run at most, in units of its live points.
NESTED_MAX_CALLS = 40


class NestedStage:
    """Nested sampling of a calibration's posterior (:mod:`.nested`)."""

    def _nested_usable(self) -> bool:
        """The stage is on and the start has set its proposal (``laplace_``)."""
        return bool(getattr(self, "nested", 0)) and bool(getattr(self, "laplace_", None))

    def _nested_reference(self) -> AxisReference:
        """The start's proposal widened by :data:`.nested.REFERENCE_SCALE` (the stage runs
        where the importance rounds failed, whose fitted t rests on a few heavy points): its
        Laplace approximation; where the chain's move refused one, the curvature held to the
        walkers' starting ball (``importance_cov``); where the Hessian was not finite, the
        ball itself (the move's idle ``cov``)."""
        info = self.laplace_
        if float(info.get("share", 1.0)) > 0.0 or "importance_cov" not in info:
            cov = info["cov"]
        else:
            cov = info["importance_cov"]
        return AxisReference.from_laplace(info["mean"], cov, REFERENCE_SCALE)

    def _nested_path(self):
        """The run's checkpoint beside the chain's (nautilus writes a file of its own)."""
        if self.backend is None:
            return None
        p = Path(self.backend)
        return p.with_name(p.stem + "-nested.h5")

    def _has_nested(self) -> bool:
        """A nested run's checkpoint exists (the start's proposal is then stored)."""
        path = self._nested_path()
        return path is not None and path.exists()

    def _run_nested(self):
        """Run or resume the stage; sets ``nested_`` (the run) and returns the likelihood calls
        this call made."""
        temperature = [float(np.max(t.inflation)) for t in self.terms_]
        self.nested_, new = nested_sample(
            self.log_posterior_.log_prior, self.record_log_likelihoods, temperature,
            self._nested_reference(), int(self.nested), NESTED_TARGET_ESS,
            seed=int(np.random.default_rng([int(self.seed), 19]).integers(2**31)),
            filepath=self._nested_path(), max_calls=NESTED_MAX_CALLS * int(self.nested))
        return new

    def _walkers_from_nested(self, rng):
        """``n_walkers`` distinct points of the run drawn by their weights (None when fewer
        carry weight), and the Laplace move's proposal refitted to the run."""
        run = self.nested_
        idx = run.distinct(rng, self.n_walkers)
        if idx is None:
            return None
        w = run.weights
        mean = w @ run.points
        diff = run.points - mean
        cov = (diff * w[:, None]).T @ diff
        self.laplace_ = {**self.laplace_, "mean": mean.tolist(), "cov": cov.tolist()}
        return run.points[idx]
