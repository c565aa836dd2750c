"""Which test tells structures apart (tvcid.discovery.prediction.discrimination)."""
import numpy as np
import pytest

from tvcid.discovery.prediction.design import Candidate
from tvcid.discovery.prediction.discrimination import (
    DECIDES,
    default_candidates,
    design_over_set,
    discriminating_tests,
    set_design_order,
)
from tvcid.models import M002, M001i
from tvcid.models.experiments import CONTROLLER_A, OpenLoop

MENU = [Candidate("sine 10 mrad 1 Hz", OpenLoop.sine(10e-3, 1.0), 6.0),
        Candidate("square 20 mrad 4 Hz", OpenLoop.square(20e-3, 4.0), 6.0),
        Candidate("controller A", CONTROLLER_A, 12.0)]


def test_different_actuators_are_told_apart_and_the_matrix_is_a_distance():
    """Paper 002's actuator (dead zone on the error, 7 ms at the output, a 30 Hz block) against
    paper 001's (dead zone on the velocity signal, 5.6 ms, a 19 Hz block): every test decides the
    pair (their cycles differ by 12 %, their responses by far more than the noise of 2e-5 rad)."""
    r = discriminating_tests([M002(), M001i()], MENU, noise_sd=2e-5, seed=1)
    assert r.members == ("dz_error+delay_output+backlash", "dz_velocity+delay_output+backlash")
    assert r.n_pairs == 1 and len(r.tests) == 3
    for t in r.tests:
        assert "skipped" not in t, t
        sep = np.array(t["separation"])
        assert sep.shape == (2, 2) and np.allclose(sep, sep.T) and np.allclose(np.diag(sep), 0)
        assert t["pairs_decided"] == 1 and t["closest_separation"] >= DECIDES and not t["undecided"]
    seps = [t["closest_separation"] for t in r.tests]
    assert seps == sorted(seps, reverse=True)
    assert r.best is r.tests[0] and r.to_dict()["best"]["name"] == r.tests[0]["name"]


def test_a_backlash_of_ten_nanoradians_cannot_be_told_from_none():
    """Paper 001's actuator with a backlash of 1e-8 rad against the same without one (the
    negative control): no test of the menu separates them at 2e-5 rad of noise."""
    a = M001i().replace(backlash=1e-8)
    b = a.replace(backlash=0.0)
    r = discriminating_tests([a, b], MENU, noise_sd=2e-5, seed=2)
    assert all(t["pairs_decided"] == 0 and t["closest_separation"] < DECIDES for t in r.tests)
    assert r.tests[0]["undecided"] == [list(r.members)]
    ax = r.plot()
    assert len(ax.patches) == 3


def test_refitted_members_are_weighed_on_the_best_candidates_only(tmp_path):
    """With the recordings the members were fitted to (a limit cycle of paper 002's actuator at
    controller A), the best candidate at fixed parameters is weighed again with each member
    refitted to that cycle and the other's record of the test: a refit starts from the fixed
    comparison and only lowers it (within the two records' noise), and the other candidates
    keep their fixed verdicts."""
    from tvcid.discovery.structure.targets import make_target
    from tvcid.models.synthetic import synthetic_recording

    rec = synthetic_recording(M002(), CONTROLLER_A, 30.0, 2e-5, 4, tmp_path / "cycle.csv",
                              keep_last=20.0)
    r = discriminating_tests([M002(), M001i()], MENU, noise_sd=2e-5, seed=1,
                             recorded=[make_target(rec, 5e-4)], n_refit=1)
    refitted = [t for t in r.tests if t["refitted"]]
    assert len(refitted) == 1 and r.best is refitted[0]
    for t in r.tests:
        sep, fixed = np.array(t["separation"]), np.array(t["separation_fixed"])
        assert np.allclose(sep, sep.T) and np.all(sep <= 1.1 * fixed + 0.05), (sep, fixed)
        if not t["refitted"]:
            assert np.array_equal(sep, fixed)
    # its cost: at least every candidate's record, each run at the discovery's 5e-4 s or finer
    assert r.simulated_seconds >= sum(c.duration for c in MENU)
    assert r.simulated_steps >= r.simulated_seconds / 5e-4


