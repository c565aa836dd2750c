"""Adaptive importance sampling of a calibration's posterior from its Laplace approximation.

Where a member's posterior is close to the Gaussian of its maximum a posteriori and curvature,
independent points from a widened multivariate t around it, weighted by ``p / q``, give the
posterior with far fewer simulations than a chain: an ensemble needs ``50 tau`` steps of every
walker, importance sampling a few hundred effective points. The rounds adapt the proposal
(population Monte Carlo; Cappe, Guillin, Marin & Robert 2004, "Population Monte Carlo", J. Comput.
Graph. Stat. 13(4)): each round's proposal is the t refitted to all points so far by their
weights, and every point is weighted against the mixture of all rounds' proposals (the balance
heuristic; Veach & Guibas 1995, Owen & Zhou 2000), so the estimate uses every simulation.

The run is trusted only where its own diagnostic says so: the Pareto ``k`` of the ratios' tail
(PSIS; Vehtari, Simpson, Gelman, Yao & Gabry 2024, JMLR 25(72)) under :data:`GOOD_K` and an
effective sample size of at least ``target_ess``. Elsewhere (a curved ridge, two modes, a
maximum on a prior bound) the caller runs its chain, started from the run's points.

The same points, with each recording's untempered log-likelihood, are the member's evidence
draws (:func:`tvcid.discovery.members.member_evidence.log_evidence`).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.special import gammaln, logsumexp

from .runner import ConvergenceReport

__all__ = ["GOOD_K", "StudentT", "ImportanceRun", "ImportanceReport", "adaptive_importance",
           "pareto_k", "weighted_quantiles", "WeightedPoints", "START_SCALE"]

#: Pareto ``k`` of the importance ratios below which the estimate is reliable (PSIS).
GOOD_K = 0.7
#: Degrees of freedom of the proposal's t: tails heavier than the posterior's keep the ratios
#: bounded where the Gaussian approximation is too narrow.
PROPOSAL_DOF = 5.0
#: Widening of a fitted covariance's square root before it proposes (in 9 dimensions a t
#: this much wider than a Gaussian target keeps about 0.7 of its points effective).
PROPOSAL_SCALE = 1.15
#: The most a round's quadratic fit widens the last proposal's scale along a direction the points
#: barely curve along.
MAX_GROWTH = 30.0
#: Widening of the Laplace approximation's square root in the first round (the curvature at the
#: maximum only approximates the posterior's spread).
START_SCALE = 1.3


def pareto_k(log_w) -> float:
    """PSIS's Pareto ``k`` of importance ratios given as logs (arviz's ``psislw``); ``inf`` with
    fewer than 10 finite ratios."""
    import arviz as az

    log_w = np.asarray(log_w, dtype=float)
    finite = log_w[np.isfinite(log_w)]
    if finite.size < 10:
        return math.inf
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, k = az.psislw(finite - finite.max(), reff=1.0)
    return float(np.asarray(k).ravel()[0])


def weighted_quantiles(values, weights, q) -> np.ndarray:
    """Quantiles ``q`` of ``values`` ``(n,)`` under normalised ``weights`` (the inverse of the
    weighted empirical distribution, midpoint rule)."""
    values = np.asarray(values, dtype=float)
    w = np.asarray(weights, dtype=float)
    order = np.argsort(values)
    v, w = values[order], w[order]
    c = np.cumsum(w) - 0.5 * w
    c = c / w.sum()
    return np.interp(np.asarray(q, dtype=float), c, v)


def _positive_definite(cov) -> np.ndarray:
    """``cov`` symmetrised, its eigenvalues held at least ``1e-13`` of the largest, so that its
    Cholesky factor exists (a covariance rebuilt from principal sds a million apart loses
    definiteness to rounding)."""
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    cov = 0.5 * (cov + cov.T)
    try:
        np.linalg.cholesky(cov)
        return cov
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(cov)
        vals = np.maximum(vals, 1e-13 * max(float(np.max(vals)), 1e-300))
        return (vecs * vals) @ vecs.T


def tempered_power(log_w, min_ess) -> float:
    """The largest ``beta`` in (0, 1] whose weights ``exp(beta * log_w)`` keep ``min_ess``
    effective points (bisection; 1 when the untempered weights already do)."""
    finite = np.asarray(log_w, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return 1.0

    def ess(beta):
        lw = beta * (finite - finite.max())
        w = np.exp(lw)
        return float(w.sum() ** 2 / np.sum(w * w))

    if ess(1.0) >= min_ess:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ess(mid) >= min_ess else (lo, mid)
    return max(lo, 1e-6)


@dataclass(frozen=True)
class StudentT:
    """A multivariate t density in the sampling coordinates.

    Attributes
    ----------
    mean : ndarray (d,)
    cov : ndarray (d, d)
        Its scale matrix (the covariance times ``(dof - 2) / dof``).
    dof : float
    """

    mean: np.ndarray
    cov: np.ndarray
    dof: float = PROPOSAL_DOF

    def __post_init__(self):
        object.__setattr__(self, "mean", np.asarray(self.mean, dtype=float))
        object.__setattr__(self, "cov", _positive_definite(self.cov))

    @property
    def ndim(self) -> int:
        return int(np.size(self.mean))

    def _chol(self):
        return np.linalg.cholesky(self.cov)

    def sample(self, rng, n) -> np.ndarray:
        """``n`` points ``(n, d)`` drawn with a ``numpy.random.Generator``."""
        g = rng.standard_normal((int(n), self.ndim)) @ self._chol().T
        return self.mean + g / np.sqrt(rng.chisquare(self.dof, size=int(n)) / self.dof)[:, None]

    def log_density(self, z) -> np.ndarray:
        """Normalised log density at the rows of ``z``."""
        z = np.atleast_2d(np.asarray(z, dtype=float))
        d, chol, nu = self.ndim, self._chol(), self.dof
        u = np.linalg.solve(chol, (z - self.mean).T)
        maha = np.sum(u * u, axis=0)
        log_det = 2.0 * float(np.sum(np.log(np.diag(chol))))
        return (gammaln((nu + d) / 2) - gammaln(nu / 2) - 0.5 * d * math.log(nu * math.pi)
                - 0.5 * log_det - 0.5 * (nu + d) * np.log1p(maha / nu))

    @classmethod
    def fit(cls, points, log_w, previous, scale=PROPOSAL_SCALE) -> "StudentT":
        """The t over ``points`` weighted by ``exp(beta * log_w)``: their weighted mean and
        covariance, widened by ``scale`` and shrunk toward ``previous``'s by ``d`` pseudo-points
        against the weights' effective sample size. ``beta`` is 1, or the largest power that
        leaves a quarter of the points effective (:func:`tempered_power`): from a proposal far
        from the posterior, a few heavy points would give a fit of low rank; tempered, the fit
        moves part of the way, and the next round the rest."""
        log_w = np.where(np.isfinite(log_w), log_w, -np.inf)
        beta = tempered_power(log_w, 0.25 * np.count_nonzero(np.isfinite(log_w)))
        lw = beta * log_w
        w = np.exp(lw - np.max(lw))
        w = w / w.sum()
        mean = w @ points
        diff = points - mean
        cov = (diff * w[:, None]).T @ diff
        ess = 1.0 / float(np.sum(w * w))
        d = points.shape[1]
        # shrunk toward the previous fit before its widening, not toward the widened proposal
        cov = (ess * cov + d * np.atleast_2d(previous.cov) / PROPOSAL_SCALE**2) / (ess + d)
        return cls(mean, cov * scale**2, previous.dof)

    @classmethod
    def from_quadratic(cls, points, log_post, previous, scale=PROPOSAL_SCALE):
        """The t whose centre and scale are the maximum and inverse curvature of a quadratic
        fitted by least squares to the log posterior ``log_post`` at ``points`` (a Laplace
        approximation read from the points instead of finite differences at one; the points
        within a Gaussian's 99.9 % region of the best one where they are enough), widened by
        ``scale``; None where fewer points than twice the quadratic's coefficients are finite.
        A maximum more than ``3 + sqrt(d)`` of ``previous``'s scales from ``previous``'s centre
        (beyond the points: an extrapolation) is brought back to that distance. Along a direction whose curvature is under ``MAX_GROWTH**-2`` of the
        last proposal's (flat, or curving the wrong way: the points did not reach the posterior's
        edge there) the scale grows ``MAX_GROWTH`` times.

        Where the weights are heavy-tailed, the log posterior's values still carry its shape
        (docs/methods/calibration.md, "Importance sampling before the chain")."""
        from scipy.stats import chi2

        ok = np.isfinite(log_post)
        d = points.shape[1]
        n_coef = 1 + d + d * (d + 1) // 2
        if ok.sum() < 2 * n_coef:
            return None
        # the core: points a Gaussian posterior would reach (its 99.9 % region); the far tails
        # of early, wide rounds would fit a global curvature instead of the posterior's
        core = ok & (log_post >= np.max(log_post[ok]) - 0.5 * chi2.ppf(0.999, d))
        if core.sum() >= 2 * n_coef:
            ok = core
        chol = np.linalg.cholesky(np.atleast_2d(previous.cov))
        u = np.linalg.solve(chol, (points[ok] - previous.mean).T).T  # whitened by ``previous``
        iu, ju = np.triu_indices(d)
        design = np.column_stack([np.ones(u.shape[0]), u, u[:, iu] * u[:, ju]])
        coef, *_ = np.linalg.lstsq(design, log_post[ok], rcond=None)
        grad = coef[1:1 + d]
        hess = np.zeros((d, d))
        hess[iu, ju] = coef[1 + d:]
        hess = hess + hess.T  # diagonal doubled: d2/du2 of c u^2 is 2c
        # a direction the points barely curve along (the posterior far wider there than the
        # last proposal, as along a thin ridge) grows by at most MAX_GROWTH this round
        lam, vec = np.linalg.eigh(-hess)
        if not np.all(np.isfinite(lam)):
            return None
        lam = np.maximum(lam, MAX_GROWTH**-2)
        cov_u = (vec / lam) @ vec.T
        centre = cov_u @ grad
        if not np.all(np.isfinite(centre)):
            return None
        reach = 3.0 + math.sqrt(d)  # the points' extent: beyond it the fit extrapolates
        centre = centre * min(1.0, reach / max(float(np.sqrt(np.sum(centre**2))), 1e-300))
        mean = previous.mean + chol @ centre
        cov = chol @ cov_u @ chol.T
        return cls(mean, cov * scale**2, previous.dof)

    def to_dict(self) -> dict:
        return {"mean": np.asarray(self.mean).tolist(), "cov": np.atleast_2d(self.cov).tolist(),
                "dof": self.dof}

    @classmethod
    def from_dict(cls, d) -> "StudentT":
        return cls(np.asarray(d["mean"], dtype=float), np.asarray(d["cov"], dtype=float),
                   float(d.get("dof", PROPOSAL_DOF)))


def systematic_resample(weights, rng, n) -> np.ndarray:
    """Indices of ``n`` points drawn by their normalised ``weights`` (systematic resampling, in
    a random order)."""
    u = (rng.uniform() + np.arange(n)) / n
    idx = np.minimum(np.searchsorted(np.cumsum(weights), u), len(weights) - 1)
    return rng.permutation(idx)


class WeightedPoints:
    """What weighted points of a posterior give, whatever drew them: a class with ``points``
    ``(n, d)``, ``log_prior`` ``(n,)``, ``log_lik`` ``(n, r)`` (untempered, per recording),
    ``temperature`` ``(r,)`` and a ``log_weights`` property (:class:`ImportanceRun`,
    :class:`.nested.NestedRun`)."""

    @property
    def n(self) -> int:
        return int(self.points.shape[0])

    @property
    def log_posterior(self) -> np.ndarray:
        """Unnormalised log posterior at every point (``-inf`` where a run failed)."""
        with np.errstate(invalid="ignore"):
            lp = self.log_prior + np.sum(self.log_lik / self.temperature[None, :], axis=1)
        return np.where(np.isnan(lp), -np.inf, lp)

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights (zeros where none is finite)."""
        lw = self.log_weights
        if not np.any(np.isfinite(lw)):
            return np.zeros(self.n)
        w = np.exp(lw - np.max(lw))
        return w / w.sum()

    @property
    def ess(self) -> float:
        """Effective sample size ``1 / sum w^2`` of the normalised weights (0 if none is
        finite)."""
        w = self.weights
        return float(1.0 / np.sum(w * w)) if w.sum() > 0 else 0.0

    @property
    def pareto_k(self) -> float:
        return pareto_k(self.log_weights)

    def resample(self, rng, n) -> np.ndarray:
        """Indices of ``n`` points drawn by their weights (:func:`systematic_resample`)."""
        return systematic_resample(self.weights, rng, n)

    def distinct(self, rng, n):
        """Indices of ``n`` distinct points drawn by their weights without replacement (the
        walkers of a chain started from the run), or None when fewer carry weight."""
        w = self.weights
        if np.count_nonzero(w > 0) < n:
            return None
        return rng.choice(self.n, size=n, replace=False, p=w)

    def interval_drift(self, logs=None) -> dict:
        """How far the 90 % intervals move between the run's two halves (points of even and odd
        index, each weighted on its own), over the whole run's width, the largest over the
        coordinates (sampling coordinates): the chain's :meth:`.posterior.Posterior.
        interval_drift` for independent points."""
        z, lw = self.points, self.log_weights
        out = []
        for j in range(z.shape[1]):
            q = []
            for part in (slice(0, None, 2), slice(1, None, 2), slice(None)):
                lwp = lw[part]
                w = np.exp(lwp - np.max(lwp)) if np.any(np.isfinite(lwp)) else np.ones(lwp.size)
                q.append(weighted_quantiles(z[part, j], w, (0.05, 0.95)))
            width = q[2][1] - q[2][0]
            out.append(float(np.abs(q[0] - q[1]).sum() / width) if width > 0 else 0.0)
        j = int(np.argmax(out))
        return {"largest": out[j], "index": j}


