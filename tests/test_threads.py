"""Threads in the searches (tvcid.discovery.structure.search) and the BLAS budget (tvcid.discovery.threads):
the concurrent discovery returns exactly what the plain loops return."""
import numpy as np
import pytest

import tvcid.discovery.structure.search as search
import tvcid.discovery.threads as threads
from tvcid.discovery.structure import StructureDiscovery
from tvcid.discovery.threads import one_blas_thread
from tvcid.models import simulate
from tvcid.models.structures import Structure
from tvcid.studies.benchmarks.scenarios import draw_scenario, shortened, write_recordings


def _blas_threads():
    from threadpoolctl import threadpool_info

    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_inside_the_block_and_restored_after():
    before = _blas_threads()
    with one_blas_thread():
        assert set(_blas_threads()) == {1}
    assert _blas_threads() == before


def test_concurrent_map_keeps_the_order_and_the_loop_runs_without_threads(monkeypatch):
    seen = []

    def square(x):
        seen.append(x)
        return x * x

    assert search.concurrent_map(square, range(20)) == [x * x for x in range(20)]
    monkeypatch.setattr(threads, "THREADED", False)
    seen.clear()
    assert search.concurrent_map(square, range(5)) == [0, 1, 4, 9, 16]
    assert seen == [0, 1, 2, 3, 4]  # a plain loop: in order


def _summary(disc):
    return [(f.structure.name, f.cost, f.score, f.indistinguishable_from_best, f.merged_into,
             tuple(np.round(f.theta, 12))) for f in disc.ranking_]


@pytest.mark.slow
def test_threaded_discovery_is_the_loop_discovery(tmp_path, monkeypatch):
    """A drawn truth (benchmark generator, seed 5) with both positions and the loop fixed: four
    structures, so the nested level, the superset repair and the ranking's folds all run
    concurrently. Every cost, score, coordinate and verdict equals the sequential run's, and
    so does the count of simulated sets. The searches are cut short (the test is about the
    threads, not the search)."""
    import tvcid.discovery.structure.global_fit as global_fit
    import tvcid.discovery.structure.structure_search as structure_search

    monkeypatch.setitem(structure_search.SEARCHES, "standard", structure_search.SearchSizes(
        pop=3, gens=4, open_pop=3, open_gens=4, nfev=6, rank_nfev=3))
    monkeypatch.setattr(global_fit, "OPEN_LOOP_RESTARTS", (2, 2))
    s = Structure("velocity", "output", friction=True, backlash=True, bandpass=False)
    scenario = shortened(draw_scenario(5, structure=s), closed=10.0, open_=5.0)
    # coarse, and made by the numba kernel in place of the plain-Python reference path (which
    # costs more than the discoveries): any data will do here
    monkeypatch.setattr("tvcid.studies.benchmarks.scenarios.simulate_reference", simulate)
    paths = write_recordings(scenario, tmp_path, dt=5e-4)
    fixed = {"dead_zone_position": "velocity", "delay_position": "output", "bandpass_gain": 0.0}
    runs = {}
    for threaded in (True, False):
        monkeypatch.setattr(threads, "THREADED", threaded)
        disc = StructureDiscovery(fixed=fixed, seed=0, use_sindy=False).fit(paths)
        runs[threaded] = (_summary(disc), disc.n_simulations_, disc.repaired_)
    assert len(runs[True][0]) == 4
    assert runs[True] == runs[False]


def test_threaded_log_posterior_is_the_loop_log_posterior(tmp_path, monkeypatch):
    """The calibration's likelihood terms simulated concurrently: a limit cycle (features) and an
    open-loop square (output error) of paper 002's actuator; the log posterior of a batch, of one
    point, and the pointwise log-likelihoods equal the plain loop's bit for bit."""
    from tvcid.discovery.calibration import Calibration
    from tvcid.models import CONTROLLER_A, M002, OpenLoop
    from tvcid.models.synthetic import synthetic_recording

    recs = [synthetic_recording(M002(), CONTROLLER_A, 14.0, 1e-4, 1, tmp_path / "a.csv",
                                keep_last=8.0),
            synthetic_recording(M002(), OpenLoop.square(0.01, 2.0), 3.0, 1e-4, 2, tmp_path / "sq.csv")]
    cal = Calibration("M002", params=("dead_zone", "delay"), likelihood="features", window=6.0,
                      transient=4.0, seed=0).setup(recs)
    lp = cal.log_posterior_
    z0 = lp.internal(np.array([[M002().dead_zone, M002().delay]]))
    z = z0 + [0.02, 2e-4] * np.random.default_rng(3).standard_normal((6, 2))  # log, s
    out = {}
    for threaded in (True, False):
        monkeypatch.setattr(threads, "THREADED", threaded)
        out[threaded] = (lp(z), lp(z[0]), lp.pointwise(z))
    assert np.all(np.isfinite(out[True][0])) and out[True][2].shape[0] == 6
    for a, b in zip(out[True], out[False]):
        assert np.array_equal(a, b)



@pytest.mark.slow
def test_likelihood_threads_benchmark_records_equal_numbers_and_both_timings(tmp_path):
    """``python -m tvcid.studies.benchmarks.likelihood_threads --quick``: its record holds both timings
    of one point and of a batch, the bit-for-bit comparison (its goals judge the speed-ups) and
    each recording's share of a point's cost."""
    import json

    from tvcid.studies.benchmarks.likelihood_threads import main

    main(["--quick", "--out", str(tmp_path)])
    saved = json.loads((tmp_path / "bench.json").read_text())
    assert saved["equal"] is True and saved["repeats"] == 2
    assert {k: v["points"] for k, v in saved["rows"].items()} == {"point": 1, "batch": 40}
    assert all(v["seconds_loop"] > 0 and v["seconds_threaded"] > 0 for v in saved["rows"].values())
    # where a point's time goes: every recording, shares summing to 1, its run and step
    terms = saved["terms"]
    assert sorted(terms) == ["m000_closed_A", "m000_closed_B", "m000_open_sine", "m000_open_square"]
    assert sum(t["share"] for t in terms.values()) == pytest.approx(1.0)
    assert all(t["simulated_seconds"] > 0 and 0 < t["step"] <= 5e-4 for t in terms.values())
    # docs/limits.md: cycle B, still settling over its record, runs longer than cycle A; the
    # square test's switching events need a finer step than the sine's
    assert terms["m000_closed_B"]["simulated_seconds"] > 1.5 * terms["m000_closed_A"]["simulated_seconds"]
    assert terms["m000_open_square"]["step"] < terms["m000_open_sine"]["step"]


if __name__ == "__main__":  # pragma: no cover
    pytest.main([__file__, "-n", "0"])
