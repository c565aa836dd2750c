"""Nested sampling of a calibration's posterior, with the start's proposal as reference density.

A member's posterior on limit cycles alone is thin and curved: its bulk is 1e-5 to 1e-3 of the
prior box along most axes, so nested sampling over the box spends 60-80 nats of compression
before it reaches any posterior mass, and an ensemble chain mixes along the curved ridge in
hundreds of autocorrelation times. Written as

    p(z) = pi(z) L(z) / Z = q(z) [pi(z) L(z) / q(z)] / Z,

the same posterior is the one nested sampling gives over a reference density ``q`` (here a
product of Student t's along the Cholesky axes of the start's Laplace covariance, widened:
:class:`AxisReference`) with the likelihood ``pi L / q``: the target and its evidence ``Z``
(the member's marginal likelihood) stay exact, and the compression starts at the Laplace
approximation's scale. The sampler is nautilus (Lange 2023, "nautilus: boosting Bayesian
importance nested sampling with deep learning", MNRAS 525(2)), whose draws are importance
weighted within neural-network bounds of the likelihood's shells: what it returns is a weighted
sample, like an importance run (:class:`NestedRun`).

Its own diagnostics flag where it fails: the run stopped before its effective sample size
(``finished``), the Pareto ``k`` of its weights (:func:`.importance.pareto_k`; a shell whose
bound missed the posterior leaves a few heavy points), and the standard error of ``log Z`` from
the spread of the likelihood within each shell.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import special, stats

from .importance import GOOD_K, ImportanceReport, WeightedPoints

__all__ = ["AxisReference", "NestedRun", "NestedReport", "nested_sample", "REFERENCE_DOF", "REFERENCE_SCALE"]

#: Degrees of freedom of the reference's t along each axis: tails heavier than the posterior's,
#: so ``pi L / q`` stays bounded where the Laplace approximation is too narrow.
REFERENCE_DOF = 3.0
#: Widening of the Laplace approximation's square root in the reference: nested sampling
#: compresses from it, so a wide reference costs a few nats (``d ln scale``), a narrow one
#: leaves posterior mass in its tails.
REFERENCE_SCALE = 3.0


@dataclass(frozen=True)
class AxisReference:
    """A product of Student t's along the columns of ``chol`` about ``mean`` (sampling
    coordinates): ``z = mean + chol t``, each ``t_i`` a standard t with ``dof`` degrees of
    freedom. Its unit-cube transform is exact (each axis' inverse CDF), which nested sampling
    needs.
    """

    mean: np.ndarray
    chol: np.ndarray
    dof: float = REFERENCE_DOF

    @classmethod
    def from_laplace(cls, mean, cov, scale=REFERENCE_SCALE, dof=REFERENCE_DOF):
        """The reference about a Laplace approximation (``mean``, ``cov``), its square root
        widened by ``scale``."""
        cov = np.atleast_2d(np.asarray(cov, dtype=float))
        return cls(np.asarray(mean, dtype=float), np.linalg.cholesky(cov) * float(scale),
                   float(dof))

    @property
    def ndim(self) -> int:
        return int(np.size(self.mean))

    def from_unit(self, u) -> np.ndarray:
        """Points ``(m, d)`` of the unit cube's rows ``u``, mapped through each axis' inverse
        CDF."""
        t = stats.t.ppf(np.clip(np.atleast_2d(u), 1e-15, 1 - 1e-15), self.dof)
        return self.mean + t @ self.chol.T

    def log_density(self, z) -> np.ndarray:
        """Normalised log density at the rows of ``z``."""
        w = np.linalg.solve(self.chol, (np.atleast_2d(z) - self.mean).T).T
        log_det = float(np.sum(np.log(np.abs(np.diag(self.chol)))))
        return np.sum(stats.t.logpdf(w, self.dof), axis=1) - log_det


@dataclass(frozen=True)
class NestedRun(WeightedPoints):
    """A nested-sampling run's weighted points of the posterior.

    Attributes
    ----------
    points : ndarray (n, d)
        Sampling coordinates.
    log_prior : ndarray (n,)
    log_lik : ndarray (n, r)
        Untempered log-likelihood of each recording (``-inf`` outside the prior).
    temperature : ndarray (r,)
        Each recording's discrepancy factor (the posterior's log-likelihood is
        ``sum_r log_lik[:, r] / temperature[r]``).
    log_w : ndarray (n,)
        Normalised log weights of the points in the posterior.
    log_z, log_z_se : float
        Log evidence ``ln int pi L`` of the tempered posterior and its standard error.
    n_like : int
        Likelihood calls of the run (every one simulates every recording once).
    finished : bool
        The run reached its effective sample size (not stopped by its call limit).
    """

    points: np.ndarray
    log_prior: np.ndarray
    log_lik: np.ndarray
    temperature: np.ndarray
    log_w: np.ndarray
    log_z: float
    log_z_se: float
    n_like: int
    finished: bool

    @property
    def log_proposal(self) -> np.ndarray:
        """The density each point was drawn from, as an importance sampler's proposal: within a
        shell, the reference's density over the shell's share of it, times the shell's share of
        the points; so that ``exp(log_posterior - log_proposal)`` averages to ``Z`` and the
        points reweight to another temperature
        (:func:`tvcid.discovery.members.member_evidence.run_draws`)."""
        with np.errstate(invalid="ignore"):
            return self.log_posterior - self.log_w - self.log_z - math.log(self.n)

    @property
    def log_weights(self) -> np.ndarray:
        return self.log_w

    def reliable(self, target_ess) -> bool:
        """Finished, ``k < GOOD_K`` and at least ``target_ess`` effective points."""
        return bool(self.finished and self.pareto_k < GOOD_K and self.ess >= target_ess)

    @property
    def counts(self) -> tuple:
        """Points of the run, as one round (the traces' plot marks no round edges)."""
        return (self.n,)


@dataclass(frozen=True)
class NestedReport(ImportanceReport):
    """The diagnostics of a nested-sampling run in an importance run's terms
    (:class:`.importance.ImportanceReport`: ``iterations`` the weighted points, ``n_over_tau``
    their effective number, ``converged`` the run finished with ``k < GOOD_K`` and the target
    effective points), with the evidence.

    Attributes
    ----------
    log_z, log_z_se : float
        Log evidence of the tempered posterior and its standard error.
    n_like : int
        Likelihood calls of the whole run.
    """

    log_z: float = math.nan
    log_z_se: float = math.inf
    n_like: int = 0
    method: str = "nested"

    @classmethod
    def of(cls, run: NestedRun, target_ess, new_points=0, wall_time=0.0):
        """:meth:`.importance.ImportanceReport.of`'s diagnostics, converged only where the run
        also finished, with the evidence."""
        base = ImportanceReport.of(run, target_ess, new_points, wall_time)
        fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
        return cls(**{**fields, "converged": run.reliable(target_ess), "method": "nested",
                      "log_z": float(run.log_z), "log_z_se": float(run.log_z_se),
                      "n_like": int(run.n_like)})


def nested_sample(log_prior, log_lik, temperature, reference, n_live, target_ess, seed,
                  filepath=None, max_calls=math.inf, batch=96, **options):
    """Nested sampling (nautilus) of ``pi L`` over ``reference`` until ``target_ess`` effective
    points; checkpointed to ``filepath`` (HDF5) and resumed from it.

    Parameters
    ----------
    log_prior : callable
        ``(m, d)`` points -> ``(m,)`` log prior density (``-inf`` outside its support).
    log_lik : callable
        ``(m, d)`` points inside the prior -> ``(m, r)`` untempered log-likelihoods.
    temperature : sequence of float (r,)
    reference : AxisReference
    n_live : int
        Live points of each bound.
    target_ess : float
        Effective points at which the run stops.
    seed : int
    filepath : str or Path, optional
        Checkpoint (``.h5``): a run stopped there resumes with the same draws.
    max_calls : float
        Likelihood calls at most, those of a resumed run's earlier part included.
    batch : int
        Points per likelihood call.
    **options
        Further arguments of ``nautilus.Sampler``.

    Returns
    -------
    (NestedRun, int)
        The run and the likelihood calls this call made.
    """
    try:
        import nautilus
    except ImportError:
        raise ImportError("nested sampling needs nautilus-sampler: pip install 'tvcid[nested]'") \
            from None

    temperature = np.asarray(temperature, dtype=float)
    r = temperature.size

    def likelihood(z):
        z = np.atleast_2d(z)
        lpr = np.asarray(log_prior(z), dtype=float)
        ll = np.full((z.shape[0], r), -np.inf)
        inside = np.flatnonzero(np.isfinite(lpr))
        if inside.size:
            ll[inside] = np.asarray(log_lik(z[inside]), dtype=float).reshape(inside.size, r)
        ll = np.where(np.isnan(ll), -np.inf, ll)
        with np.errstate(invalid="ignore"):
            target = lpr + np.sum(ll / temperature, axis=1) - reference.log_density(z)
        target = np.where(np.isfinite(target), target, -np.inf)
        return target, lpr, ll

    sampler = nautilus.Sampler(
        reference.from_unit, likelihood, n_dim=reference.ndim, n_live=int(n_live),
        vectorized=True, seed=int(seed), n_batch=int(batch),
        filepath=None if filepath is None else str(filepath), resume=True,
        blobs_dtype=[("log_prior", float), ("log_lik", float, (r,))], **options)
    before = int(sampler.n_like)
    finished = bool(sampler.run(n_eff=float(target_ess), n_like_max=max_calls,
                                discard_exploration=True, verbose=False))
    points, log_w, _, blobs = sampler.posterior(return_blobs=True)
    keep = np.isfinite(log_w)  # points of no weight: outside the prior, or a failed run
    points, log_w, blobs = points[keep], log_w[keep], blobs[keep]
    run = NestedRun(
        points=np.asarray(points, dtype=float), log_prior=np.asarray(blobs["log_prior"], float),
        log_lik=np.asarray(blobs["log_lik"], dtype=float).reshape(-1, r),
        temperature=temperature, log_w=np.asarray(log_w, dtype=float),
        log_z=float(sampler.log_z), log_z_se=_log_z_se(sampler), n_like=int(sampler.n_like),
        finished=finished)
    return run, int(sampler.n_like) - before


def _log_z_se(sampler) -> float:
    """Standard error of nautilus' ``log Z``: each shell's mean likelihood is a mean over its
    points, its variance the points' variance over their number; the shells' errors are
    independent."""
    start = (sampler.shell_end_exp if sampler._discard_exploration and sampler.explored
             else np.zeros(len(sampler.log_l), dtype=int))
    shells = []
    for log_l, s, log_v in zip(sampler.log_l, start, sampler.shell_log_v):
        log_l = np.asarray(log_l[s:], dtype=float)
        if log_l.size == 0 or not np.isfinite(log_v):
            continue
        log_mean = special.logsumexp(log_l) - math.log(log_l.size)
        if np.isfinite(log_mean):
            shells.append((log_v + log_mean, log_l - log_mean))
    if not shells:
        return math.inf
    log_z = float(special.logsumexp([c for c, _ in shells]))
    # each shell's share of Z times the relative error of its mean
    var = sum(math.exp(2 * (c - log_z)) * float(np.var(np.exp(rel), ddof=1)) / rel.size
              for c, rel in shells if rel.size > 1)
    return float(math.sqrt(var))
