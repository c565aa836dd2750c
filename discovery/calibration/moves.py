"""An independence move from the Laplace approximation, for posteriors that are nearly Gaussian,
and its adaptation to the chain over a calibration's run.

emcee's differential-evolution moves cross a narrow valley in a few tens of steps per independent
sample. Where the posterior is
close to the Gaussian of its maximum a posteriori and Hessian (the Laplace approximation), a
Metropolis-Hastings *independence* proposal drawn from a widened multivariate t around it is
accepted most of the time and forgets the walker's position at once (Robert & Casella 2004,
section 7.4; the t's tails keep the importance ratio bounded where the Gaussian is too narrow).
Mixed with the DE moves, which carry the chain where the approximation is poor, the mixture keeps
detailed balance move by move. Where the Laplace approximation cannot serve (a ridge cut by the
prior, a maximum on a prior bound: :func:`tvcid.discovery.calibration.optimum.laplace_covariance`)
the move waits idle
until it can be fitted to the chain; a proposal that would be accepted under a quarter of the
time is not switched on (:meth:`LaplaceIndependenceMove.expected_acceptance`).

:class:`LaplaceAdaptation` (a part of :class:`tvcid.discovery.calibration.calibration.Calibration`)
builds the moves of a run and refits, checks and switches the move off as the chain grows.
"""
from __future__ import annotations

import json

import emcee
import numpy as np

from .backend import H5_GROUP, CheckpointBackend

__all__ = ["LaplaceIndependenceMove", "PriorChordMove", "LaplaceAdaptation"]


class LaplaceIndependenceMove(emcee.moves.MHMove):
    """Independence proposals from a multivariate t around the maximum a posteriori.

    Parameters
    ----------
    mean : array (ndim,)
        Centre (the MAP, sampling coordinates).
    cov : array (ndim, ndim)
        The Laplace covariance (inverse of the negative Hessian of the log posterior there).
    df : float
        Degrees of freedom of the t (heavier tails than the Gaussian: 5).
    scale : float
        Widening of the covariance's square root (1.15: a proposal somewhat wider than the
        target is accepted less often but never stalls in a tail).
    """

    def __init__(self, mean, cov, df=5.0, scale=1.15):
        self.df = float(df)
        self.scale = float(scale)
        self.set_proposal(mean, cov)
        super().__init__(self._propose, ndim=self.mean.size)

    def set_proposal(self, mean, cov):
        """Centre and covariance (before the widening ``scale``) of the proposal."""
        self.mean = np.asarray(mean, dtype=float)
        cov = np.atleast_2d(np.asarray(cov, dtype=float)) * self.scale**2
        self.chol = np.linalg.cholesky(cov)

    def log_density(self, x):
        """Log density of the proposal at the rows of ``x`` (up to a constant)."""
        d = np.linalg.solve(self.chol, (np.atleast_2d(x) - self.mean).T)
        q = np.sum(d * d, axis=0)
        return -0.5 * (self.df + self.mean.size) * np.log1p(q / self.df)

    def draw(self, rng, n):
        """``n`` proposals drawn with a ``numpy.random.Generator``."""
        g = rng.standard_normal((n, self.mean.size))
        w = rng.chisquare(self.df, size=n) / self.df
        return self.mean + (g / np.sqrt(w)[:, None]) @ self.chol.T

    def expected_acceptance(self, trial, trial_log_prob) -> float:
        """Acceptance the move would have at equilibrium, from proposals ``trial`` and their log
        posterior alone: with importance weights ``w = pi / q``, ``sum_ij min(w_i, w_j) /
        (M sum_i w_i)`` (the current point weighted to the posterior, the proposal from ``q``).
        The walkers' own positions are not used: early in a chain they sit where the posterior
        is low, and every proposal looks acceptable from there."""
        lw = np.asarray(trial_log_prob, dtype=float) - self.log_density(trial)
        lw = np.where(np.isfinite(lw), lw, -np.inf)
        if not np.any(np.isfinite(lw)):
            return 0.0
        w = np.exp(lw - np.max(lw))
        return float(np.sum(np.minimum(w[:, None], w[None, :])) / (w.size * np.sum(w)))

    def _propose(self, coords, random):
        n, ndim = coords.shape
        g = random.randn(n, ndim)
        w = random.chisquare(self.df, size=n) / self.df
        new = self.mean + (g / np.sqrt(w)[:, None]) @ self.chol.T
        # independence: the ratio q(old) / q(new) enters the acceptance
        return new, self.log_density(coords) - self.log_density(new)


