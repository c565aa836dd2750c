"""tvcid.discovery.members.set_posterior: the linear block's DC gain and bandwidth, the members'
quantities, their weighted mixture with the structure-dependence rule, the not-pinned verdict of
every quantity against its prior-implied spread, the range the recordings allow, components the
set leaves open and the step error's widening; and how the report's summary prints them."""
import numpy as np
import pytest
from scipy import signal

from tvcid.discovery.calibration.profile_range import allowed_range
from tvcid.discovery.members.set_posterior import (
    STRUCTURE_DEPENDENCE,
    MemberPosterior,
    combine,
    left_open_quantities,
)
from tvcid.models import M000, M002
from tvcid.models.quantities import linear_block_dc_gain_and_bandwidth, member_quantities


@pytest.mark.parametrize("params", [M000(), M002()])
def test_dc_gain_and_bandwidth_are_those_of_the_position_loop(params):
    """``1/K`` and the -3 dB frequency of ``K1/(s^3 + K2 s^2 + K3 s + K K1)``, checked against
    scipy's frequency response on a fine grid (0.1 % apart at most)."""
    k1, k2, k3, k = params.gain, params.damping, params.stiffness, params.feedback_gain
    dc, bw = linear_block_dc_gain_and_bandwidth(k1, k2, k3, k)
    w = np.logspace(0, 4, 200_000)
    _, h = signal.freqs([k1], [1.0, k2, k3, k * k1], worN=w)
    reference = w[np.argmax(np.abs(h) * k < 1 / np.sqrt(2))]
    assert dc[0] == pytest.approx(1 / k)
    assert bw[0] == pytest.approx(reference, rel=1e-3)


def test_member_quantities_take_draws_and_fill_the_rest_from_the_fit():
    """Sampled fields come from the draws, the others from the fit; the velocity form's
    threshold is ``z - off``; a component's quantity is there only where the member has the
    component."""
    params = M000().to_dict()
    draws = {"dead_zone": np.array([0.008, 0.009]), "delay": np.array([0.001, 0.002])}
    q = member_quantities(params, draws)
    assert np.allclose(q["dead_zone[velocity]"], [0.008, 0.009])
    assert np.allclose(q["threshold"], np.array([0.008, 0.009]) - params["friction_offset"])
    assert np.allclose(q["backlash"], params["backlash"]) and np.allclose(q["delay"], [0.001, 0.002])
    assert np.allclose(q["bandpass_gain"], params["bandpass_gain"])
    error = member_quantities(M002().to_dict(), {"delay": np.array([0.007])})
    assert "dead_zone[error]" in error and "threshold" not in error
    assert "friction_offset" not in error and "bandpass_gain" not in error


def _member(name, centre, sd, rng, n=4000):
    values = centre + sd * rng.standard_normal(n)
    return MemberPosterior(name, {"delay": values, "backlash": np.full(n, 1e-4)}, {"converged": True},
                           0.5)


def test_equal_weights_mix_the_members_and_flag_disagreement():
    """Two members whose delays disagree by many of their own widths: the combined interval
    spans both and the delay depends on the structure; two that agree: decided regardless. The
    mixture's median lies between the members'; each member keeps its own quantiles."""
    rng = np.random.default_rng(0)
    apart = combine([_member("a", 2e-3, 1e-5, rng), _member("b", 3e-3, 1e-5, rng)], seed=1)
    d = apart.quantities["delay"]
    assert d["q05"] < 2.01e-3 and d["q95"] > 2.99e-3 and 2e-3 < d["q50"] < 3e-3
    assert d["depends_on_structure"] and d["spread_over_width"] > 10
    together = combine([_member("a", 2e-3, 1e-4, rng), _member("b", 2.01e-3, 1e-4, rng)], seed=1)
    t = together.quantities["delay"]
    assert not t["depends_on_structure"] and t["spread_over_width"] < STRUCTURE_DEPENDENCE
    assert t["q95"] - t["q05"] == pytest.approx(2 * 1.645e-4, rel=0.1)
    out = apart.to_dict()
    assert [m["weight"] for m in out["members"]] == [0.5, 0.5]
    assert out["members"][0]["quantities"]["delay"]["q50"] == pytest.approx(2e-3, rel=1e-3)
    with pytest.raises(ValueError, match="no member"):
        combine([])