def test_bad_requests_are_refused():
    with pytest.raises(ValueError, match="at least two"):
        discriminating_tests([M002()], MENU)
    with pytest.raises(ValueError, match="share a structure"):
        discriminating_tests([M002(), M002().replace(dead_zone=2e-3)], MENU)
    with pytest.raises(ValueError, match="noise_sd"):
        discriminating_tests([M002(), M001i()], MENU, noise_sd=0.0)


def test_default_menu_spans_slow_and_fast_tests_and_both_controllers():
    menu = default_candidates(sample_rate=200.0)
    assert len(menu) == 32 and len({c.name for c in menu}) == 32
    assert {c.kind for c in menu} == {"open", "closed"}
    assert all(c.sample_rate == 200.0 for c in menu)
    freqs = {c.experiment.frequency for c in menu if c.kind == "open"}
    assert min(freqs) == 0.5 and max(freqs) == 8.0


def test_discover_names_the_test_that_would_decide_its_set(tmp_path):
    """``tvcid discover``'s ``next_test`` on a set of two (paper 002's and paper 001's actuators,
    as a ranking would list them, with the last 10 s of the bundled M000 cycle A as the
    recording: the refits simulate the record's length): the unmerged members are weighed on the
    default menu at the recordings' rate and median noise, and the report gives the best test
    and its verdict with the figure; a set of one gives ``None`` and no section."""
    from tvcid.models import M002, M001i
    from tvcid.models.recording import load_recording, save_recording
    from tvcid.pipeline import next_test
    from tvcid.run_record import RunRecord
    from tvcid.report import _next_test_lines

    def entry(params, inside=True, merged=None):
        return {"params": params.to_dict(), "indistinguishable_from_best": inside,
                "merged_into": merged}

    structures = [entry(M002()), entry(M001i()), entry(M002().replace(backlash=0.0), True, "x"),
                  entry(M001i().replace(dead_zone=0.02), False)]
    summary = {"structures": structures, "sensor_noise": {"a": 2e-5, "b": "nan", "c": 4e-5}}
    cycle = load_recording("data/m000_closed_A.csv")
    keep = cycle.columns["t"] >= cycle.columns["t"][-1] - 10.0
    tail = {k: v[keep] - v[keep][0] if k == "t" else v[keep] for k, v in cycle.columns.items()}
    recs = [load_recording(save_recording(tmp_path / "cycle_A_tail.csv", tail, cycle.meta))]
    nt = next_test(RunRecord.from_dict(summary), recs, 0, tmp_path)
    assert nt["members"] == ["dz_error+delay_output+backlash", "dz_velocity+delay_output+backlash"]
    assert nt["noise_sd"] == pytest.approx(3e-5) and nt["n_pairs"] == 1
    # the best candidates were weighed with the members refitted to the recording (neither was
    # fitted to it, so a refit can only bring them closer than at fixed parameters)
    best = nt["best"]
    assert best["refitted"] and best["pairs_decided"] <= best["pairs_decided_fixed"] == 1
    assert len(nt["tests"]) == 8 and sum(t["refitted"] for t in nt["tests"]) == 3
    assert (tmp_path / "next_test.png").exists()
    text = "\n".join(_next_test_lines(nt))
    assert "## A test that would decide" in text and best["name"] in text
    assert ("No candidate decides any pair" in text) == (best["pairs_decided"] == 0)
    assert next_test(RunRecord(structures[:1]), recs, 0, tmp_path) is None
    assert _next_test_lines(None) == []


