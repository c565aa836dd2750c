"""A member's evidence: the marginal likelihood of its structure, by importance sampling.

The set's weights (:mod:`.set_weights`) are the members' posterior probabilities, ``Z_m / sum
Z``, with ``Z_m = integral L_m(theta) pi_m(theta) dtheta`` the evidence of member ``m`` under its
own prior (the structure search's box, :func:`.member_calibration.member_priors`) and equal prior
probabilities of the members. This module estimates ``log Z_m`` from a member's chain:

* :class:`Proposal` -- a defensive mixture fitted to the chain's draws in the sampling
  coordinates (where every prior is flat): a multivariate Student-t over the draws' mean and
  covariance, and a Gaussian kernel density on the draws themselves (a curved ridge, such as the
  dead-zone / backlash family of paper 002, is followed by the kernels where one ellipsoid would
  put most of its points off it);
* :func:`importance_draws` -- points drawn from it, each point's log prior, log proposal density
  and untempered log-likelihood per recording (:class:`ImportanceDraws`; the simulations are the
  cost, and are made once);
* :func:`log_evidence` -- ``log Z`` at given per-recording temperatures from those draws, with its
  standard error, effective sample size and the Pareto ``k`` of the importance ratios (Vehtari,
  Simpson, Gelman, Yao & Gabry 2024, "Pareto smoothed importance sampling", JMLR 25(72)):
  ``k < 0.7`` is where the estimate is reliable.

The estimate is exact in expectation whatever the proposal (the ratio ``p / q`` is unbiased for
``Z`` wherever ``q`` covers the posterior); the proposal only sets its variance, which ``k`` and
the standard error report. The chain's draws need not have converged for that: a chain that has
not reached part of the posterior gives a proposal that misses it, which ``k`` may not see, and
the report then names the chain as capped.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import logsumexp

from tvcid.discovery.calibration.importance import GOOD_K, StudentT, pareto_k

__all__ = ["Proposal", "ImportanceDraws", "Evidence", "importance_draws", "member_importance_draws",
           "run_draws", "log_evidence", "EVIDENCE_DRAWS"]

#: Proposal points of a member's evidence (:func:`member_importance_draws`).
EVIDENCE_DRAWS = 400
#: Share of the proposal in its Student-t component (the rest in the kernels).
T_SHARE = 0.3
#: Degrees of freedom of the Student-t component.
T_DOF = 4.0
#: Kernels of the kernel component at most (draws chosen at random beyond).
MAX_KERNELS = 300


@dataclass(frozen=True)
class Proposal:
    """A defensive mixture density in the sampling coordinates (:meth:`fit`).

    Attributes
    ----------
    mean : ndarray (d,)
    cov : ndarray (d, d)
        The draws' covariance (floored in each coordinate at a millionth of its prior width).
    centres : ndarray (m, d)
        The kernels' centres (draws).
    bandwidth : float
        The kernels' covariance is ``bandwidth**2 * cov`` (Scott's factor ``m**(-1/(d+4))``).
    t_share : float
    """

    mean: np.ndarray
    cov: np.ndarray
    centres: np.ndarray
    bandwidth: float
    t_share: float = T_SHARE

    @classmethod
    def fit(cls, draws, widths=None, rng=None, max_kernels=MAX_KERNELS) -> "Proposal":
        """The proposal for posterior ``draws`` ``(n, d)`` in the sampling coordinates.

        ``widths``: the prior's width in each coordinate, whose millionth floors the covariance
        (a chain stuck in one coordinate would otherwise give a degenerate proposal).
        """
        z = np.atleast_2d(np.asarray(draws, dtype=float))
        z = z[np.all(np.isfinite(z), axis=1)]
        n, d = z.shape
        if n < 2:
            raise ValueError(f"Proposal.fit: {n} finite draw(s); at least 2 are needed")
        rng = rng if rng is not None else np.random.default_rng(0)
        cov = np.atleast_2d(np.cov(z, rowvar=False))
        floor = (np.full(d, 1e-12) if widths is None
                 else (1e-6 * np.asarray(widths, dtype=float)) ** 2)
        cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
        centres = z if n <= max_kernels else z[rng.choice(n, max_kernels, replace=False)]
        bandwidth = float(centres.shape[0] ** (-1.0 / (d + 4)))
        return cls(z.mean(axis=0), cov, centres, bandwidth)

    @property
    def ndim(self) -> int:
        return self.mean.size

    def _chol(self):
        return np.linalg.cholesky(self.cov)

    def _t(self) -> StudentT:
        """The Student-t component."""
        return StudentT(self.mean, self.cov, T_DOF)

    def sample(self, rng, n) -> np.ndarray:
        """``n`` points ``(n, d)`` from the mixture."""
        d, chol = self.ndim, self._chol()
        from_t = rng.uniform(size=n) < self.t_share
        out = np.empty((n, d))
        k = int(from_t.sum())
        out[from_t] = self._t().sample(rng, k)
        m = n - k
        pick = self.centres[rng.integers(self.centres.shape[0], size=m)]
        out[~from_t] = pick + self.bandwidth * (rng.standard_normal((m, d)) @ chol.T)
        return out

    def log_density(self, z) -> np.ndarray:
        """The mixture's log density at ``z`` ``(n, d)``."""
        z = np.atleast_2d(np.asarray(z, dtype=float))
        d, chol = self.ndim, self._chol()
        log_det = 2.0 * float(np.sum(np.log(np.diag(chol))))
        log_t = self._t().log_density(z)
        h = self.bandwidth
        k_log_norm = -0.5 * d * math.log(2 * math.pi) - 0.5 * log_det - d * math.log(h)
        log_k = np.empty(z.shape[0])
        for start in range(0, z.shape[0], 256):  # bounded memory: points x kernels x d
            diff = z[start:start + 256, None, :] - self.centres[None, :, :]
            v = np.linalg.solve(chol, diff.reshape(-1, d).T).T.reshape(diff.shape) / h
            log_k[start:start + 256] = (logsumexp(-0.5 * np.sum(v * v, axis=2), axis=1)
                                        - math.log(self.centres.shape[0]))
        log_k += k_log_norm
        return np.logaddexp(math.log(self.t_share) + log_t, math.log1p(-self.t_share) + log_k)


