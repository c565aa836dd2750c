"""tvcid.discovery.members.set_weights: the members' weights as their posterior probabilities (each
one's evidence, by importance sampling, at a common temperature), and the share of the members
the cap leaves uncalibrated, read off the ranking.

Members are Gaussian models of ``N_OBS`` observations in one recording: the data ``y`` are
standard normal, a member predicts ``theta + shape`` with unit sd (``theta`` flat on
[-BOX, BOX]); its draws come from its exact posterior, as a converged chain would give them."""
import json
import math

import numpy as np
import pytest
from scipy import integrate, stats

from tvcid.discovery.members.member_evidence import Proposal, importance_draws
from tvcid.discovery.members.ranking_shares import (
    RANKING_RULE,
    ranking_shares,
    uncalibrated_share,
)
from tvcid.discovery.members.set_weights import (
    EVIDENCE_RULE,
    common_temperature,
    evidence_weights,
    unsure_members,
    weighed_choices,
)
from tvcid.discovery.structure.indistinguishable import DECIDING_SHARE

N_OBS = 20
BOX = 5.0
#: A shape alternating in sign: the location ``theta`` cannot absorb it.
PATTERN = np.where(np.arange(N_OBS) % 2, 1.0, -1.0)


def _member(y, shape, rng, inflation=1.0, extra=None):
    """Importance draws of the member ``y ~ N(theta + shape, 1)``; ``extra``: a second parameter
    ``phi`` (flat on [0, 1]) whose log-likelihood ``extra(phi)`` is added (a superset's component)."""
    n = y.size
    centre, sd = (y - shape).mean(), 1 / math.sqrt(n)
    post = centre + sd * rng.standard_normal((300, 1))
    if extra is not None:
        phi = rng.uniform(0, 1, 4000)
        keep = rng.uniform(size=phi.size) < np.exp(extra(phi) - extra(phi).max())
        post = np.column_stack([post[:, 0], rng.choice(phi[keep], 300)])

    def log_prior(z):
        ok = np.abs(z[:, 0]) < BOX
        if extra is not None:
            ok &= (z[:, 1] >= 0) & (z[:, 1] <= 1)
        return np.where(ok, -math.log(2 * BOX), -np.inf)

    def log_lik(z):
        ll = stats.norm.logpdf(y[None, :], loc=z[:, :1] + shape[None, :]).sum(axis=1)
        return (ll + (extra(z[:, 1]) if extra is not None else 0.0))[:, None]

    return importance_draws(Proposal.fit(post, rng=rng), log_prior, log_lik, ["rec"], 600, rng,
                            inflation=[inflation])


def test_a_member_fitting_clearly_worse_gets_a_weight_near_zero_and_is_screened():
    """A member whose shape misses by 2 sd on every observation (about 40 nats below the right
    member's evidence) gets under 1 % of the weight in each of 10 noise realisations, its
    weight's allowance stays under the deciding share (screened), and the rule says what the
    weights are."""
    for seed in range(10):
        rng = np.random.default_rng(seed)
        y = rng.standard_normal(N_OBS)
        w = evidence_weights({"right": _member(y, 0 * PATTERN, rng),
                              "wrong": _member(y, 2.0 * PATTERN, rng)})
        assert w.method == "evidence" and w.rule == EVIDENCE_RULE
        assert w.weights["wrong"] < 0.01 and w.screened() == ["wrong"], (seed, w.weights, w.upper)
        assert w.upper["right"] >= w.weights["right"] > 0.99


def test_two_members_of_the_same_quality_get_about_half_each():
    """Two copies of the right model, each with its own proposal points: weights within 0.4-0.6
    in every one of 10 realisations (the importance noise only), and neither screened."""
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        y = rng.standard_normal(N_OBS)
        w = evidence_weights({"a": _member(y, 0 * PATTERN, rng), "b": _member(y, 0 * PATTERN, rng)})
        assert 0.4 < w.weights["a"] < 0.6 and w.screened() == [], (seed, w.weights)