#: M000's bundled cycle A with every choice but the delay's position fixed (its linear block,
#: backlash, friction offset and band-pass loop at the generator's values): one limit cycle does
#: not tell the three delay positions apart.
DELAY_POSITIONS_RUN = [
    "data/m000_closed_A.csv", "--fix", "dead_zone_position=velocity",
    "--fix", "friction_offset=-0.0054", "--fix", "backlash=1.1625e-4", "--fix", "bandpass_gain=72",
    "--fix", "bandpass_saturation=0.01", "--fix", "gain=305494.36", "--fix", "damping=202.1",
    "--fix", "stiffness=14510.9821", "--fix", "feedback_gain=1.0697",
    "--quick", "--seed", "3", "--max-steps", "100", "--no-progress"]


@pytest.mark.slow
def test_members_differing_in_the_delays_position_are_combined_to_cover_each_and_the_truth(tmp_path):
    """``tvcid discover`` on one limit cycle leaves the delay's position open: every member is
    calibrated, the combined 90 % interval of the delay and of the dead zone holds each member's
    median and the truth (1.7 ms, 8.3 mrad/s), the delay is flagged as depending on the
    structure, and the report's summary says so."""
    import json

    from tvcid.cli import main

    assert main(["discover", *DELAY_POSITIONS_RUN, "--out", str(tmp_path)]) == 0
    out = json.loads((tmp_path / "discovery.json").read_text())
    truth = json.loads(open("data/m000_closed_A.json").read())["parameters"]
    members = out["set_posterior"]["members"]
    positions = {m["structure"].split("+")[1] for m in members}
    assert len(positions) >= 2, positions
    combined = out["set_posterior"]["quantities"]
    for name, value in (("delay", truth["delay"]), ("dead_zone[velocity]", truth["dead_zone"])):
        q = combined[name]
        medians = [m["quantities"][name]["q50"] for m in members]
        assert q["q05"] <= min(medians) and max(medians) <= q["q95"], (name, q, medians)
        assert q["q05"] <= value <= q["q95"], (name, q, value)
    assert combined["delay"]["depends_on_structure"]
    summary = (tmp_path / "report.md").read_text().split("## Recordings")[0]
    assert any(line.startswith("| delay |") and "depends on the structure" in line
               for line in summary.splitlines())


def _verdicts(combined, names=("a", "b")):
    """The summary's table as quantity -> (median cell, interval cell, verdict cell)."""
    from tvcid.report import summary_lines

    rows = [{"structure": n, "indistinguishable_from_best": True, "merged_into": None}
            for n in names]
    lines = summary_lines({"structures": rows, "decided": {}, "set_posterior": combined})
    cells = [[c.strip() for c in li.split("|")[1:-1]] for li in lines if li.startswith("| ")]
    return {c[0]: (c[1], c[2], c[4]) for c in cells if len(c) == 5 and c[0] != "quantity"}


