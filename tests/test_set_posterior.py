"""discovery.structure.set_posterior: the linear block's DC gain and bandwidth, the members'
quantities, their equal-weight mixture with the structure-dependence rule, and the range the
recordings allow."""
import numpy as np
import pytest
from scipy import signal

from discovery.structure.set_posterior import (
    STRUCTURE_DEPENDENCE,
    MemberPosterior,
    allowed_range,
    combine,
    linear_block_dc_gain_and_bandwidth,
    member_quantities,
)
from models import M000, M002


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
    threshold is ``z - off``; a member without friction has offset 0."""
    params = M000().to_dict()
    draws = {"dead_zone": np.array([0.008, 0.009]), "delay": np.array([0.001, 0.002])}
    q = member_quantities(params, draws)
    assert np.allclose(q["dead_zone[velocity]"], [0.008, 0.009])
    assert np.allclose(q["threshold"], np.array([0.008, 0.009]) - params["friction_offset"])
    assert np.allclose(q["backlash"], params["backlash"]) and np.allclose(q["delay"], [0.001, 0.002])
    error = member_quantities(M002().to_dict(), {"delay": np.array([0.007])})
    assert "dead_zone[error]" in error and "threshold" not in error


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


def test_the_summary_tells_a_quantity_the_recordings_leave_open_from_a_decided_one():
    """A backlash whose member interval spans most of its prior is printed as not pinned, not as
    decided because the members happen to agree; a dead zone the members agree on is decided
    regardless of the structure; a delay they disagree on depends on it."""
    from tvcid.report import summary_lines

    rng = np.random.default_rng(2)
    a, b = _member("a", 2e-3, 1e-5, rng), _member("b", 3e-3, 1e-5, rng)
    for m, centre in ((a, 0.02), (b, 0.0201)):
        m.quantities["dead_zone[velocity]"] = centre + 1e-3 * rng.standard_normal(4000)
        m.quantities["backlash"] = np.exp(rng.uniform(np.log(1e-6), np.log(1e-4), 4000))
    combined = combine([a, b], seed=1).to_dict()
    combined["members"][0]["posterior"] = {"not_pinned": ["backlash"]}
    combined["members"][1]["posterior"] = {"not_pinned": []}
    rows = [{"structure": s, "indistinguishable_from_best": True, "merged_into": None}
            for s in ("a", "b")]
    lines = summary_lines({"structures": rows, "decided": {}, "set_posterior": combined})
    verdict = {line.split("|")[1].strip(): line.split("|")[5].strip()
               for line in lines if line.startswith("| ") and "quantity" not in line}
    assert verdict == {"delay": "depends on the structure",
                       "backlash": "not pinned by the recordings",
                       "dead_zone[velocity]": "decided regardless of the structure"}, verdict


def _bounded_from_above(rng, n=20000, bound=2e-4, edge=2e-5):
    """Draws of a backlash the recordings bound only from above (log likelihood flat below
    ``bound``, a Gaussian fall of sd ``edge`` above) under a log-uniform prior on [1e-6, 3e-3]:
    exact posterior draws (prior draws kept with the likelihood's probability) and their log
    posterior (prior flat in log)."""
    x = np.exp(rng.uniform(np.log(1e-6), np.log(3e-3), 40 * n))
    loglike = np.where(x > bound, -0.5 * ((x - bound) / edge) ** 2, 0.0)
    kept = x[np.log(rng.uniform(size=x.size)) < loglike][:n]
    return kept, np.where(kept > bound, -0.5 * ((kept - bound) / edge) ** 2, 0.0)


def test_allowed_range_finds_the_bound_the_data_set_where_the_interval_follows_the_prior():
    """A backlash bounded from above at 2e-4 rad under a log-uniform prior from 1e-6 (draw 1000
    of the wide set-coverage benchmark, as a known distribution): the 90 % interval follows the
    prior's mass and its 95th percentile (1.7e-4) falls under a truth of 1.8e-4 just below the
    bound; the allowed range reaches the prior's floor and the bound's 1.92-nat point (2e-4 +
    1.96 sd of the edge = 2.39e-4) within 5 %, and holds the truth (read without the log
    posterior, the range would run to the largest draw, 2.7e-4). On a quantity the data pin (a
    Gaussian), the range is the mean +- 1.96 sd within 1 %."""
    rng = np.random.default_rng(5)
    values, log_prob = _bounded_from_above(rng)
    assert np.quantile(values, 0.95) < 1.8e-4
    low, high = allowed_range(values, log_prob)
    assert low < 1.5e-6 and high == pytest.approx(2.39e-4, rel=0.05) and low < 1.8e-4 < high
    g = 3e-3 + 1e-4 * rng.standard_normal(20000)
    low, high = allowed_range(g, -0.5 * ((g - 3e-3) / 1e-4) ** 2)
    assert low == pytest.approx(3e-3 - 1.96e-4, rel=0.01)
    assert high == pytest.approx(3e-3 + 1.96e-4, rel=0.01)
    assert allowed_range(g[:50], np.zeros(50)) is None  # too few draws to read a profile


def test_combined_quantity_joins_the_members_allowed_ranges_and_the_summary_prints_them():
    """Two members bounding the backlash at 2e-4 and 1e-4 rad: the combined allowed range runs
    from the lower member's floor to the higher's bound; a member without log posteriors adds no
    range. The summary prints the range beside a quantity not pinned."""
    from tvcid.report import summary_lines

    rng = np.random.default_rng(6)
    members = []
    for name, bound in (("a", 2e-4), ("b", 1e-4)):
        values, log_prob = _bounded_from_above(rng, n=8000, bound=bound, edge=0.1 * bound)
        members.append(MemberPosterior(name, {"backlash": values, "delay": np.full(8000, 2e-3)},
                                       {"converged": True}, 0.5, log_prob=log_prob))
    combined = combine(members, seed=1)
    low, high = combined.quantities["backlash"]["allowed"]
    own = [allowed_range(m.quantities["backlash"], m.log_prob) for m in members]
    assert low == min(r[0] for r in own) and high == max(r[1] for r in own)
    assert high == pytest.approx(2.39e-4, rel=0.05)
    bare = combine([MemberPosterior("c", {"backlash": np.full(100, 1e-4)}, {}, 0.0)])
    assert bare.quantities["backlash"]["allowed"] is None
    out = combined.to_dict()
    out["members"][0]["posterior"] = {"not_pinned": ["backlash"]}
    out["members"][1]["posterior"] = {"not_pinned": []}
    rows = [{"structure": s, "indistinguishable_from_best": True, "merged_into": None}
            for s in ("a", "b")]
    lines = summary_lines({"structures": rows, "decided": {}, "set_posterior": out})
    line = next(li for li in lines if li.startswith("| backlash |"))
    assert f"not pinned by the recordings; they allow {low:.4g} to {high:.4g} |" in line, line


def test_the_threshold_is_the_dead_zone_where_no_member_samples_a_friction_offset():
    """Without a friction offset in any member, the velocity form's threshold ``z - off`` is the
    dead zone itself and is printed as not pinned with it; where a member samples the offset,
    the threshold is their combination, which motion can pin while neither part is."""
    from tvcid.report import summary_lines

    rng = np.random.default_rng(7)
    z = np.exp(rng.uniform(np.log(1e-4), np.log(3e-2), 4000))
    member = MemberPosterior("a", {"dead_zone[velocity]": z, "threshold": z}, {"converged": True}, 0.0)
    out = combine([member], seed=1).to_dict()
    rows = [{"structure": "a", "indistinguishable_from_best": True, "merged_into": None}]

    def verdicts(parameters):
        out["members"][0]["posterior"] = {"not_pinned": ["dead_zone"], "parameters": parameters}
        lines = summary_lines({"structures": rows, "decided": {}, "set_posterior": out})
        return {li.split("|")[1].strip(): li.split("|")[5].strip() for li in lines
                if li.startswith("| ") and "quantity" not in li}

    alone = verdicts({"dead_zone": {}, "delay": {}})
    assert alone["threshold"] == alone["dead_zone[velocity]"] == "not pinned by the recordings"
    assert verdicts({"dead_zone": {}, "friction_offset": {}})["threshold"] == ""
