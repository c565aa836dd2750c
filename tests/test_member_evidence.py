"""tvcid.discovery.members.member_evidence: a member's evidence by importance sampling from its draws,
checked on known curved distributions in 9 dimensions (a banana and a ring) whose normalising
constants are known, and against the chain-length draws a member gives it."""
import math

import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

from tvcid.discovery.calibration.importance import GOOD_K
from tvcid.discovery.members.member_evidence import (
    ImportanceDraws,
    Proposal,
    importance_draws,
    log_evidence,
)

DIM = 9
#: The prior: flat on a box wide enough to hold every distribution below.
BOX = 30.0
LOG_PRIOR = -DIM * math.log(2 * BOX)


def _log_prior(z):
    return np.where(np.all(np.abs(z) < BOX, axis=1), LOG_PRIOR, -np.inf)


def _banana(b):
    """A twisted Gaussian (Haario et al. 1999): ``y2 = x2 + b (x1^2 - s1^2)``, sd 3 along x1;
    the map has Jacobian 1, so the density integrates to 1."""
    s = np.ones(DIM)
    s[0] = 3.0

    def draws(rng, n):
        x = rng.standard_normal((n, DIM)) * s
        x[:, 1] -= b * (x[:, 0] ** 2 - s[0] ** 2)
        return x

    def log_lik(z):
        x = z.copy()
        x[:, 1] += b * (z[:, 0] ** 2 - s[0] ** 2)
        return stats.norm.logpdf(x, scale=s).sum(axis=1)[:, None]

    return draws, log_lik


def _ring(radius=5.0, width=0.4):
    """A ring of ``radius`` and radial sd ``width`` in the first two coordinates, standard normal
    in the rest: ``exp(-(r - R)^2 / (2 w^2))`` normalised in closed form."""
    log_norm = math.log(2 * math.pi * (width ** 2 * math.exp(-radius ** 2 / (2 * width ** 2))
                                        + radius * width * math.sqrt(2 * math.pi)
                                        * stats.norm.cdf(radius / width)))

    def draws(rng, n):
        r = np.empty(0)
        while r.size < n:  # the radius's density is proportional to r exp(-(r - R)^2 / 2w^2)
            c = radius + width * rng.standard_normal(4 * n)
            c = c[(c > 0) & (rng.uniform(size=c.size) < c / (radius + 6 * width))]
            r = np.concatenate([r, c])
        phi = rng.uniform(0, 2 * math.pi, n)
        x = rng.standard_normal((n, DIM))
        x[:, 0], x[:, 1] = r[:n] * np.cos(phi), r[:n] * np.sin(phi)
        return x

    def log_lik(z):
        r = np.hypot(z[:, 0], z[:, 1])
        return (-(r - radius) ** 2 / (2 * width ** 2) - log_norm
                + stats.norm.logpdf(z[:, 2:]).sum(axis=1))[:, None]

    return draws, log_lik


@pytest.mark.parametrize("name, target", [("gaussian", _banana(0.0)), ("banana", _banana(0.3)),
                                          ("ring", _ring())])
def test_the_evidence_of_known_curved_distributions_in_nine_dimensions(name, target):
    """Each density integrates to 1 inside the prior's box, so ``log Z`` is the prior's log
    density. From 300 of its draws (a member's chain gives a few hundred) and 600 proposal
    points, over 5 seeds: the estimate within 3 of its standard errors (and 0.25) of the truth
    every time, its Pareto k under 0.7 on the Gaussian and the banana, and the standard error
    honest (the estimates' scatter within twice the mean stated error)."""
    draws, log_lik = target
    estimates, errors = [], []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        proposal = Proposal.fit(draws(rng, 300), rng=rng)
        ev = log_evidence(importance_draws(proposal, _log_prior, log_lik, ["r"], 600, rng))
        assert abs(ev.log_z - LOG_PRIOR) < max(3 * ev.se, 0.25), (name, seed, ev)
        if name != "ring":
            assert ev.reliable and ev.pareto_k < GOOD_K, (name, seed, ev)
        estimates.append(ev.log_z)
        errors.append(ev.se)
    assert np.std(estimates) < 2 * np.mean(errors) + 0.02, (name, estimates, errors)


def test_the_proposal_density_is_a_density_and_its_samples_follow_it():
    """The mixture's density integrates to 1 (one dimension, by quadrature), and in two
    dimensions its samples fall in a square as often as its density there says."""
    from scipy import integrate

    rng = np.random.default_rng(3)
    one = Proposal.fit(rng.standard_normal((150, 1)) * 2.0 + 1.0, rng=rng)
    total, _ = integrate.quad(lambda x: float(np.exp(one.log_density([[x]]))[0]), -np.inf, np.inf,
                              limit=200)
    assert total == pytest.approx(1.0, abs=1e-4)
    draws, _ = _banana(0.2)
    two = Proposal.fit(draws(rng, 150)[:, :2], rng=rng)
    s = two.sample(rng, 20000)
    inside = np.mean((np.abs(s[:, 0]) < 2) & (np.abs(s[:, 1]) < 2))
    g = np.linspace(-2, 2, 81)
    xx, yy = np.meshgrid(0.5 * (g[1:] + g[:-1]), 0.5 * (g[1:] + g[:-1]))
    mass = np.exp(two.log_density(np.column_stack([xx.ravel(), yy.ravel()]))).sum() * (g[1] - g[0]) ** 2
    assert inside == pytest.approx(mass, abs=0.01)