def test_every_quantity_is_judged_pinned_against_its_own_prior_implied_spread():
    """A backlash whose draws span its prior is not pinned and prints the range the recordings
    allow; a dead zone the members agree on, narrow against its prior, is decided regardless of
    the structure; a delay they disagree on depends on it. A threshold ``z - off`` that motion
    pins while the dead zone and the offset each span their priors (a ridge) is pinned: the
    composite is judged on its own draws."""
    rng = np.random.default_rng(2)
    n = 4000
    members = []
    for name, delay in (("a", 2e-3), ("b", 3e-3)):
        z = np.exp(rng.uniform(np.log(1e-3), np.log(3e-2), n))
        off = z - 2e-3 - 1e-5 * rng.standard_normal(n)
        quantities = {"delay": delay + 1e-5 * rng.standard_normal(n),
                      "backlash": np.exp(rng.uniform(np.log(1e-6), np.log(1e-4), n)),
                      "dead_zone[velocity]": z, "friction_offset": off, "threshold": z - off,
                      "dc_gain": 0.93 + 1e-4 * rng.standard_normal(n)}
        prior = {"delay": rng.uniform(5e-4, 2e-2, n),
                 "backlash": np.exp(rng.uniform(np.log(1e-6), np.log(3e-3), n)),
                 "dead_zone[velocity]": np.exp(rng.uniform(np.log(1e-3), np.log(3e-2), n)),
                 "friction_offset": rng.uniform(-3e-2, 1e-2, n),
                 "dc_gain": 1 / np.exp(rng.uniform(np.log(0.1), np.log(10), n))}
        prior["threshold"] = prior["dead_zone[velocity]"] - prior["friction_offset"]
        members.append(MemberPosterior(name, quantities, {"converged": True}, 0.5,
                                       log_prob=np.zeros(n), prior_quantities=prior))
    combined = combine(members, seed=1).to_dict()
    q = combined["quantities"]
    assert q["backlash"]["pinned"] is False and q["backlash"]["width_over_prior"] > 0.5
    assert q["dead_zone[velocity]"]["pinned"] is False and q["friction_offset"]["pinned"] is False
    assert q["threshold"]["pinned"] and q["threshold"]["width_over_prior"] < 0.01
    assert q["dc_gain"]["pinned"]
    verdict = {k: v[2] for k, v in _verdicts(combined).items()}
    assert verdict["delay"] == "depends on the structure"
    assert verdict["backlash"].startswith("not pinned by the recordings; they allow")
    assert verdict["threshold"] == verdict["dc_gain"] == "decided regardless of the structure"
    assert verdict["friction_offset"].startswith("not pinned")
    # chains stopped at their cap holding the weight: their agreement is not called decided
    capped = {**combined, "members": [
        {**m, "converged": False, "posterior": {**m["posterior"], "iterations": 2000,
                                                "n_over_tau": 9.5}}
        for m in combined["members"]]}
    verdict = {k: v[2] for k, v in _verdicts(capped).items()}
    assert verdict["threshold"] == ("the members agree, but their chains stopped at the cap: not "
                                    "yet decided")
    assert verdict["delay"] == "depends on the structure"


def test_weights_mix_the_members_by_the_data():
    """A member with weight 0 adds nothing to the combined interval, flags no dependence on the
    structure and widens no allowed range; with equal weights the same pair's interval spans
    both, and the equal-weight mixture is stored beside the weighted one. Weights that are not
    one non-negative number a member are refused."""
    rng = np.random.default_rng(3)
    a, b = _member("a", 2e-3, 1e-5, rng), _member("b", 3e-3, 1e-5, rng)
    weighted = combine([a, b], weights=[1.0, 0.0], seed=1, criterion="stacking").to_dict()
    d = weighted["quantities"]["delay"]
    assert d["q95"] < 2.1e-3 and not d["depends_on_structure"]
    assert d["equal_weights"]["q05"] < 2.01e-3 and d["equal_weights"]["q95"] > 2.99e-3
    assert [m["weight"] for m in weighted["members"]] == [1.0, 0.0]
    assert weighted["criterion"] == "stacking"
    both = combine([a, b], weights=[0.6, 0.4], seed=1).quantities["delay"]
    assert both["q05"] < 2.01e-3 and both["q95"] > 2.99e-3 and both["depends_on_structure"]
    with pytest.raises(ValueError, match="weights must be 2 non-negative"):
        combine([a, b], weights=[1.0, -1.0])