@dataclass(frozen=True)
class ImportanceRun(WeightedPoints):
    """The points of an adaptive importance sampling run and what weighs them.

    Attributes
    ----------
    proposals : tuple of StudentT
        One per round, in order.
    counts : tuple of int
        Points drawn from each.
    points : ndarray (n, d)
        Sampling coordinates, rounds concatenated.
    log_prior : ndarray (n,)
        ``-inf`` outside the prior (such points are not simulated).
    log_lik : ndarray (n, r)
        Untempered log-likelihood of each recording.
    temperature : ndarray (r,)
        Each recording's discrepancy factor: the posterior's log-likelihood is
        ``sum_r log_lik[:, r] / temperature[r]``.
    """

    proposals: tuple
    counts: tuple
    points: np.ndarray
    log_prior: np.ndarray
    log_lik: np.ndarray
    temperature: np.ndarray
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def log_proposal(self) -> np.ndarray:
        """Log density of the rounds' mixture, ``sum_j n_j q_j / sum_j n_j``, at every point."""
        if "log_q" not in self._cache:
            parts = [math.log(c / self.n) + p.log_density(self.points)
                     for p, c in zip(self.proposals, self.counts)]
            self._cache["log_q"] = logsumexp(np.vstack(parts), axis=0)
        return self._cache["log_q"]

    @property
    def log_weights(self) -> np.ndarray:
        return self.log_posterior - self.log_proposal

    def reliable(self, target_ess) -> bool:
        """``k < GOOD_K`` and at least ``target_ess`` effective points."""
        return bool(self.pareto_k < GOOD_K and self.ess >= target_ess)


