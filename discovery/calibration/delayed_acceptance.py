"""Delayed acceptance: an emcee move that screens its proposals with a cheap surrogate of the log
posterior before it pays for a simulation.

Each walker's proposal, drawn by an inner emcee move (the differential-evolution, snooker and
stretch moves, or a Metropolis-Hastings move), passes two tests (Christen & Fox 2005, "Markov
chain Monte Carlo using an approximation", J. Comput. Graph. Stat. 14(4), 795-810). The first is
the inner move's own Metropolis-Hastings test with the surrogate in place of the posterior; only
the proposals it keeps are simulated, and the second test accepts them with the ratio of the true
posterior's ratio to the surrogate's. The product of the two acceptance probabilities satisfies
detailed balance with respect to the true posterior, whatever the surrogate, so the chain is
exact: a poor surrogate costs acceptance, never bias. A proposal the surrogate rules out is not
simulated, and the share of simulations saved is about the share of proposals the surrogate
rejects (a correlated 3-d Gaussian sampled with DE moves, which accept 32 % of their proposals:
35 % of the proposals simulated with the target widened 1.2x in variance as surrogate;
``tests/test_delayed_acceptance.py``).

The surrogate's support bounds the chain's: a point where the surrogate is not finite is never
entered, and a walker that starts at one leaves it by the inner move's plain Metropolis-Hastings
step on the true posterior.
"""
from __future__ import annotations

import emcee
import numpy as np
from emcee.state import State

__all__ = ["DelayedAcceptanceMove"]