def test_a_component_the_set_leaves_open_prints_as_present_or_absent():
    """Members with and without a backlash: the combined backlash is the one *if present*, its
    share of the weight is stated, and the summary prints "present or absent" with the interval
    if present, never ``0 [0, 0]``, and the range its member allows, pinned or not."""
    rng = np.random.default_rng(4)
    with_it = _member("a", 2e-3, 1e-5, rng)
    with_it.quantities["backlash"] = 1e-4 + 1e-5 * rng.standard_normal(4000)
    without = MemberPosterior("b", {"delay": 2e-3 + 1e-5 * rng.standard_normal(4000)},
                              {"converged": True}, 0.2)
    combined = combine([with_it, without], weights=[0.25, 0.75], seed=1).to_dict()
    q = combined["quantities"]["backlash"]
    assert q["present"] == pytest.approx(0.25) and q["members"] == 1
    assert q["q05"] == pytest.approx(1e-4 - 1.645e-5, rel=0.05)
    median, interval, verdict = _verdicts(combined)["backlash"]
    assert median == "present or absent (25 % of the weight present)"
    assert interval.startswith("if present, [") and "0, 0" not in interval
    with_it.log_prob = -0.5 * ((with_it.quantities["backlash"] - 1e-4) / 1e-5) ** 2
    low, high = combine([with_it, without], weights=[0.25, 0.75], seed=1).quantities["backlash"]["allowed"]
    verdict = _verdicts(combine([with_it, without], weights=[0.25, 0.75], seed=1).to_dict())["backlash"][2]
    assert verdict == f"they allow {low:.4g} to {high:.4g}"


def test_a_component_the_set_leaves_open_prints_as_present_or_absent_whichever_members_calibrated():
    """The set leaves the backlash and the friction offset open, and only a member with a
    backlash calibrated (the others could not start their chains): the backlash, at 100 % of the
    calibrated weight, still prints "present or absent" with its interval if present, and the
    friction offset, which no calibrated member holds, prints "present or absent" without an
    interval instead of vanishing from the table; the backlash shows the range its member allows,
    pinned or not. The backlash the set decides prints as it is."""
    rng = np.random.default_rng(6)
    survivor = _member("a", 2e-3, 1e-5, rng)
    survivor.quantities["backlash"] = 1e-4 + 1e-5 * rng.standard_normal(4000)
    decided = {"backlash": None, "friction": None, "bandpass": False}
    assert left_open_quantities(decided) == ("backlash", "friction_offset")
    combined = combine([survivor], seed=1, left_open=left_open_quantities(decided)).to_dict()
    q = combined["quantities"]["backlash"]
    assert q["present"] == 1.0 and q["left_open"]
    assert combined["left_open_uncalibrated"] == ["friction_offset"]
    cells = _verdicts(combined, ["a"])
    assert cells["backlash"][0].startswith("present or absent")
    assert cells["backlash"][1].startswith("if present, [")
    assert cells["friction_offset"][0].startswith("present or absent") and cells["friction_offset"][1] == ""
    survivor.log_prob = -0.5 * ((survivor.quantities["backlash"] - 1e-4) / 1e-5) ** 2
    combined = combine([survivor], seed=1, left_open=left_open_quantities(decided)).to_dict()
    low, high = combined["quantities"]["backlash"]["allowed"]
    assert _verdicts(combined, ["a"])["backlash"][2].endswith(f"they allow {low:.4g} to {high:.4g}")
    closed = combine([survivor], seed=1).to_dict()
    assert "left_open" not in closed["quantities"]["backlash"]
    assert "they allow" not in _verdicts(closed, ["a"])["backlash"][2]
    assert _verdicts(closed, ["a"])["backlash"][0] == f"{closed['quantities']['backlash']['q50']:.4g}"
    assert "friction_offset" not in _verdicts(closed, ["a"])


def test_an_interval_narrower_than_the_step_error_is_widened_and_says_so():
    """A DC gain whose 90 % interval (3.3e-5 wide) is narrower than twice its step error (5e-5)
    is widened to its median +- the step error and the summary says so; the delay, far wider
    than its step error, is untouched."""
    rng = np.random.default_rng(5)
    m = _member("a", 2e-3, 1e-4, rng)
    m.quantities["dc_gain"] = 0.93 + 1e-5 * rng.standard_normal(4000)
    m.step_error = {"dc_gain": 5e-5, "delay": 1e-6}
    combined = combine([m], seed=1).to_dict()
    dc, delay = combined["quantities"]["dc_gain"], combined["quantities"]["delay"]
    assert dc["widened"] and dc["q95"] - dc["q05"] == pytest.approx(1e-4, rel=0.01)
    assert not delay["widened"] and delay["q95"] - delay["q05"] == pytest.approx(3.29e-4, rel=0.1)
    assert "widened to the step error, +-5e-05" in _verdicts(combined, ["a"])["dc_gain"][2]