def test_a_nested_superset_that_fits_as_well_gets_comparable_weight():
    """A superset whose added component the recordings allow over 60 % of its prior (its
    log-likelihood flat there and falling by 50 nats beyond) fits as well as its nested
    member: its evidence is 0.6 of the nested one's, weight 0.6 / 1.6 = 0.375; one the data
    leave free over its whole prior gets half."""
    rng = np.random.default_rng(7)
    y = rng.standard_normal(N_OBS)
    for allowed, want in ((0.6, 0.375), (1.0, 0.5)):
        w = evidence_weights({
            "nested": _member(y, 0 * PATTERN, rng),
            "superset": _member(y, 0 * PATTERN, rng,
                                extra=lambda phi: np.where(phi <= allowed, 0.0, -50.0))})
        assert w.weights["superset"] == pytest.approx(want, abs=0.06), (allowed, w.weights)


def test_the_evidence_is_taken_at_the_smallest_temperature_any_member_needs():
    """A wrong member's chain tempered by 4 (its discrepancy factor) would flatten its misfit
    (40 nats to 10); the weights take both at the right member's factor 1, so the wrong one
    still gets under 1 %. The common temperature is per recording; members holding different recordings are an
    error."""
    rng = np.random.default_rng(11)
    y = rng.standard_normal(N_OBS)
    right = _member(y, 0 * PATTERN, rng)
    wrong = _member(y, 2.0 * PATTERN, rng, inflation=4.0)
    assert common_temperature({"right": right, "wrong": wrong}) == {"rec": 1.0}
    w = evidence_weights({"right": right, "wrong": wrong})
    assert w.weights["wrong"] < 0.01 and w.evidence["wrong"]["temperature"] == [1.0]
    other = _member(y, 0 * PATTERN, rng)
    other = type(other)(("elsewhere",), other.log_prior, other.log_proposal, other.log_lik,
                        other.inflation, other.n_parameters)
    with pytest.raises(ValueError, match="holds recordings"):
        evidence_weights({"right": right, "other": other})


def test_the_held_out_shares_and_equal_weights_are_kept_beside_as_comparisons():
    """With the members' ranking rows, their held-out-score shares are kept (not used), equal
    weights too; one member takes all the weight."""
    rng = np.random.default_rng(12)
    y = rng.standard_normal(N_OBS)
    rows = [{"structure": "a", "score": 2.0, "margin": None},
            {"structure": "b", "score": 2.1, "margin": 0.2}]
    w = evidence_weights({"a": _member(y, 0 * PATTERN, rng), "b": _member(y, 2.0 * PATTERN, rng)},
                         rows=rows, seed=1)
    assert w.held_out["b"] == pytest.approx(stats.norm.cdf(-1.0), abs=0.01)
    assert w.held_out_rule == RANKING_RULE and w.equal == {"a": 0.5, "b": 0.5}
    assert w.weights["b"] < 0.01 < w.held_out["b"]
    d = w.to_dict()
    assert d["method"] == "evidence" and set(d["evidence"]) == {"a", "b"}
    assert DECIDING_SHARE == 0.05
    one = evidence_weights({"a": _member(y, 0 * PATTERN, rng)})
    assert one.weights == {"a": 1.0} and one.method == "single member"


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


def test_an_unreliable_screening_run_screens_its_member_only_far_under_the_share():
    """The set stage's screening: a member under 5 % even at its allowance is screened; one whose
    importance run has Pareto k of 0.7 or more only when its allowance is 20 nats under 5 %; a
    member over the share never."""
    import math

    from tvcid.discovery.members.set_weights import SetWeights
    from tvcid.set_stage import screened_members

    far = 0.05 * math.exp(-20.5)
    weighed = SetWeights({"a": 0.9, "b": 0.01, "c": far / 2, "d": 0.09 - far / 2}, "evidence",
                         "rule", upper={"a": 0.95, "b": 0.02, "c": far, "d": 0.1})
    assert screened_members(weighed) == ["b", "c"]
    assert screened_members(weighed, unsure={"b", "c", "d"}) == ["c"]
    near = SetWeights(weighed.weights, "evidence", "rule",
                      upper={**weighed.upper, "c": 0.05 * math.exp(-19.5)})
    assert screened_members(near, unsure={"c"}) == ["b"]