@dataclass(frozen=True)
class ImportanceDraws:
    """Points from a member's :class:`Proposal` with what its evidence needs
    (:func:`importance_draws`).

    Attributes
    ----------
    records : tuple of str
        The recordings, in the columns' order.
    log_prior : ndarray (n,)
        Log prior density in the sampling coordinates (``-inf`` outside the prior's box).
    log_proposal : ndarray (n,)
    log_lik : ndarray (n, n_records)
        Untempered log-likelihood of each recording (``-inf`` where a run failed or the point
        lies outside the prior; such points are not simulated).
    inflation : tuple of float
        The member's own discrepancy factor per recording (its chain's temperature).
    n_parameters : int
    simulated_seconds, simulated_steps : float
        The simulations' cost.
    points : ndarray (n, d) or None
        The points themselves (sampling coordinates); not kept in :meth:`to_dict`.
    """

    records: tuple
    log_prior: np.ndarray
    log_proposal: np.ndarray
    log_lik: np.ndarray
    inflation: tuple
    n_parameters: int
    simulated_seconds: float = 0.0
    simulated_steps: float = 0.0
    points: np.ndarray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        return {"records": list(self.records), "log_prior": self.log_prior.tolist(),
                "log_proposal": self.log_proposal.tolist(), "log_lik": self.log_lik.tolist(),
                "inflation": list(self.inflation), "n_parameters": self.n_parameters,
                "simulated_seconds": self.simulated_seconds,
                "simulated_steps": self.simulated_steps}

    @classmethod
    def from_dict(cls, d) -> "ImportanceDraws":
        def arr(v):
            return np.array([-np.inf if x is None else x for x in np.ravel(v)],
                            dtype=float).reshape(np.shape(v))
        return cls(tuple(d["records"]), arr(d["log_prior"]), arr(d["log_proposal"]),
                   arr(d["log_lik"]).reshape(len(d["log_lik"]), len(d["records"])),
                   tuple(d["inflation"]), int(d["n_parameters"]),
                   float(d.get("simulated_seconds", 0.0)), float(d.get("simulated_steps", 0.0)))