def test_each_member_is_widened_by_its_own_step_error_within_the_quantity_s_support():
    """Six members the step resolves (step errors 2e-5 s on delays about 1e-3 s wide) and one
    it does not (8e-3 s), holding 15 % of the weight: the combined delay interval is not the
    seventh member's median +- 8e-3, as widening the mixture by the largest error would make
    it, but the mixture of each member widened by its own; the seventh's own interval is
    widened, to its prior's floor and not below 0; the report names it as not resolved by the
    step and says the members were widened."""
    rng = np.random.default_rng(7)
    members = []
    for k in range(7):
        m = _member(f"m{k}", 5e-3 + 3e-4 * k, 6e-4 if k < 6 else 7e-4, rng)
        m.prior_quantities = {"delay": rng.uniform(6e-4, 0.05, 4000)}
        m.step_error = {"delay": 2e-5 if k < 6 else 8e-3}
        m.summary["step_error"] = {"resolved": k < 6, "residual_sd": 0.1 if k < 6 else 15.7,
                                   "log_prob_sd": 2.0}
        members.append(m)
    weights = [0.85 / 6] * 6 + [0.15]
    combined = combine(members, weights=weights, seed=3).to_dict()
    delay = combined["quantities"]["delay"]
    unwidened = combine(members[:6], seed=3).to_dict()["quantities"]["delay"]
    assert delay["q05"] > 0 and delay["q95"] < members[6].quantities["delay"].mean() + 8e-3
    assert delay["widened"] and delay["step_error_widened"] == 8e-3
    assert delay["step_error"] == pytest.approx(0.85 * 2e-5 + 0.15 * 8e-3)
    width = delay["q95"] - delay["q05"]
    assert unwidened["q95"] - unwidened["q05"] < width < 0.5 * (2 * 8e-3)
    own = combined["members"][6]["quantities"]["delay"]
    assert own["widened"] and own["q05"] == pytest.approx(6e-4, rel=0.05)
    assert "widened" not in combined["members"][0]["quantities"]["delay"]
    verdict = _verdicts(combined, [m.structure for m in members])["delay"][2]
    assert "members widened to their step errors (up to +-0.008)" in verdict
    from tvcid.report import summary_lines

    rows = [{"structure": m.structure, "indistinguishable_from_best": True, "merged_into": None}
            for m in members]
    text = "\n".join(summary_lines({"structures": rows, "decided": {}, "set_posterior": combined}))
    assert "Not resolved by the integration step: `m6` (halving the step changes its log " \
           "posterior by 15.7 nats rms" in text and "`m5`" not in text.split("Not resolved")[1]
    from tvcid.report import member_table_lines

    table = {li.split("|")[1].strip(): li for li in member_table_lines(combined) if "`m" in li}
    assert table["`m6`"].count("(w)") == 1 and "(w)" not in table["`m0`"]


def test_the_richer_structure_of_a_component_left_open_is_calibrated_too():
    """The set's distinct members lack a backlash the set leaves open: the best structure with
    one, merged into a member, joins the calibration; a decided component adds none; one richer
    structure holding two open components serves both."""
    from tvcid.discovery.members.set_posterior import richer_members

    base = "dz_velocity+delay_output"
    rows = [{"structure": base, "indistinguishable_from_best": True, "merged_into": None},
            {"structure": base + "+backlash", "indistinguishable_from_best": True, "merged_into": base},
            {"structure": base + "+friction+backlash", "indistinguishable_from_best": True,
             "merged_into": base},
            {"structure": base + "+bandpass", "indistinguishable_from_best": False, "merged_into": None}]
    assert [r["structure"] for r in richer_members(rows, {"backlash": None, "friction": False})] \
        == [base + "+backlash"]
    assert richer_members(rows, {"backlash": True, "friction": False}) == []
    assert [r["structure"] for r in richer_members(rows, {"backlash": None, "friction": None})] \
        == [base + "+friction+backlash"]