@dataclass(frozen=True)
class ImportanceReport(ConvergenceReport):
    """The diagnostics of an importance run, in the chain's terms (a
    :class:`tvcid.discovery.calibration.runner.ConvergenceReport`): ``iterations`` counts the
    points drawn, ``tau`` is the points per effective point (``n / ess``), so ``n_over_tau`` is
    the effective sample size and the rule ``N > tau_factor * tau`` reads ``ess >= target``;
    ``converged`` adds ``k < GOOD_K``; ``acceptance`` is the ratios' efficiency ``ess / n``;
    ``new_steps`` the points this call simulated; ``burn`` is 0.

    Attributes
    ----------
    pareto_k : float
        PSIS's Pareto ``k`` of the ratios (1e9 where it cannot be estimated).
    rounds : int
    method : str
        ``"importance"``.
    """

    pareto_k: float = 1e9
    rounds: int = 0
    method: str = "importance"

    @classmethod
    def of(cls, run: ImportanceRun, target_ess, new_points=0, wall_time=0.0):
        ess = run.ess
        tau = run.n / ess if ess > 0 else math.inf
        k = run.pareto_k
        return cls(iterations=run.n, tau=(float(tau),) * run.points.shape[1],
                   n_over_tau=float(ess), tau_factor=float(target_ess),
                   converged=bool(k < GOOD_K and ess >= target_ess),
                   acceptance=float(ess / run.n) if run.n else 0.0, new_steps=int(new_points),
                   wall_time=float(wall_time), pareto_k=float(k) if math.isfinite(k) else 1e9,
                   rounds=len(run.counts))