def _stored_set(members):
    """A ``set_posterior`` as ``discovery.json`` stores it: ``members`` rows of (name, weight,
    upper, converged, screened, evidence reliable)."""
    return {"members": [{"structure": n, "weight": w, "converged": conv,
                         "posterior": {"screened": {"steps": 300}} if scr else {}}
                        for n, w, _, conv, scr, _ in members],
            "weighting": {"method": "evidence",
                          "upper": {n: u for n, _, u, *_ in members},
                          "evidence": {n: {"reliable": rel} for n, *_, rel in members}}}


def test_a_member_whose_weight_is_not_final_is_not_decided_against_unless_far_under_the_share():
    """A member whose chain stopped at its cap, or whose evidence is unreliable, is unsure: the
    data decide against it only 20 nats under the share even at its allowance. A converged
    member with reliable evidence, or one screened by its weight, is decided against under the
    share, whatever its evidence, unless its allowance (the evidence's noise and the step)
    lifts it to the share; no member over it is."""
    import math

    from tvcid.discovery.members.set_weights import decided_against, unsure_members

    far = 0.05 * math.exp(-20.5)
    sp = _stored_set([
        ("best", 0.90, 0.95, True, False, True),
        ("capped", 0.005, 0.026, False, False, True),    # chain stopped at its cap
        ("unreliable", 0.01, 0.02, True, False, False),  # Pareto k >= 0.7 or few points
        ("settled", 0.01, 0.02, True, False, True),
        ("screened", 0.01, 0.02, False, True, False),    # decided by the screening's rule
        ("hopeless", far / 2, far, False, False, False),
        ("rest", 0.075 - far / 2, 0.1, False, False, True),
        ("lifted", 0.01, 0.06, False, True, True),         # screened, its step unresolved
    ])
    unsure = unsure_members(sp)
    assert unsure == ["capped", "unreliable", "rest", "lifted"]
    weights = {m["structure"]: m["weight"] for m in sp["members"]}
    assert decided_against(weights, unsure) == ["settled", "screened", "hopeless"]
    assert decided_against(weights) == ["capped", "unreliable", "settled", "screened", "hopeless",
                                        "lifted"]
    assert decided_against(None, unsure) == []
    assert unsure_members({**sp, "members": sp["members"][:1]}) == []  # a set of one
    assert unsure_members({**sp, "weighting": {"method": "held-out scores"}}) == []