def importance_draws(proposal, log_prior, log_lik, records, n, rng, inflation=None,
                     batch=64) -> ImportanceDraws:
    """``n`` points from ``proposal`` and their log prior, log proposal density and
    log-likelihood per recording.

    Parameters
    ----------
    proposal : Proposal
    log_prior : callable
        ``(m, d)`` points -> ``(m,)`` log prior density (``-inf`` outside its support).
    log_lik : callable
        ``(m, d)`` points inside the prior -> ``(m, n_records)`` untempered log-likelihoods.
    records : sequence of str
    n : int
    rng : numpy.random.Generator
    inflation : sequence of float, optional
        The member's own temperatures (default 1 each).
    batch : int
        Points simulated per call of ``log_lik``.
    """
    z = proposal.sample(rng, int(n))
    lp = np.asarray(log_prior(z), dtype=float)
    ll = np.full((z.shape[0], len(records)), -np.inf)
    inside = np.flatnonzero(np.isfinite(lp))
    for start in range(0, inside.size, batch):
        idx = inside[start:start + batch]
        ll[idx] = np.asarray(log_lik(z[idx]), dtype=float).reshape(idx.size, len(records))
    ll = np.where(np.isnan(ll), -np.inf, ll)
    return ImportanceDraws(tuple(records), lp, proposal.log_density(z), ll,
                           tuple(inflation) if inflation is not None else (1.0,) * len(records),
                           proposal.ndim, points=z)


def run_draws(posterior) -> ImportanceDraws:
    """The evidence draws of a member whose posterior is an importance run
    (:attr:`tvcid.discovery.calibration.Posterior.importance`): its points, the rounds'
    mixture density and each recording's untempered log-likelihood, at no further cost (the
    run's simulations are counted in the member's sampling)."""
    run = posterior.importance
    lp = posterior.calibration.log_posterior_
    return ImportanceDraws(tuple(t.name for t in lp.terms), run.log_prior, run.log_proposal,
                           run.log_lik, tuple(float(v) for v in run.temperature),
                           run.points.shape[1], points=run.points)


def member_importance_draws(posterior, n=EVIDENCE_DRAWS, seed=0) -> ImportanceDraws:
    """:func:`importance_draws` of one calibrated member: the proposal fitted to its posterior
    draws (:attr:`tvcid.discovery.calibration.Posterior.internal`), each point's log-likelihood per
    recording without the discrepancy factor
    (:meth:`tvcid.discovery.calibration.log_posterior.LogPosterior.pointwise`, summed per record), its
    simulations counted in the member's cost.

    Where the ratios at the member's own temperatures are unreliable (:attr:`Evidence.reliable`:
    the chain's draws miss where the posterior's mass is, as a short chain at a prior bound
    does), a second proposal is fitted to the chain's draws and the first points resampled by
    their ratios, and ``n`` more points drawn from it: each round's points keep their own
    proposal's density, so the mean over both rounds averages two estimates each exact in
    expectation (the mixture's density would not be: the second proposal sits on the first
    round's heaviest points and would lower exactly their ratios)."""
    from tvcid.discovery.calibration.log_posterior import term_size
    from tvcid.discovery.calibration.posterior import _uninflated

    if getattr(posterior, "importance", None) is not None:
        return run_draws(posterior)
    cal = posterior.calibration
    if cal is None:
        raise ValueError("member_importance_draws: the posterior has no calibration to evaluate "
                         "(a posterior read back from JSON cannot be)")
    lp = cal.log_posterior_
    rng = np.random.default_rng([int(seed), 7])
    widths = np.array([np.diff(p.internal_bounds)[0] for p in lp.priors])
    proposal = Proposal.fit(posterior.internal, widths=widths, rng=rng)
    sizes = [term_size(t) for t in lp.terms]
    cuts = np.cumsum([0] + sizes)
    seconds, steps = lp.simulated_seconds, lp.simulated_steps
    inflation = [float(np.max(t.inflation)) for t in lp.terms]

    def log_lik(z):
        lp.account(z.shape[0])  # pointwise() runs every record once per point
        pw = lp.pointwise(z)
        return np.column_stack([pw[:, a:b].sum(axis=1) for a, b in zip(cuts[:-1], cuts[1:])])

    records = [t.name for t in lp.terms]
    with _uninflated(cal):
        draws = importance_draws(proposal, lp.log_prior, log_lik, records, n, rng,
                                 inflation=inflation)
        if not log_evidence(draws, inflation).reliable:
            draws = _second_round(draws, posterior.internal, widths, lp.log_prior,
                                  log_lik, n, rng)
    return ImportanceDraws(draws.records, draws.log_prior, draws.log_proposal, draws.log_lik,
                           draws.inflation, draws.n_parameters,
                           lp.simulated_seconds - seconds, lp.simulated_steps - steps)


