"""discovery.structure.set_weights: the members' weights by their leave-one-out predictive
densities (pseudo-BMA+ on PSIS-LOO), the units an autocorrelated record is left out in, and the
share of the members the cap leaves uncalibrated, read off the ranking.

Members are synthetic Gaussian models of ``N_OBS`` observations (four closed-loop records' five
features): the data are standard normal, a member predicts ``theta + shape`` with unit sd, its
posterior draws ``theta`` around the data's mean less its shape."""
import math

import numpy as np
import pytest
from scipy import integrate, signal, stats

from discovery.structure.ranking_shares import RANKING_RULE, ranking_shares, uncalibrated_share
from discovery.structure.set_weights import (
    EQUAL_RULE,
    MemberPointwise,
    _chain_rule_offsets,
    align_pointwise,
    member_weights,
    weigh_set,
)

N_OBS = 20
N_DRAWS = 400
#: A shape alternating in sign: the location ``theta`` cannot absorb it.
PATTERN = np.where(np.arange(N_OBS) % 2, 1.0, -1.0)


def _pointwise(y, shape, rng, n_draws=N_DRAWS, theta_sd=None):
    """``(n_draws, n)`` log-likelihood draws of the member ``y ~ N(theta + shape, 1)``."""
    n = y.size
    sd = 1 / math.sqrt(n) if theta_sd is None else theta_sd
    theta = (y - shape).mean() + sd * rng.standard_normal(n_draws)
    return stats.norm.logpdf(y[None, :], loc=theta[:, None] + shape[None, :])


def test_a_member_fitting_clearly_worse_gets_a_weight_near_zero():
    """A member whose shape error is 2 sd on every observation (40 nats below the right member
    in expectation) gets under 5 % of the weight in each of 10 noise realisations; the weights
    sum to 1 and the equal-weight alternative is stated beside them."""
    for seed in range(10):
        rng = np.random.default_rng(seed)
        y = rng.standard_normal(N_OBS)
        w = member_weights({"right": _pointwise(y, 0 * PATTERN, rng),
                            "worse": _pointwise(y, 2.0 * PATTERN, rng)}, seed=seed)
        assert w.method == "pseudo-BMA+"
        assert w.weights["worse"] < 0.05, (seed, w.weights)
        assert sum(w.weights.values()) == pytest.approx(1.0)
        assert w.equal == {"right": 0.5, "worse": 0.5} and w.equal_rule == EQUAL_RULE
        d = w.diagnostics["worse"]
        assert d["elpd_diff"] > 10 and d["n_units"] == N_OBS and d["n_draws"] == N_DRAWS


def test_two_members_of_the_same_quality_get_about_half_each():
    """Two copies of the right model, each with its own posterior draws: 0.35-0.65 each in every
    one of 10 realisations. Stacking, returned as the alternative, gives one of them under 0.05
    or over 0.95 in most: the Monte Carlo noise of the draws alone decides it (the module
    docstring's reason for pseudo-BMA+)."""
    extreme = 0
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        y = rng.standard_normal(N_OBS)
        w = member_weights({"a": _pointwise(y, 0 * PATTERN, rng),
                            "b": _pointwise(y, 0 * PATTERN, rng)}, seed=seed)
        assert 0.35 < w.weights["a"] < 0.65, (seed, w.weights)
        assert w.of(["b", "a"]) == [w.weights["b"], w.weights["a"]]
        extreme += not 0.05 < w.stacking["a"] < 0.95
    assert extreme >= 7


def test_unreliable_psis_is_said_and_too_few_units_fall_back_to_equal_weights():
    """Draws far wider than the data allow (posterior sd 5 where 20 observations give 0.22: a
    draw far from an observation has a heavy-tailed importance ratio) give Pareto k above
    arviz's threshold, which the
    diagnostics and notes state; a single unit cannot be left out, so the weights are equal
    and say why; a failed run's draw is dropped and counted."""
    rng = np.random.default_rng(7)
    y = rng.standard_normal(N_OBS)
    narrow = _pointwise(y, 0 * PATTERN, rng, theta_sd=5.0)
    narrow[0, 0] = -np.inf
    w = member_weights({"a": _pointwise(y, 0 * PATTERN, rng), "b": narrow}, seed=1)
    d = w.diagnostics["b"]
    assert d["pareto_k_max"] > d["good_k"] and d["n_bad_k"] > 0 and not d["psis_reliable"]
    assert d["dropped_draws"] == 1 and d["n_draws"] == N_DRAWS - 1
    assert any(n.startswith("b: PSIS unreliable") for n in w.notes)
    assert w.diagnostics["a"]["psis_reliable"]
    one = member_weights({"a": _pointwise(y, 0 * PATTERN, rng), "b": narrow},
                         units=["record"] * N_OBS)
    assert one.method == "equal" and one.weights == {"a": 0.5, "b": 0.5}
    assert any("1 unit(s) to leave out" in n for n in one.notes)