def test_the_next_test_leaves_out_the_members_the_weights_decided_against(tmp_path):
    """A member under 5 % of the set's weight is left out of the next test (named with its
    weight); with one member left there is nothing to split and the summary says so, with no
    section of candidates."""
    from tvcid.models import M002, M001i
    from tvcid.pipeline import next_test
    from tvcid.run_record import RunRecord
    from tvcid.report import _next_test_headline, _next_test_lines

    rows = [{"structure": n, "params": p.to_dict(), "indistinguishable_from_best": True,
             "merged_into": None} for n, p in (("a", M002()), ("b", M001i()))]
    summary = {"structures": rows, "sensor_noise": {},
               "set_posterior": {"members": [{"structure": "a", "weight": 0.97},
                                             {"structure": "b", "weight": 0.03}]}}
    nt = next_test(RunRecord.from_dict(summary), [], 0, tmp_path)
    assert nt["left_out"] == [{"structure": "b", "weight": 0.03}] and nt["members"] == ["a"]
    assert _next_test_headline(nt, 2) == ("Next test: none needed: the weights leave one "
                                          "structure, `a` (the others hold under 5 % of the "
                                          "weight).")
    assert _next_test_lines(nt) == []


def test_the_next_test_keeps_a_member_under_the_share_whose_weight_is_not_final(tmp_path,
                                                                                 monkeypatch):
    """A member under 5 % whose chain stopped at its cap (``set_posterior.unsure``) is not left
    out: the candidates are ranked on both members."""
    from types import SimpleNamespace

    import tvcid.discovery.prediction.discrimination as discrimination
    import tvcid.discovery.structure.targets as targets
    from tvcid.models import M002, M001i
    from tvcid.pipeline import next_test
    from tvcid.run_record import RunRecord

    ranked = []

    class Stop(Exception):
        pass

    def discriminating_tests(members, *args, **kwargs):
        ranked.append(len(members))
        raise Stop

    monkeypatch.setattr(discrimination, "discriminating_tests", discriminating_tests)
    monkeypatch.setattr(targets, "make_target", lambda rec, dt: None)
    rows = [{"structure": n, "params": p.to_dict(), "indistinguishable_from_best": True,
             "merged_into": None} for n, p in (("a", M002()), ("b", M001i()))]
    summary = {"structures": rows, "sensor_noise": {},
               "set_posterior": {"members": [{"structure": "a", "weight": 0.995},
                                             {"structure": "b", "weight": 0.005}],
                                 "unsure": ["b"]}}
    with pytest.raises(Stop):
        next_test(RunRecord.from_dict(summary), [SimpleNamespace(sample_rate=1000.0)], 0,
                  tmp_path)
    assert ranked == [2]


def test_a_merged_members_weight_counts_for_the_structure_it_is_merged_into(tmp_path):
    """A superset merged into a member of the set can carry the weight its posterior earns; the
    next test counts it for the structure it is merged into: that one is kept, the rest (under
    5 %) left out, and the summary names it."""
    from tvcid.models import M002, M001i
    from tvcid.pipeline import next_test
    from tvcid.run_record import RunRecord
    from tvcid.report import _next_test_headline

    rows = [{"structure": n, "params": p.to_dict(), "indistinguishable_from_best": True,
             "merged_into": into} for n, p, into in (("a", M002(), None), ("b", M001i(), None),
                                                     ("a+x", M002(), "a"))]
    summary = {"structures": rows, "sensor_noise": {},
               "set_posterior": {"members": [{"structure": "a", "weight": 1e-9},
                                             {"structure": "b", "weight": 1e-6},
                                             {"structure": "a+x", "weight": 1.0 - 1e-6}]}}
    nt = next_test(RunRecord.from_dict(summary), [], 0, tmp_path)
    assert nt["members"] == ["a"] and [x["structure"] for x in nt["left_out"]] == ["b"]
    assert "`a`" in _next_test_headline(nt, 2)


