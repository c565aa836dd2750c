"""Threads in the searches (discovery.structure.search) and the BLAS budget (discovery.threads):
the concurrent discovery returns exactly what the plain loops return."""
import numpy as np
import pytest

import discovery.structure.search as search
from discovery.structure import StructureDiscovery
from discovery.threads import one_blas_thread
from models.structures import Structure
from studies.benchmarks.scenarios import draw_scenario, shortened, write_recordings


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
    monkeypatch.setattr(search, "THREADED", False)
    seen.clear()
    assert search.concurrent_map(square, range(5)) == [0, 1, 4, 9, 16]
    assert seen == [0, 1, 2, 3, 4]  # a plain loop: in order


def _summary(disc):
    return [(f.structure.name, f.cost, f.score, f.indistinguishable_from_best, f.merged_into,
             tuple(np.round(f.theta, 12))) for f in disc.ranking_]


def test_threaded_discovery_is_the_loop_discovery(tmp_path, monkeypatch):
    """A drawn truth (benchmark generator, seed 5) with both positions and the loop fixed: four
    structures, so the nested level, the superset repair and the ranking's folds all run
    concurrently. Every cost, score, coordinate and verdict equals the sequential run's, and
    so does the count of simulated sets. The searches are cut short (the test is about the
    threads, not the search)."""
    import discovery.structure.structure_search as structure_search

    monkeypatch.setitem(structure_search.SEARCHES, "standard", structure_search.SearchSizes(
        pop=3, gens=4, open_pop=3, open_gens=4, nfev=6, rank_nfev=3))
    monkeypatch.setattr(structure_search, "OPEN_LOOP_RESTARTS", (2, 2))
    s = Structure("velocity", "output", friction=True, backlash=True, bandpass=False)
    scenario = shortened(draw_scenario(5, structure=s), closed=10.0, open_=5.0)
    paths = write_recordings(scenario, tmp_path, dt=5e-4)  # coarse: any data will do here
    fixed = {"dead_zone_position": "velocity", "delay_position": "output", "bandpass_gain": 0.0}
    runs = {}
    for threaded in (True, False):
        monkeypatch.setattr(search, "THREADED", threaded)
        disc = StructureDiscovery(fixed=fixed, seed=0, use_sindy=False).fit(paths)
        runs[threaded] = (_summary(disc), disc.n_simulations_, disc.repaired_)
    assert len(runs[True][0]) == 4
    assert runs[True] == runs[False]


if __name__ == "__main__":  # pragma: no cover
    pytest.main([__file__, "-n", "0"])