class DelayedAcceptanceMove(emcee.moves.Move):
    """An emcee move whose proposals are screened by a surrogate before the true log
    probability is computed (delayed acceptance, Christen & Fox 2005).

    The first stage accepts a proposal ``q`` from ``x`` with probability
    ``min(1, exp(f + s(q) - s(x)))``, where ``f`` is the inner move's log proposal ratio and ``s``
    the surrogate; the second, for the first stage's survivors alone, with probability
    ``min(1, exp((p(q) - p(x)) - (s(q) - s(x))))``, where ``p`` is the true log probability.
    The first stage is a Metropolis-Hastings step on the surrogate and the second corrects it, so
    the product of the two satisfies detailed balance with respect to ``exp(p)`` and the chain
    samples the true posterior (Christen & Fox 2005).

    Parameters
    ----------
    inner : emcee.moves.RedBlueMove or emcee.moves.MHMove
        The move that draws the proposals (``DEMove``, ``DESnookerMove``, ``StretchMove``,
        ``GaussianMove``, ...), exactly as it draws them on its own.
    surrogate : callable
        ``surrogate(coords)``, with ``coords`` an array (n, ndim), returns the approximate log
        probability of each row, an array (n,). A value that is not finite at a proposal
        rejects it in the first stage.

    Attributes
    ----------
    n_proposed : int
        Proposals drawn.
    n_screened_out : int
        Proposals rejected in the first stage, which cost no simulation.
    n_evaluated : int
        Proposals whose true log probability is computed.
    n_accepted : int
        Proposals accepted.
    """

    def __init__(self, inner, surrogate):
        if not isinstance(inner, (emcee.moves.RedBlueMove, emcee.moves.MHMove)):
            raise TypeError("the inner move is an emcee RedBlueMove or MHMove, not "
                            f"{type(inner).__name__}")
        self.inner = inner
        self.surrogate = surrogate
        self.reset_counters()

    def reset_counters(self):
        """Sets the four counters to zero."""
        self.n_proposed = 0
        self.n_screened_out = 0
        self.n_evaluated = 0
        self.n_accepted = 0

    @property
    def evaluated_fraction(self) -> float:
        """``n_evaluated / n_proposed``: the share of proposals that cost a simulation."""
        return self.n_evaluated / self.n_proposed if self.n_proposed else float("nan")

    def tune(self, state, accepted):
        """The inner move's tuning."""
        self.inner.tune(state, accepted)

    def propose(self, model, state):
        """Proposals from the inner move, accepted in two stages.

        Parameters
        ----------
        model : emcee.model.Model
            The sampler's model: ``compute_log_prob_fn`` (the true log probability and blobs)
            and ``random`` (the sampler's random state, the only source of random numbers here).
        state : emcee.State
            The walkers' current state; updated in place.

        Returns
        -------
        state : emcee.State
            The new state.
        accepted : ndarray of bool (nwalkers,)
            The walkers that moved.
        """
        if isinstance(self.inner, emcee.moves.RedBlueMove):
            return self._propose_red_blue(model, state)
        return self._propose_mh(model, state)

    def _propose_red_blue(self, model, state):
        # the split and the proposal calls of emcee's RedBlueMove.propose, so that the inner
        # move's proposals are drawn as they are without the surrogate
        inner = self.inner
        nwalkers, ndim = state.coords.shape
        if nwalkers < 2 * ndim and not inner.live_dangerously:
            raise RuntimeError("It is unadvisable to use a red-blue move with fewer walkers than "
                               "twice the number of dimensions.")
        inner.setup(state.coords)
        accepted = np.zeros(nwalkers, dtype=bool)
        inds = np.arange(nwalkers) % inner.nsplits
        if inner.randomize_split:
            model.random.shuffle(inds)
        for split in range(inner.nsplits):
            S1 = inds == split
            # the complement is read after the previous half has moved, as in emcee
            sets = [state.coords[inds == j] for j in range(inner.nsplits)]
            q, factors = inner.get_proposal(sets[split], sets[:split] + sets[split + 1:],
                                            model.random)
            new_state, accepted[S1] = self._two_stages(model, state, S1, q, factors)
            state = self.update(state, new_state, accepted, S1)
        return state, accepted

    def _propose_mh(self, model, state):
        # as emcee's MHMove.propose: one proposal for every walker at once
        inner = self.inner
        nwalkers, ndim = state.coords.shape
        if inner.ndim is not None and inner.ndim != ndim:
            raise ValueError("Dimension mismatch in proposal")
        q, factors = inner.get_proposal(state.coords, model.random)
        everyone = np.ones(nwalkers, dtype=bool)
        new_state, accepted = self._two_stages(model, state, everyone, q, factors)
        state = self.update(state, new_state, accepted)
        return state, accepted

    def _two_stages(self, model, state, subset, q, factors):
        """The proposals ``q`` of the walkers in ``subset``, screened by the surrogate and then
        corrected by the true log probability. Returns the proposals' state (the current log
        probability and blobs where no simulation is run; those walkers do not move) and which
        of them are accepted."""
        x = state.coords[subset]
        n = len(x)
        surr = np.asarray(self.surrogate(np.concatenate([x, q], axis=0)), dtype=float)
        s_x, s_q = surr[:n], surr[n:]
        factors = np.asarray(factors, dtype=float)
        ok_x, ok_q = np.isfinite(s_x), np.isfinite(s_q)
        # where the surrogate is not finite at the current point, every proposal with a finite
        # surrogate passes (the ratio would be infinite, or NaN)
        s_x = np.where(ok_x, s_x, 0.0)
        with np.errstate(invalid="ignore", over="ignore"):
            r1 = np.where(ok_x, factors + s_q - s_x, np.inf)
        survive = ok_q & (np.log(model.random.rand(n)) < r1)

        log_prob = state.log_prob[subset].copy()
        blobs = None
        k = int(survive.sum())
        accepted = np.zeros(n, dtype=bool)
        if k:
            lp_q, new_blobs = model.compute_log_prob_fn(q[survive])
            lp_q = np.asarray(lp_q, dtype=float)
            lp_x = log_prob[survive]
            with np.errstate(invalid="ignore", over="ignore"):
                # the first stage's ratio divided out; with no surrogate at the current point
                # the second stage is the inner move's own test on the true log probability
                r2 = np.where(ok_x[survive], (lp_q - lp_x) - (s_q[survive] - s_x[survive]),
                              factors[survive] + lp_q - lp_x)
            # a ratio of one or more accepts without a draw: with the surrogate equal to the
            # target no draw is made here, and the chain is the inner move's own; NaN (both log
            # probabilities -inf) rejects, as in emcee
            second = r2 >= 0.0
            draw = r2 < 0.0
            second[draw] = np.log(model.random.rand(int(draw.sum()))) < r2[draw]
            accepted[survive] = second
            log_prob[survive] = lp_q
            if new_blobs is not None:
                # the walkers not simulated keep their blobs; update copies accepted rows only
                if state.blobs is not None:
                    blobs = state.blobs[subset].copy()
                else:
                    # a state without blobs: emcee's update raises, as for its own moves
                    blobs = np.zeros((n,) + np.shape(new_blobs)[1:],
                                     dtype=np.asarray(new_blobs).dtype)
                blobs[survive] = new_blobs
        self.n_proposed += n
        self.n_screened_out += n - k
        self.n_evaluated += k
        self.n_accepted += int(accepted.sum())
        return State(q, log_prob=log_prob, blobs=blobs), accepted