def _dead_zone_draws(base, n=8, seed=0):
    """Draws of ``base`` with its dead zone spread by 5 % (the one sampled parameter)."""
    from tvcid.discovery.calibration.priors import LogUniform
    from tvcid.discovery.prediction.draws import PosteriorDraws

    z = base.dead_zone * np.exp(0.05 * np.random.default_rng(seed).standard_normal(n))
    return PosteriorDraws(names=("dead_zone",), samples=z[:, None], internal=np.log(z)[:, None],
                          base=base, priors={"dead_zone": LogUniform(1e-5, 0.1)}, config={})


def test_design_over_a_set_puts_the_test_that_tells_its_members_apart_first():
    """Two members that differ in where the delay acts (paper 002's actuator): a 20 mrad square
    tells them apart, a 0.5 mrad sine inside the dead zone moves neither. Each member ranks both
    tests with its own draws; the means and each member's gain are reported."""
    a = M002()
    b = a.replace(delay_position="before_integrator")
    members = {"output": _dead_zone_draws(a), "before_integrator": _dead_zone_draws(b, seed=1)}
    menu = [Candidate("sine 0.5 mrad 1 Hz", OpenLoop.sine(0.5e-3, 1.0), 4.0),
            Candidate("square 20 mrad 2 Hz", OpenLoop.square(20e-3, 2.0), 4.0)]
    ranking = design_over_set(members, menu, noise=2e-5, seed=1, n_truths=4)
    assert [r["name"] for r in ranking.rows] == ["square 20 mrad 2 Hz", "sine 0.5 mrad 1 Hz"]
    square, sine = ranking.rows
    assert (square["pairs_decided"], sine["pairs_decided"], square["n_pairs"]) == (1, 0, 1)
    assert set(square["members"]) == {"output", "before_integrator"}
    gains = [m["information_gain"] for m in square["members"].values()]
    assert square["information_gain"] == pytest.approx(np.mean(gains))
    assert ranking.params == ("dead_zone",) and "told apart" in ranking.to_dict()["criterion"]
    with pytest.raises(ValueError, match="at least two members"):
        design_over_set({"output": members["output"]}, menu, noise=2e-5)
    with pytest.raises(ValueError, match="not sampled by every member"):
        design_over_set(members, menu, params=["delay"], noise=2e-5)


def test_set_design_order_tells_apart_first_then_gains():
    rows = [{"name": "teaches", "pairs_decided": 0, "information_gain": 5.0},
            {"name": "decides", "pairs_decided": 2, "information_gain": 0.1},
            {"name": "decides less", "pairs_decided": 1, "information_gain": 9.0},
            {"name": "decides, teaches", "pairs_decided": 2, "information_gain": 1.0}]
    assert [r["name"] for r in set_design_order(rows)] == [
        "decides, teaches", "decides", "decides less", "teaches"]


def test_report_says_which_members_chains_did_not_converge():
    from tvcid.report import _convergence_line

    done = {"structure": "a", "converged": True, "posterior": {"iterations": 400, "n_over_tau": 55.0}}
    late = {"structure": "b", "converged": False, "posterior": {"iterations": 2000, "n_over_tau": 9.5}}
    assert _convergence_line([done]).startswith("Every calibrated structure's posterior converged")
    line = _convergence_line([done, late])
    assert line.startswith("**Not converged**: `b` (2000 steps, 9.5 autocorrelation times)")
    assert "`a`" not in line
    off = {**late, "posterior": {**late["posterior"], "laplace_move": {"share": 0.0}}}
    assert "(2000 steps, 9.5 autocorrelation times; without the Laplace move" in (
        _convergence_line([off]))
    drifting = {**late, "posterior": {**late["posterior"],
                                      "interval_drift": {"largest": 0.42, "parameter": "delay"}}}
    assert ("9.5 autocorrelation times; its 90 % intervals differ between the chain's two halves "
            "by up to 42 % of their width (`delay`))") in _convergence_line([drifting])