def test_the_weights_are_the_evidences_at_half_the_step_and_the_step_bounds_a_decision():
    """Two members 4.2 nats apart (data at 0; the second's shape misses by 0.65 sd): a change
    of the log evidence that halving the step gives both alike moves no weight. One that raises
    the second by 2 and lowers the first by 1 (their switching events converge differently) puts
    the weights at the half step, 3 nats closer. One that brings them 1.2 nats closer leaves the
    second under the deciding share at half the step, but what half the step still leaves (those
    1.2 nats) lifts its allowance over the share: its weight is not final, and the choice it
    holds stays open where at the step alone the weights decide it. A member without a measured
    change takes the others' median and adds nothing to the allowance."""
    rng = np.random.default_rng(21)
    y = np.zeros(N_OBS)
    draws = {"a": _member(y, 0 * PATTERN, rng), "b": _member(y, 0.65 * PATTERN, rng)}
    plain = evidence_weights(draws)
    gap = plain.evidence["a"]["log_z"] - plain.evidence["b"]["log_z"]
    assert gap == pytest.approx(0.5 * N_OBS * 0.65**2, abs=0.1)
    assert plain.weights["b"] < DECIDING_SHARE
    common = evidence_weights(draws, step_shifts={"a": (1.3, 0.01), "b": (1.3, 0.01)})
    assert common.weights["b"] == pytest.approx(plain.weights["b"], rel=1e-9)
    assert common.upper["b"] == pytest.approx(plain.upper["b"], rel=0.1)
    assert common.upper["b"] < DECIDING_SHARE

    apart = evidence_weights(draws, step_shifts={"a": (-1.0, 0.01), "b": (2.0, 0.01)})
    assert apart.weights["b"] == pytest.approx(1 / (1 + math.exp(gap - 3.0)), rel=0.02)
    assert apart.step_shift["b"] == {"shift": 2.0, "se": 0.01, "measured": True}
    assert apart.upper["b"] > DECIDING_SHARE

    def stored(w):  # converged members with reliable evidence: only the step can make one unsure
        d = w.to_dict()
        d["evidence"] = {n: {**e, "reliable": True} for n, e in d["evidence"].items()}
        return {"members": [{"structure": n, "weight": w.weights[n], "converged": True}
                            for n in w.weights], "weighting": d}

    # b under the share at its step and at half of it, but lifted over it by what is unresolved
    half = evidence_weights(draws, step_shifts={"a": (-0.2, 0.01), "b": (1.0, 0.01)})
    assert half.weights["b"] < DECIDING_SHARE < half.upper["b"]
    names = {"a": "dz_error+delay_before_integrator", "b": "dz_error+delay_before_first_integrator"}
    for w, unsure, by in ((plain, [], "weights"), (half, ["b"], "open")):
        assert unsure_members(stored(w)) == unsure
        choice = weighed_choices({"delay_position": None},
                                 {names[n]: w.weights[n] for n in w.weights}, list(names.values()),
                                 [names[n] for n in unsure])["delay_position"]
        assert choice["by"] == by, (choice, w.weights, w.upper)

    partial = evidence_weights(draws, step_shifts={"a": (0.7, 0.01)})
    assert partial.step_shift["b"] == {"shift": 0.7, "se": 0.0, "measured": False}
    assert partial.weights["b"] == pytest.approx(plain.weights["b"], rel=1e-9)
    assert partial.upper["b"] == pytest.approx(plain.upper["b"], rel=1e-9)


@pytest.mark.slow
def test_on_a_drawn_truth_the_step_not_the_data_separated_two_delay_positions(tmp_path):
    """The set-coverage draw 3009 (``python -m tvcid.studies.benchmarks.set_coverage --seed 3009
    --draws 1``; its truth puts the delay before the first integrator): at the chains' step the
    member with the delay before the second integrator leads by over 3 nats of evidence, and
    halving the step moves the two members' log evidences apart by over 2.5 nats towards the
    truth's. At half the step the truth's member keeps at least the deciding share, the delay's
    position is left open, and the printed delay and bandwidth hold the truth. (Slow: the whole
    discover run, about 8 minutes on 2 cores.)"""
    from tvcid.studies.benchmarks.set_coverage import run_draw

    row = run_draw(3009, tmp_path, quick=False)
    sp = json.loads((tmp_path / "draw3009" / "discover" / "discovery.json").read_text())[
        "set_posterior"]
    w = sp["weighting"]
    truth, other = ("dz_error+delay_before_first_integrator+backlash",
                    "dz_error+delay_before_integrator+backlash")
    assert row["structure"] == truth
    at_step = w["evidence"][other]["log_z"] - w["evidence"][truth]["log_z"]
    moved = w["step_shift"][truth]["shift"] - w["step_shift"][other]["shift"]
    assert at_step > 3.0 and moved > 2.5, (at_step, moved)
    assert w["weights"][truth] >= DECIDING_SHARE
    assert sp["choices"]["delay_position"]["by"] == "open"
    assert row["quantities"]["delay"]["covered"] and row["quantities"]["bandwidth"]["covered"]