def adaptive_importance(log_prior, log_lik, temperature, start, rng_of_round, n_round,
                        max_rounds, target_ess, stored=(), save=None, batch=48):
    """Rounds of importance sampling until the ratios are reliable, ``max_rounds`` are spent, or
    from the third round on the rounds left could not reach ``target_ess`` at the last round's
    own efficiency. Each round's proposal after the first is the quadratic fit to the log
    posterior at all points so far (:meth:`StudentT.from_quadratic`), or where that fails the
    t of their tempered weights (:meth:`StudentT.fit`).

    Parameters
    ----------
    log_prior : callable
        ``(m, d)`` points -> ``(m,)`` log prior density (``-inf`` outside its support).
    log_lik : callable
        ``(m, d)`` points inside the prior -> ``(m, r)`` untempered log-likelihoods.
    temperature : sequence of float (r,)
    start : StudentT
        The first round's proposal (the Laplace approximation, widened).
    rng_of_round : callable
        ``j -> numpy.random.Generator`` of round ``j`` (a resumed run draws the same points).
    n_round : int
        Points per round.
    max_rounds : int
    target_ess : float
    stored : sequence of tuples
        Rounds already simulated, ``(proposal, points, log_prior, log_lik)`` (a checkpoint).
    save : callable, optional
        ``save(j, proposal, points, log_prior, log_lik)`` after each new round.
    batch : int
        Points simulated per call of ``log_lik``.

    Returns
    -------
    (ImportanceRun, int)
        The run and the points this call simulated.
    """
    temperature = np.asarray(temperature, dtype=float)
    rounds = list(stored)
    proposal = start
    new = 0
    while True:
        if rounds:
            run = _run_of(rounds, temperature)
            if run.reliable(target_ess) or len(rounds) >= max_rounds \
                    or _out_of_reach(rounds, run, temperature, max_rounds, target_ess):
                return run, new
            lw = run.log_weights
            if not np.any(np.isfinite(lw)):  # nothing inside: the start's proposal, wider
                proposal = StudentT(start.mean, np.atleast_2d(start.cov) * 4.0, start.dof)
            else:
                proposal = (StudentT.from_quadratic(run.points, run.log_posterior, rounds[-1][0])
                            or StudentT.fit(run.points, lw, rounds[-1][0]))
        j = len(rounds)
        z = proposal.sample(rng_of_round(j), n_round)
        lp = np.asarray(log_prior(z), dtype=float)
        ll = np.full((z.shape[0], temperature.size), -np.inf)
        inside = np.flatnonzero(np.isfinite(lp))
        for s in range(0, inside.size, batch):
            idx = inside[s:s + batch]
            ll[idx] = np.asarray(log_lik(z[idx]), dtype=float).reshape(idx.size, temperature.size)
        ll = np.where(np.isnan(ll), -np.inf, ll)
        new += int(inside.size)
        rounds.append((proposal, z, lp, ll))
        if save is not None:
            save(j, proposal, z, lp, ll)


def _out_of_reach(rounds, run, temperature, max_rounds, target_ess) -> bool:
    """From the third round on (two adaptations: the first, from one round's points of a
    proposal several times too narrow in a direction, can still miss the posterior's width
    there): the rounds left, each as effective as the last one alone, would not bring the run to
    ``target_ess`` (a posterior no t covers: a curved ridge, two modes)."""
    if len(rounds) < 3:
        return False
    last = _run_of(rounds[-1:], temperature).ess
    return run.ess + (max_rounds - len(rounds)) * last < target_ess


def _run_of(rounds, temperature) -> ImportanceRun:
    return ImportanceRun(tuple(r[0] for r in rounds), tuple(int(r[1].shape[0]) for r in rounds),
                         np.vstack([r[1] for r in rounds]),
                         np.concatenate([r[2] for r in rounds]),
                         np.vstack([r[3] for r in rounds]), temperature)