def test_an_autocorrelated_record_is_left_out_in_blocks():
    """An open-loop record whose misfit is AR(1) (correlation 0.97 from sample to sample),
    fitted by two members of equal quality (opposite shape errors): per sample, pseudo-BMA+
    gives one of them under 0.05 or over 0.95 in most of 10 realisations; in
    :func:`align_pointwise`'s blocks (about twice the correlation time of the members'
    pointwise differences, 32 samples), in few. A record the members do not share is left out
    with a note, one whose observations differ in number too, and every draw's total over the
    kept records is unchanged."""
    n, rho, n_draws = 600, 0.97, 200
    t = np.arange(n) / 100.0
    per_sample, blocked, lengths = 0, 0, []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        y = signal.lfilter([math.sqrt(1 - rho * rho)], [1.0, -rho], rng.standard_normal(n))
        members = {}
        for name, sign in (("a", 1.0), ("b", -1.0)):
            ll = _pointwise(y, sign * 0.1 * np.sin(np.pi * t), rng, n_draws)
            members[name] = MemberPointwise(ll, (("sine", "open", n),))
        al = align_pointwise(members)
        lengths.append(al.block["sine"])
        per_sample += _extreme(member_weights({k: m.log_lik for k, m in members.items()},
                                              seed=seed))
        blocked += _extreme(member_weights(al.pointwise, seed=seed))
    assert per_sample >= 7 and blocked <= 4, (per_sample, blocked)
    assert all(15 <= b <= n // 5 for b in lengths), lengths

    rng = np.random.default_rng(9)
    features, sine, extra = (rng.standard_normal((50, k)) for k in (5, 300, 7))
    a = MemberPointwise(np.hstack([features, sine]), (("A", "features", 5), ("sine", "open", 300)))
    b = MemberPointwise(np.hstack([features + 1, extra, sine]),
                        (("A", "features", 5), ("B", "features", 7), ("sine", "open", 300)))
    al = align_pointwise({"a": a, "b": b})
    assert al.units[:5] == [f"A:{j}" for j in range(5)]
    assert [note.split(" ")[0] for note in al.notes] == ["B"]
    assert np.allclose(al.pointwise["a"].sum(axis=1), a.log_lik.sum(axis=1))
    assert np.allclose(al.pointwise["b"].sum(axis=1),
                       b.log_lik[:, :5].sum(axis=1) + b.log_lik[:, 12:].sum(axis=1))
    assert al.pointwise["a"].shape[1] == len(al.units) and 5 < len(al.units) - 5 <= 300
    shorter = MemberPointwise(np.hstack([features, sine[:, :200]]),
                              (("A", "features", 5), ("sine", "open", 200)))
    al = align_pointwise({"a": a, "c": shorter})
    assert al.units == [f"A:{j}" for j in range(5)] and al.notes[0].startswith("sine left out")


def _extreme(weights):
    return not 0.05 < weights.weights["a"] < 0.95


def test_a_whitened_feature_is_the_conditional_density_of_that_feature_given_the_earlier_ones():
    """The likelihood's whitened features (each with a fifth of the log-determinant), given
    their own normalisers, are the chain rule's factors ``log p(r_j | r_1 .. r_(j-1))`` of the
    record's Gaussian, computed here by conditioning: the same data in every member whatever
    its covariance, and the record's total unchanged."""
    rng = np.random.default_rng(5)
    a = rng.standard_normal((5, 5))
    cov = a @ a.T + np.diag([0.5, 2.0, 1e-3, 3.0, 0.1])
    r = rng.multivariate_normal(np.zeros(5), cov)
    chol = np.linalg.cholesky(cov)
    z = np.linalg.solve(chol, r)
    logdet = 2 * np.sum(np.log(np.diag(chol)))
    spread = -0.5 * z**2 - 0.5 * np.log(2 * np.pi) - 0.5 * logdet / 5  # FeatureTerm.loglike's
    conditional = []
    for j in range(5):
        s12 = cov[j, :j]
        gain = np.linalg.solve(cov[:j, :j], s12) if j else np.zeros(0)
        conditional.append(stats.norm.logpdf(r[j], loc=gain @ r[:j],
                                             scale=math.sqrt(cov[j, j] - s12 @ gain)))
    assert np.allclose(spread + _chain_rule_offsets(cov), conditional)
    assert np.sum(spread) == pytest.approx(stats.multivariate_normal.logpdf(r, cov=cov))


def test_the_set_falls_back_to_held_out_scores_where_psis_cannot_weigh():
    """:func:`weigh_set`: two alike members with reliable PSIS are weighed by pseudo-BMA+; one
    with unreliable PSIS (draws far wider than the data allow) sends the set to the held-out
    scores' weights (a member one standard error behind the best: Phi(-1)), and so does a single
    unit to leave out; without scores the weights are equal. Every fallback says why and keeps
    the equal-weight alternative; a record whose features differ between the members is left
    out with a note."""
    rng = np.random.default_rng(11)
    y = rng.standard_normal(N_OBS)
    rows = [{"structure": "a", "score": 2.0, "margin": None},
            {"structure": "b", "score": 2.1, "margin": 0.2}]

    def member(ll, n=N_OBS, features=None):
        return MemberPointwise(ll, (("A", "features", n),), (1.0,),
                               {} if features is None else {"A": features})

    alike = {k: member(_pointwise(y, 0 * PATTERN, rng)) for k in ("a", "b")}
    w = weigh_set(alike, rows, seed=1)
    assert w.method == "pseudo-BMA+" and w.psis_reliable, w.notes
    assert 0.35 < w.weights["a"] < 0.65 and w.diagnostics["a"]["n_units"] == N_OBS

    unreliable = {"a": alike["a"], "b": member(_pointwise(y, 0 * PATTERN, rng, theta_sd=5.0))}
    w = weigh_set(unreliable, rows, seed=1)
    assert w.method == "held-out scores" and w.rule == RANKING_RULE
    assert w.weights["b"] == pytest.approx(stats.norm.cdf(-1.0), abs=0.01)
    assert "PSIS-LOO is unreliable" in w.notes[-1] and w.equal == {"a": 0.5, "b": 0.5}
    assert w.pseudo_bma is not None and w.stacking is not None
    assert weigh_set(unreliable, None).method == "equal"

    one = {k: member(m.log_lik[:, :1], 1) for k, m in alike.items()}
    w = weigh_set(one, rows, seed=1)
    assert w.method == "held-out scores" and "cannot weigh" in w.notes[-1]
    assert any("1 unit(s) to leave out" in n for n in w.notes)

    renamed = {"a": member(alike["a"].log_lik, features=tuple(f"f{j}" for j in range(N_OBS))),
               "b": member(alike["b"].log_lik, features=tuple(f"g{j}" for j in range(N_OBS)))}
    w = weigh_set(renamed, rows, seed=1)
    assert w.notes[0].startswith("A left out of the weights") and w.method == "held-out scores"


def test_the_share_of_uncalibrated_members_follows_their_held_out_scores():
    """A member one standard error (half its margin) behind the best has the probability that
    its expected score is the lower: Phi(-1) = 0.159. With a third member two standard errors
    behind and left uncalibrated, its share is the probability of its being lowest of the three
    (integrated here), named in the report's sentence; a member without a finite score gets 0."""
    two = ranking_shares([{"structure": "best", "score": 2.0, "margin": None},
                          {"structure": "next", "score": 2.1, "margin": 0.2}], seed=1)
    assert two["next"] == pytest.approx(stats.norm.cdf(-1.0), abs=0.01)
    assert sum(two.values()) == pytest.approx(1.0)

    rows = [{"structure": "best", "score": 2.0, "margin": None},
            {"structure": "next", "score": 2.1, "margin": 0.2},
            {"structure": "far", "score": 2.2, "margin": 0.2},
            {"structure": "failed", "score": None, "margin": 0.2}]
    dropped = uncalibrated_share(rows, ["best", "next"], seed=2)
    # far is lowest where D_far < 0 and D_far < D_next: D_far ~ N(0.2, 0.1), D_next ~ N(0.1, 0.1)
    expected, _ = integrate.quad(
        lambda x: stats.norm.pdf(x, 0.2, 0.1) * stats.norm.sf(x, 0.1, 0.1), -1.0, 0.0)
    assert dropped.names == ["far", "failed"]
    assert dropped.shares["failed"] == 0.0
    assert dropped.share == pytest.approx(expected, abs=0.005)
    assert dropped.sentence() == (f"dropped: far, failed (about {100 * dropped.share:.0f} % of "
                                  "the weight by their held-out scores)")
    assert uncalibrated_share(rows[:2], ["best", "next"]).sentence() == ""
