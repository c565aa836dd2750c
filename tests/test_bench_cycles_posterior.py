"""The cycles-alone posterior benchmark's pieces: the draws it picks, how it measures an
interval against the reference, and what its table counts."""
import numpy as np

from tvcid.studies.benchmarks.cycles_posterior import (
    GOAL_SHARE,
    cycles_only_seeds,
    interval_moves,
    summarise,
)
from tvcid.studies.benchmarks.scenarios import draw_design


def test_the_draws_hold_limit_cycles_alone_and_skip_the_others():
    seeds = cycles_only_seeds(9000, 4)
    assert len(seeds) == 4 and seeds == sorted(seeds) and seeds[0] >= 9000
    for seed in range(seeds[0], seeds[-1] + 1):
        recs, _ = draw_design(np.random.default_rng(seed), "wide")
        assert (seed in seeds) == all(r.kind == "closed" for r in recs)


def test_an_interval_moves_by_its_larger_end_over_the_reference_width():
    moves = interval_moves({"a": [1.0, 3.0], "b": [0.0, 1.0]}, {"a": [1.5, 3.0], "b": [0.0, 0.5]})
    assert moves == {"a": 0.5 / 1.5, "b": 0.5 / 0.5}


def _method(within, converged, rate):
    return {"within_goal": within, "converged": converged, "sampler": "nested",
            "effective_points_per_billion_steps": rate, "cpu_seconds": 10.0}


def test_the_table_counts_a_miss_the_diagnostic_did_not_flag():
    rows = [{"methods": {"default": _method(False, True, 1.0), "nested": _method(True, True, 3.0),
                         "reference": {"interval_drift": {"largest": 0.05}}}},
            {"methods": {"default": _method(False, False, 2.0),
                         "nested": _method(False, False, 5.0),
                         "reference": {"interval_drift": {"largest": 0.12}}}}]
    table = summarise(rows)
    assert table["goal_share"] == GOAL_SHARE and table["draws"] == 2
    assert table["default"]["missed_and_unflagged"] == 1 and table["nested"]["within_goal"] == 1
    assert table["nested"]["median_effective_points_per_billion_steps"] == 4.0
    assert table["reference_largest_drift"] == 0.12


def test_a_methods_row_keeps_what_the_nested_stage_gave_though_a_chain_followed():
    """The chain's row also holds the nested run's calls, finish and evidence, and its
    effective points per billion kernel steps come from its kept steps and walkers."""
    from types import SimpleNamespace

    from tvcid.discovery.calibration.nested import NestedRun
    from tvcid.discovery.calibration.runner import ConvergenceReport
    from tvcid.studies.benchmarks.cycles_posterior import _method_row

    rng = np.random.default_rng(0)
    z = rng.standard_normal((200, 2))
    run = NestedRun(points=z, log_prior=np.zeros(200), log_lik=np.zeros((200, 1)),
                    temperature=np.ones(1), log_w=np.full(200, -np.log(200)), log_z=-3.0,
                    log_z_se=0.1, n_like=5000, finished=False)
    rep = ConvergenceReport(iterations=1000, tau=(50.0, 100.0), n_over_tau=10.0, tau_factor=50.0,
                            converged=False, acceptance=0.2)
    cal = SimpleNamespace(n_walkers=20, importance_=None, nested_=run,
                          log_posterior_=SimpleNamespace(simulated_steps=3e9))
    post = SimpleNamespace(calibration=cal, report=rep, internal=z, names=("a", "b"), burn=200,
                           interval_drift=lambda: {"largest": 0.3, "parameter": "a"})
    row = _method_row(post, 1e9, 12.0, 7.0)
    assert row["sampler"] == "ensemble" and not row["converged"]
    assert row["effective_points"] == 800 * 20 / 100.0
    assert row["effective_points_per_billion_steps"] == row["effective_points"] / 2.0
    nested = row["stages"]["nested"]
    assert nested["likelihood_calls"] == 5000 and nested["finished"] is False
    assert nested["points"] == 200 and abs(nested["effective_points"] - 200) < 1e-9
    assert "importance" not in row["stages"]


def test_the_claim_names_each_methods_cost_and_move():
    """docs/results.md's row: per draw each method's sampler, diagnostic, effective points, CPU
    seconds and largest move; a method that ran nested sampling before its chain says so; a
    draw over 600 CPU s misses its goal, as does a resumed one, whose cost is not whole; a miss
    its diagnostic passed fails the second goal."""
    from tvcid.studies.benchmarks.claim_values import cycles_posterior

    def method(cpu, move, converged, nested=None):
        return {"sampler": "ensemble", "converged": converged, "effective_points": 40.0,
                "cpu_seconds": cpu, "largest_move": move, "within_goal": move <= GOAL_SHARE,
                "effective_points_per_billion_steps": 5.0,
                "stages": {"nested": nested} if nested else {}}

    nested = {"likelihood_calls": 40000, "finished": False, "effective_points": 3.2}
    row = {"seed": 9003, "structure": "s", "reference_steps": 10000, "methods": {
        "default": method(1500.0, 0.1, False), "nested": method(500.0, 0.3, True, nested),
        "reference": {"cpu_seconds": 7000.0, "interval_drift": {"largest": 0.08}}}}
    text = cycles_posterior({"bench_cycles_posterior": {"rows": [row]}})
    assert text.startswith("1 draws; goal default: 90 % intervals within 0.2 of the reference's "
                           "width in <= 600 CPU s: 0 of 1")
    assert ("draw 9003 (s): default ensemble, not converged, 40 effective points, 1500 CPU s, "
            "largest move 0.10; nested ensemble after nested sampling of 40000 calls "
            "(unfinished, 3 effective points), converged") in text
    assert "reference 10000 steps (7000 CPU s), its halves' largest drift 0.08" in text
    assert "nested: draws off the reference that its diagnostic passed: 1" in text
    assert text.count("NOT met") == 3
    # a run resumed from its checkpoint counts only its last call: not judged in time
    row["methods"]["default"] = {**method(300.0, 0.1, True), "resumed": True}
    text = cycles_posterior({"bench_cycles_posterior": {"rows": [row]}})
    assert "default ensemble, converged, 40 effective points, resumed, its cost not whole" in text
    assert "width in <= 600 CPU s: 0 of 1" in text