def _bounded_from_above(rng, n=20000, bound=2e-4, edge=2e-5):
    """Draws of a backlash the recordings bound only from above (log likelihood flat below
    ``bound``, a Gaussian fall of sd ``edge`` above) under a log-uniform prior on [1e-6, 3e-3]:
    exact posterior draws (prior draws kept with the likelihood's probability) and their log
    posterior (prior flat in log)."""
    x = np.exp(rng.uniform(np.log(1e-6), np.log(3e-3), 40 * n))
    loglike = np.where(x > bound, -0.5 * ((x - bound) / edge) ** 2, 0.0)
    kept = x[np.log(rng.uniform(size=x.size)) < loglike][:n]
    return kept, np.where(kept > bound, -0.5 * ((kept - bound) / edge) ** 2, 0.0)


def test_combined_quantity_joins_the_members_allowed_ranges_and_the_summary_prints_them():
    """Two members bounding the backlash at 2e-4 and 1e-4 rad under a prior from 1e-6: the
    combined allowed range runs from the prior's floor to the higher member's bound; a member
    without log posteriors adds no range. The summary prints the bound "down to the prior's
    floor"."""
    rng = np.random.default_rng(6)
    members = []
    for name, bound in (("a", 2e-4), ("b", 1e-4)):
        values, log_prob = _bounded_from_above(rng, n=8000, bound=bound, edge=0.1 * bound)
        prior = np.exp(rng.uniform(np.log(1e-6), np.log(3e-3), 8000))
        members.append(MemberPosterior(name, {"backlash": values, "delay": np.full(8000, 2e-3)},
                                       {"converged": True}, 0.5, log_prob=log_prob,
                                       prior_quantities={"backlash": prior}))
    combined = combine(members, seed=1)
    low, high = combined.quantities["backlash"]["allowed"]
    own = [allowed_range(m.quantities["backlash"], m.log_prob) for m in members]
    assert low == min(r.low for r in own) and high == max(r.high for r in own)
    assert high == pytest.approx(2.39e-4, rel=0.05)
    assert combined.quantities["backlash"]["allowed_open"] == [True, False]
    bare = combine([MemberPosterior("c", {"backlash": np.full(100, 1e-4)}, {}, 0.0)])
    assert bare.quantities["backlash"]["allowed"] is None
    verdict = _verdicts(combined.to_dict())["backlash"][2]
    floor = combined.quantities["backlash"]["prior_range"][0]
    assert floor == pytest.approx(prior.min())
    # read from its lower end to its upper end, the prior's end with its value
    assert verdict == (f"not pinned by the recordings; they allow the prior's floor ({floor:.4g}) "
                       f"to {high:.4g}")


def test_an_open_end_short_of_the_prior_is_where_the_draws_end():
    """A backlash bounded at 1e-3 rad whose draws stop at 1e-6 (a chain that has not gone
    lower) while its prior reaches down to 3e-8: the low end is open but not the prior's, and
    the summary says the draws end there instead of naming the prior's floor."""
    rng = np.random.default_rng(8)
    values, log_prob = _bounded_from_above(rng, n=8000, bound=1e-3, edge=1e-4)
    prior = np.exp(rng.uniform(np.log(3e-8), np.log(3e-3), 8000))
    member = MemberPosterior("a", {"backlash": values}, {"converged": True}, 0.0,
                             log_prob=log_prob, prior_quantities={"backlash": prior})
    q = combine([member], seed=1).quantities["backlash"]
    assert q["pinned"] is False
    assert q["allowed_open"] == [True, False] and q["allowed_at_prior"] == [False, False]
    verdict = _verdicts(combine([member], seed=1).to_dict(), ["a"])["backlash"][2]
    assert f"they allow {q['allowed'][0]:.4g} or below (where the draws end) to" in verdict