class PriorChordMove(emcee.moves.RedBlueMove):
    """Hit-and-run across the prior: a walker moves to a uniform point of the chord the prior's
    box cuts along a direction drawn independently of it.

    The direction is a coordinate axis or a principal axis of the complementary half of the
    ensemble (the red-blue split keeps the proposal independent of the walker moved, so the
    uniform chord is a symmetric proposal: Smith 1984; Belisle, Romeijn & Smith 1993). Along a
    direction the recordings do not pin (a band-pass gain deep in saturation, a hydraulic
    resonance far above the cycle, a backlash below what the cycle resolves) the chord's points are
    accepted about as often as the prior allows, and a walker crosses the whole prior in one step,
    where the differential-evolution moves diffuse across it at the ensemble's own spread. Along a
    pinned direction the move is accepted rarely and costs one simulation.

    Parameters
    ----------
    low, high : array (ndim,)
        The prior's box in sampling coordinates.
    extra : sequence of arrays (ndim,)
        Directions known to be flat where the recordings do not reach, besides the axes (the
        linear block's resonance at fixed damping ratio and static gain:
        :func:`resonance_direction`).
    """

    def __init__(self, low, high, extra=()):
        super().__init__(nsplits=2, randomize_split=True, live_dangerously=True)
        self.low = np.asarray(low, dtype=float)
        self.high = np.asarray(high, dtype=float)
        self.extra = [np.asarray(d, dtype=float) / np.linalg.norm(d) for d in extra]

    def directions(self, complement):
        """Unit directions: the coordinate axes, ``extra`` and the principal axes of
        ``complement``."""
        ndim = self.low.size
        axes = [np.eye(ndim)] + [d[None, :] for d in self.extra]
        c = np.concatenate(complement, axis=0)
        if len(c) > ndim:
            # in units of the box, so a principal axis is not one coordinate's unit
            scaled = (c - self.low) / (self.high - self.low)
            _, vecs = np.linalg.eigh(np.cov(scaled, rowvar=False))
            vecs = vecs * (self.high - self.low)[:, None]
            axes.append((vecs / np.linalg.norm(vecs, axis=0)).T)
        return np.concatenate(axes, axis=0)

    def get_proposal(self, s, c, random):
        dirs = self.directions(c)
        d = dirs[random.randint(len(dirs), size=len(s))]
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (self.low - s) / d
            b = (self.high - s) / d
        lo = np.where(d != 0, np.minimum(a, b), -np.inf).max(axis=1)
        hi = np.where(d != 0, np.maximum(a, b), np.inf).min(axis=1)
        t = lo + (hi - lo) * random.rand(len(s))
        return s + t[:, None] * d, np.zeros(len(s))


def resonance_direction(names, priors):
    """The direction, in sampling coordinates, that moves the linear block's resonance
    ``wn = sqrt(K3)`` at a fixed damping ratio ``K2 / (2 wn)`` and static gain ``K1 / K3``:
    ``d ln K1 = d ln K3 = 2 d ln wn``, ``d ln K2 = d ln wn`` (docs/models.md#the-linear-block-and-the-papers-a-b-c).
    A cycle far below the resonance does not see it move. ``None`` unless the three are sampled
    in their logarithms."""
    steps = {"gain": 2.0, "damping": 1.0, "stiffness": 2.0}
    if not all(n in names and getattr(priors[n], "log", False) for n in steps):
        return None
    d = np.zeros(len(names))
    for n, v in steps.items():
        d[list(names).index(n)] = v
    return d