def _second_round(first, chain, widths, log_prior, log_lik, n, rng) -> ImportanceDraws:
    """``first``'s points and ``n`` more from a proposal refitted to ``chain`` and ``first``'s
    points resampled by their ratios, each at its own proposal's density."""
    centres = chain
    t = np.asarray(first.inflation, dtype=float)
    with np.errstate(invalid="ignore"):
        log_w = first.log_prior + np.sum(first.log_lik / t[None, :], axis=1) - first.log_proposal
    log_w = np.where(np.isfinite(log_w), log_w, -np.inf)
    points = first.points
    if np.any(np.isfinite(log_w)):
        w = np.exp(log_w - np.max(log_w))
        picked = points[rng.choice(points.shape[0], size=chain.shape[0], p=w / w.sum())]
        centres = np.concatenate([chain, picked])
    second = Proposal.fit(centres, widths=widths, rng=rng)
    more = importance_draws(second, log_prior, log_lik, first.records, n, rng,
                            inflation=first.inflation)
    return ImportanceDraws(first.records, np.concatenate([first.log_prior, more.log_prior]),
                           np.concatenate([first.log_proposal, more.log_proposal]),
                           np.concatenate([first.log_lik, more.log_lik]), first.inflation,
                           first.n_parameters, points=np.concatenate([points, more.points]))


@dataclass(frozen=True)
class Evidence:
    """A member's ``log Z`` (:func:`log_evidence`).

    Attributes
    ----------
    log_z : float
        ``-inf`` where no proposal point had a finite target.
    se : float
        Standard error of ``log_z`` (delta method on the ratios' mean).
    ess : float
        Effective sample size of the ratios, ``(sum w)^2 / sum w^2``.
    pareto_k : float
        The generalised Pareto shape fitted to the ratios' tail (PSIS).
    n : int
        Proposal points.
    temperature : tuple of float
        Each recording's log-likelihood was divided by these.
    """

    log_z: float
    se: float
    ess: float
    pareto_k: float
    n: int
    temperature: tuple = field(default=())

    @property
    def reliable(self) -> bool:
        """``k < GOOD_K`` and at least 20 effective points."""
        return bool(math.isfinite(self.log_z) and self.pareto_k < GOOD_K and self.ess >= 20)

    def to_dict(self) -> dict:
        return {"log_z": self.log_z, "se": self.se, "ess": self.ess, "pareto_k": self.pareto_k,
                "n": self.n, "temperature": list(self.temperature), "reliable": self.reliable}


def log_evidence(draws: ImportanceDraws, temperature=None) -> Evidence:
    """``log Z`` of a member at per-recording ``temperature`` (default 1 each): the mean of the
    importance ratios ``pi(theta) prod_r L_r(theta)^(1/T_r) / q(theta)`` over the proposal's
    points."""
    t = (np.ones(len(draws.records)) if temperature is None
         else np.asarray(temperature, dtype=float))
    if t.shape != (len(draws.records),) or np.any(~(t > 0)):
        raise ValueError(f"log_evidence: temperatures {t.tolist()} for records "
                         f"{list(draws.records)}; one positive value each")
    with np.errstate(invalid="ignore"):
        log_w = draws.log_prior + np.sum(draws.log_lik / t[None, :], axis=1) - draws.log_proposal
    log_w = np.where(np.isnan(log_w), -np.inf, log_w)
    n = log_w.size
    if not np.any(np.isfinite(log_w)):
        return Evidence(-math.inf, math.inf, 0.0, math.inf, n, tuple(t.tolist()))
    top = float(np.max(log_w))
    w = np.exp(log_w - top)
    mean = float(w.mean())
    ess = float(w.sum() ** 2 / np.sum(w * w))
    se = float(w.std(ddof=1) / math.sqrt(n) / mean) if n > 1 else math.inf
    return Evidence(top + math.log(mean), se, ess, pareto_k(log_w), n, tuple(t.tolist()))