def test_temperatures_divide_each_recordings_log_likelihood():
    """``log_evidence`` at temperature ``T`` of a Gaussian likelihood ``N(0, 1)`` per recording
    is that of ``exp(log L / T)``: ``log Z = 0.5 log(2 pi T) - log(2 pi) / (2 T)`` per dimension,
    times the prior's density; a wrong number of temperatures is one line."""
    rng = np.random.default_rng(4)
    proposal = Proposal.fit(rng.standard_normal((300, 1)) * 2.0, rng=rng)

    def log_lik(z):
        ll = stats.norm.logpdf(z[:, 0])
        return np.column_stack([ll, ll])

    draws = importance_draws(proposal, lambda z: np.where(np.abs(z[:, 0]) < BOX,
                                                          -math.log(2 * BOX), -np.inf),
                             log_lik, ["a", "b"], 2000, rng)
    for t in (1.0, 2.0):
        want = -math.log(2 * BOX) + 0.5 * math.log(2 * math.pi * t / 2) - math.log(2 * math.pi) / t
        assert log_evidence(draws, [t, t]).log_z == pytest.approx(want, abs=0.05)
    with pytest.raises(ValueError, match="one positive value each"):
        log_evidence(draws, [1.0])


def test_failed_runs_count_as_zero_likelihood_and_the_draws_round_trip_through_json():
    """Points whose run failed (-inf) weigh 0; none finite gives ``log Z = -inf`` and an
    unreliable estimate; ``to_dict`` / ``from_dict`` keep every number (``-inf`` as ``None`` in
    strict JSON)."""
    rng = np.random.default_rng(5)
    proposal = Proposal.fit(rng.standard_normal((100, 2)), rng=rng)
    draws = importance_draws(proposal, lambda z: np.zeros(len(z)),
                             lambda z: np.where(z[:, :1] > 0, -1.0, -np.inf), ["r"], 400, rng)
    ev = log_evidence(draws)
    finite = np.isfinite(draws.log_lik[:, 0])
    want = logsumexp(-1.0 - draws.log_proposal[finite]) - math.log(400)
    assert ev.log_z == pytest.approx(want)
    none = ImportanceDraws(("r",), np.zeros(3), np.zeros(3), np.full((3, 1), -np.inf), (1.0,), 2)
    assert log_evidence(none).log_z == -math.inf and not log_evidence(none).reliable
    d = draws.to_dict()
    d["log_lik"] = [[None if not math.isfinite(v) else v for v in row] for row in d["log_lik"]]
    back = ImportanceDraws.from_dict(d)
    assert np.array_equal(back.log_lik, draws.log_lik) and back.records == ("r",)


def test_a_second_round_keeps_the_estimate_exact_and_moves_towards_mass_the_chain_missed():
    """The second round's points, each at its own proposal's density, keep ``log Z`` exact in
    expectation: on a chain that covers the banana, within three standard errors of the
    truth over 5 seeds. On a chain that saw one end of a ridge only (the draws with x1 < -3 of a
    Gaussian of sd 3 along x1), the first round misses about a third of the mass (log Z 0.8-1.1
    low) and the second recovers part of it in each of 4 seeds, while its Pareto k says the
    estimate is not to be trusted: a chain that misses mass is not repaired by importance
    sampling."""
    from tvcid.discovery.members.member_evidence import _second_round

    draws, log_lik = _banana(0.3)
    for seed in range(5):
        rng = np.random.default_rng(seed)
        chain = draws(rng, 300)
        proposal = Proposal.fit(chain, rng=rng)
        first = importance_draws(proposal, _log_prior, log_lik, ["r"], 400, rng)
        both = _second_round(first, chain, None, _log_prior, log_lik, 400, rng)
        ev = log_evidence(both)
        assert both.log_lik.shape == (800, 1)
        assert abs(ev.log_z - LOG_PRIOR) < max(3 * ev.se, 0.2), (seed, ev)
    draws, log_lik = _banana(0.0)
    for seed in range(4):
        rng = np.random.default_rng(seed)
        chain = draws(rng, 20000)
        chain = chain[chain[:, 0] < -3.0][:300]
        proposal = Proposal.fit(chain, rng=rng)
        first = importance_draws(proposal, _log_prior, log_lik, ["r"], 400, rng)
        both = log_evidence(_second_round(first, chain, None, _log_prior, log_lik,
                                          400, rng))
        missed = LOG_PRIOR - log_evidence(first).log_z
        assert 0.5 < missed and LOG_PRIOR - both.log_z < missed, (seed, missed, both)
        assert not both.reliable, (seed, both)