#: Share of the steps taken by :class:`PriorChordMove`, of those the Laplace move leaves.
CHORD_SHARE = 0.25
#: Steps between checks of the move's realised acceptance ...
LAPLACE_CHECK_STEPS = 50
#: ... and under which (the fraction of walker-steps that moved) it is switched off.
LAPLACE_MIN_REALISED = 0.15
#: Refits of the proposal after its first when its realised acceptance falls short.
LAPLACE_MAX_REFITS = 3
#: Share of the DE moves when the Laplace independence move is on.
LAPLACE_SHARE_OTHER = 0.1
#: Steps after which the independence proposal is refitted to the chain, once.
LAPLACE_ADAPT_STEPS = 50
#: Expected acceptance of the refitted proposal under which it is switched off.
LAPLACE_MIN_ACCEPTANCE = 0.25
#: Times a switched-off proposal is refitted again, each when the chain has doubled: from step 50,
#: up to 12,800 steps (the chord moves spread the walkers early, so an early refit can fail where
#: a later one serves).
LAPLACE_MAX_RETRIES = 8
#: Acceptance (expected, or realised over the last check) under which a proposal in use is
#: refitted when the chain has doubled since its fit (its first fit rests on 25 steps).
LAPLACE_GOOD_ACCEPTANCE = 0.6


def _move_weights(share):
    """Weights of (DEMove, DESnookerMove, Laplace move, chord move) when the Laplace move takes
    ``share`` of the steps: the chord move takes ``CHORD_SHARE`` of the rest, the DE moves split
    what is left 80/20 as in :func:`.runner.default_moves`."""
    rest = 1.0 - share
    return np.array([0.8 * rest * (1.0 - CHORD_SHARE), 0.2 * rest * (1.0 - CHORD_SHARE), share,
                     rest * CHORD_SHARE])