def test_the_summary_marks_a_chain_stopped_at_its_cap_and_names_prior_bounds_and_dropped_members():
    """A member whose chain stopped at its cap is marked in the summary's table with how far
    its intervals still move; a parameter at its prior's bound is named; members beyond the cap
    are named with their share of the weight."""
    rng = np.random.default_rng(9)
    a, b = _member("a", 2e-3, 1e-4, rng), _member("b", 2e-3, 1e-4, rng)
    b.summary = {"converged": False, "iterations": 2000, "n_over_tau": 14.0,
                 "interval_drift": {"largest": 0.3, "parameter": "delay"},
                 "at_prior_bound": ["backlash"]}
    combined = combine([a, b], weights=[0.7, 0.3], seed=1).to_dict()
    combined["not_calibrated"], combined["not_calibrated_share"] = ["c", "d"], 0.12
    rows = [{"structure": n, "indistinguishable_from_best": True, "merged_into": None}
            for n in ("a", "b", "c", "d")]
    from tvcid.report import summary_lines

    text = "\n".join(summary_lines({"structures": rows, "decided": {}, "set_posterior": combined}))
    assert "| `a` | 0.70 | - | 0.50 | converged |" in text
    assert ("| `b` | 0.30 | - | 0.50 | **stopped at its cap** (2000 steps): its intervals are lower "
            "bounds on the width; its intervals move by up to 30 % of their width") in text
    assert "`b`: backlash." in text and "At a prior bound" in text
    assert "`c`, `d`, about 12 % of the weight by their held-out scores" in text


def test_the_report_lists_pruned_structures_once_per_reason():
    """A reason that prunes several structures is written once, with the structures it prunes."""
    from tvcid.report import _pruned_line

    line = _pruned_line({"a+friction": "friction needs the velocity dead zone",
                         "b+friction": "friction needs the velocity dead zone",
                         "c": "another reason"})
    assert line == ("Pruned structures: `a+friction`, `b+friction`: friction needs the velocity "
                    "dead zone; `c`: another reason")


def test_a_component_the_shared_choices_rule_out_is_said_to_be_decided_by_the_structure():
    """A set whose members all put the dead zone on the error has no friction offset because the
    structure forbids it there (:func:`tvcid.models.structures.prune_reason`), not because the data
    rule it out: the summary says so. A friction offset all members have, and a backlash all
    lack beside a velocity dead zone, are decided plainly."""
    from tvcid.report import summary_lines

    def decided(best, choices):
        rows = [{"structure": best, "indistinguishable_from_best": True, "merged_into": None}]
        lines = summary_lines({"structures": rows, "decided": choices,
                               "set_posterior": combine([_member("a", 2e-3, 1e-4, rng)]).to_dict()})
        return [li for li in lines if li.startswith("Decided:")][0]

    rng = np.random.default_rng(2)

    error = decided("dz_error+delay_output", {"dead_zone_position": "error", "friction": False,
                                              "backlash": False, "delay_position": None})
    assert ("friction offset off (not by the data: friction offset needs the dead zone on the "
            "velocity signal)") in error
    assert "backlash off," in error or "backlash off." in error
    velocity = decided("dz_velocity+delay_output+friction",
                       {"dead_zone_position": "velocity", "friction": True, "backlash": False})
    assert "friction offset on" in velocity and "not by the data" not in velocity


def test_each_calibrated_structure_says_why_it_is_calibrated():
    """Beyond the cap, a member is calibrated for its held-out score or for a component the set
    leaves open that no better member has; the report names both."""
    from tvcid.discovery.members.set_posterior import calibration_reasons
    from tvcid.report import _members_lines

    base = "dz_velocity+delay_output"
    distinct = [{"structure": base}, {"structure": "dz_error+delay_output"},
                {"structure": "dz_velocity+delay_before_integrator"}]
    richer = [{"structure": base + "+backlash", "merged_into": base}]
    why = calibration_reasons(distinct, richer, 2)
    assert list(why) == [base, "dz_error+delay_output", base + "+backlash"]
    assert why[base] == "held-out score 1 of the set's 3 distinct members"
    assert why[base + "+backlash"] == ("the best-scored structure with backlash, which the set "
                                       f"leaves open (merged into `{base}`)")
    text = "\n".join(_members_lines({
        "members": [], "not_calibrated": ["dz_velocity+delay_before_integrator"],
        "not_calibrated_share": 0.04, "calibrated_because": why, "distinct_members": 3}))
    assert ("The recordings leave 3 distinct structures open, more than the cap calibrates; "
            f"calibrated: `{base}` (held-out score 1 of the set's 3 distinct members); ") in text
    assert "about 4 % of the weight" in text