def test_an_importance_or_nested_sampled_member_is_named_with_its_diagnostic():
    from tvcid.report import _chain_cell

    drawn = {"structure": "a", "converged": True, "posterior": {
        "sampler": "importance", "iterations": 1200, "rounds": 3, "n_over_tau": 394.2,
        "pareto_k": -0.11}}
    assert _chain_cell(drawn) == ("importance sampled: 1200 points in 3 rounds, 394 effective, "
                                  "Pareto k -0.11")
    assert _chain_cell({**drawn, "posterior": {"iterations": 400}}) == "converged"
    nested = {**drawn, "posterior": {"sampler": "nested", "iterations": 5120, "n_over_tau": 640.4,
                                     "pareto_k": 0.31, "log_z": -12.345, "log_z_se": 0.021}}
    assert _chain_cell(nested) == ("nested sampled: 5120 points, 640 effective, Pareto k 0.31, "
                                   "log evidence -12.35 ± 0.02")


def test_a_screened_member_says_what_its_short_run_was():
    """A member the weights screened after its importance rounds names its points; one screened
    after its chain's steps names the steps."""
    from tvcid.report import _chain_cell

    screened = {"share": 0.05, "steps": 300, "upper_weight": 2e-10}
    member = {"structure": "a", "converged": False, "posterior": {
        "sampler": "importance", "iterations": 800, "screened": screened}}
    assert _chain_cell(member) == ("screened: under 5 % of the weight after 800 importance "
                                   "points (at most 0.0 % allowing for its estimate's error), so "
                                   "not run further; its ranges are its short run's")
    chain = {**member, "posterior": {"sampler": "ensemble", "iterations": 300,
                                     "screened": screened}}
    assert "after 300 steps (at most" in _chain_cell(chain)


def test_a_pair_is_decided_in_fact_by_the_members_the_second_set_keeps_merged_ones_included():
    """The next-test benchmark's count: a richer structure the first set merged into a member
    keeps that member when the second set needs it; a structure outside the first set keeps none."""
    from tvcid.studies.benchmarks.next_test import pairs_decided_in_fact

    first = {"a": "a", "b": "b", "c": "c", "a+bandpass": "a"}
    assert pairs_decided_in_fact(first, ["a+bandpass"]) == [("a", "b"), ("a", "c")]
    assert pairs_decided_in_fact(first, ["b", "x+friction"]) == [("a", "b"), ("b", "c")]
    assert pairs_decided_in_fact(first, ["c", "a", "b"]) == []


#: 2 kHz as read off a record's timestamps, and rates drawn over 200 Hz-2 kHz.
DRAWN_RATES = (2000.0000000046612, *np.round(np.random.default_rng(65).uniform(200.0, 2000.0, 2), 3))


@pytest.mark.parametrize("rate", DRAWN_RATES)
def test_the_menu_runs_at_any_acquisition_rate(rate):
    """The menu acquired at a recording's rate, one the simulation's default step does not divide
    (2 kHz as read off a record's timestamps, rates drawn over 200 Hz-2 kHz): every candidate is
    simulated and the pair is decided, as at 1 kHz."""
    menu = [Candidate(c.name, c.experiment, c.duration, rate) for c in MENU]
    r = discriminating_tests([M002(), M001i()], menu, noise_sd=2e-5, seed=1)
    assert all("skipped" not in t for t in r.tests), r.tests
    assert r.best is not None and r.best["pairs_decided"] == 1


def test_the_report_gives_the_reason_no_candidate_ran():
    """Where the best structure could run no candidate of the menu, the first screen says why
    (the reasons the candidates were skipped), not a guess."""
    from tvcid.report import _next_test_headline

    skipped = {"best": None, "n_pairs": 1, "tests": [
        {"name": "square", "skipped": "the best structure: no cycle"},
        {"name": "sine", "skipped": "the best structure: it diverged"},
        {"name": "A", "skipped": "the best structure: no cycle"}]}
    assert _next_test_headline(skipped, 2) == ("Next test: no candidate of the menu could be "
                                               "simulated (the best structure: it diverged; the "
                                               "best structure: no cycle).")
    assert _next_test_headline(None, 1) == "Next test: none needed (one structure left)."