class LaplaceAdaptation:
    """The Laplace independence move of a calibration's run: built at the start, adapted to the
    chain after each chunk of steps.

    A part of :class:`tvcid.discovery.calibration.calibration.Calibration`: reads its ``moves``,
    ``laplace_`` (mean, covariance in sampling coordinates, the move's share, and the refits'
    record; set at the start, :meth:`.start.StartSearch._start_laplace`, or read from the
    checkpoint), ``seed``, ``n_walkers``, ``log_posterior_`` and ``backend``, and keeps the move
    in ``_laplace_move``.
    """

    def _moves(self):
        """The user's moves; else DE moves and chord moves across the prior
        (:class:`PriorChordMove`), nine in ten of them replaced by independence proposals from the
        Laplace approximation when it is usable (``laplace_``)."""
        self._laplace_move = None
        if self.moves is not None:
            return self.moves
        bounds = np.array([self.priors_[n].internal_bounds for n in self.names_], dtype=float)
        resonance = resonance_direction(self.names_, self.priors_)
        chord = PriorChordMove(bounds[:, 0], bounds[:, 1],
                               extra=() if resonance is None else (resonance,))
        if self.laplace_ is None:
            w = _move_weights(0.0)
            return list(zip((emcee.moves.DEMove(), emcee.moves.DESnookerMove(), chord),
                            w[[0, 1, 3]] / w[[0, 1, 3]].sum()))
        self._laplace_move = LaplaceIndependenceMove(self.laplace_["mean"], self.laplace_["cov"])
        share = float(self.laplace_.get("share", 1.0 - LAPLACE_SHARE_OTHER))
        moves = (emcee.moves.DEMove(), emcee.moves.DESnookerMove(), self._laplace_move, chord)
        return list(zip(moves, _move_weights(share)))

    def _adapt_laplace(self, sampler):
        """At the first chunk end past ``LAPLACE_ADAPT_STEPS``, the independence proposal is
        refitted to the chain (:meth:`_refit_laplace`); after that, every
        ``LAPLACE_CHECK_STEPS``, the walkers' realised acceptance over those steps is read off the
        chain (so a resumed run decides as the uninterrupted one), and under
        ``LAPLACE_MIN_REALISED`` the proposal is refitted again (at most
        ``LAPLACE_MAX_REFITS`` times, then the move is switched off). The trial's importance
        weights only see where the proposal reaches, so a proposal refitted while the walkers
        still spread along a ridge can fall far below its first acceptance. Each
        refit is kept in the checkpoint; the posterior's burn-in covers the last one."""
        move, info = self._laplace_move, self.laplace_
        if move is None:
            return
        it = int(sampler.iteration)
        if info.get("adapted_at") is None:
            if it >= LAPLACE_ADAPT_STEPS:
                self._refit_laplace(sampler, it)
            return
        last = int(info.get("checked_at", info["adapted_at"]))
        if info.get("share", 0.0) <= 0.0:
            # switched off while the walkers were still spreading along a ridge: tried again once
            # the chain has doubled
            retries = int(info.get("retries", 0))
            tried = int(info.get("retried_at", info["adapted_at"]))
            if retries < LAPLACE_MAX_RETRIES and it >= 2 * tried:
                info["retries"] = retries + 1
                self._refit_laplace(sampler, it, retry=True)
            return
        if it < last + LAPLACE_CHECK_STEPS:
            return
        chain = sampler.get_chain(discard=it - LAPLACE_CHECK_STEPS - 1)
        realised = float(np.mean(np.any(np.diff(chain, axis=0) != 0, axis=2)))
        info.update(checked_at=it, realised_acceptance=realised)
        refits = int(info.get("refits", 0))
        mediocre = (min(realised, info.get("expected_acceptance", 1.0)) < LAPLACE_GOOD_ACCEPTANCE
                    and it >= 2 * int(info["adapted_at"]))
        if realised >= LAPLACE_MIN_REALISED and not (mediocre and refits < LAPLACE_MAX_REFITS):
            self._save_laplace()
        elif refits < LAPLACE_MAX_REFITS:
            info["refits"] = int(info.get("refits", 0)) + 1
            self._refit_laplace(sampler, it)
        else:
            info["share"] = 0.0
            sampler._weights = _move_weights(0.0)
            self._save_laplace()

    def _refit_laplace(self, sampler, it, retry=False):
        """The independence proposal recentred on the chain's second half (its mean and
        covariance), which the curvature at the optimum only approximates, then tried:
        ``2 n_walkers`` proposals (a seeded draw, one batch of simulations) give its expected
        acceptance at equilibrium; under
        ``LAPLACE_MIN_ACCEPTANCE`` the move is switched off and the DE moves take every step.

        ``retry``: the move is off and tried again. If it stays off, the chain's moves did not
        change, so neither does the burn-in (``adapted_at``, which the posterior's samples start
        after); the step is kept as ``retried_at``, from which the next retry waits for the chain
        to double. The record is written once, so that a run killed here resumes as it would
        have gone on."""
        move, info = self._laplace_move, self.laplace_
        z = sampler.get_chain(discard=it // 2, flat=True)
        cov = np.cov(z, rowvar=False)
        try:
            move.set_proposal(z.mean(axis=0), cov)
        except np.linalg.LinAlgError:
            info["share"] = 0.0
            if retry:
                info["retried_at"] = it
            sampler._weights = _move_weights(0.0)
            self._save_laplace()
            return
        trial = move.draw(np.random.default_rng([int(self.seed), it]), 2 * self.n_walkers)
        acceptance = move.expected_acceptance(trial, self.log_posterior_(trial))
        share = (1.0 - LAPLACE_SHARE_OTHER) if acceptance >= LAPLACE_MIN_ACCEPTANCE else 0.0
        sampler._weights = _move_weights(share)  # emcee's move weights, in _moves' order
        info.update(mean=z.mean(axis=0).tolist(), cov=np.atleast_2d(cov).tolist(),
                    checked_at=it, expected_acceptance=acceptance, share=share)
        if retry and share <= 0.0:
            info["retried_at"] = it
        else:
            info["adapted_at"] = it
        self._save_laplace()

    def _save_laplace(self):
        """``laplace_`` kept in the checkpoint (when there is one)."""
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(H5_GROUP).attrs["laplace"] = json.dumps(self.laplace_)

