"""A closed-loop record whose cycle is still settling is compared as the transient it is.

Drawn truths near the bifurcation that makes their cycle grow it slowly: a 12 s record taken 10 s
after the loop closes can sit 5-25 % under the settled cycle. Compared with the settled cycle, the
truth then costs tens to hundreds of units on its own record and the fit moves the linear block
(:func:`tvcid.models.cycle_settling.settles`,
:meth:`tvcid.discovery.structure.targets.CycleTarget._transient_features`).
"""
from __future__ import annotations

from unittest import mock

import numpy as np
import pytest

from tvcid.discovery.structure import targets
from tvcid.discovery.structure.search import Objective
from tvcid.models import cycle_settling, simulate
from tvcid.models.recording import load_recording
from tvcid.studies.benchmarks import scenarios
from tvcid.studies.benchmarks.scenarios import draw_scenario, shortened, write_recordings

DATA = "data/bench/draw1000"


def _cost(target, truth):
    return float(np.ravel(Objective([target]).costs([truth]))[0])


def closed_record_costs(seeds, directory, closed=None):
    """``(seed, record, settling, cost, cost as a settled cycle)`` at the truth, per closed record
    of each drawn scenario (records cut to ``closed`` s when given, made by the numba kernel at
    1e-4 s and written as measured recordings)."""
    rows = []
    for seed in seeds:
        scenario = draw_scenario(seed)
        if closed is not None:
            scenario = shortened(scenario, closed=closed, open_=6.0)
        with mock.patch.object(scenarios, "simulate_reference", simulate):
            paths = write_recordings(scenario, directory / f"draw{seed}", dt=1e-4)
        for path in paths:
            if not path.stem.endswith("_closed"):
                continue
            recording = load_recording(path)
            target = targets.make_target(recording, 5e-4)
            with mock.patch.object(targets, "settles", lambda *a: False):
                as_settled = targets.make_target(recording, 5e-4)
            rows.append((seed, path.stem, target.settling, _cost(target, scenario.truth),
                         _cost(as_settled, scenario.truth)))
    return rows


def test_settling_records_of_drawn_truths_cost_the_truth_about_one_unit(tmp_path):
    """Draws 0-5 of the wide ranges, closed records cut to 12 s: every record found settling
    costs the truth under 1 (about 1 is what the generating model pays), and at least three of
    them cost it over 10 as settled cycles (measured: 20, 100 and 22 on draws 1, 3 and 5)."""
    rows = closed_record_costs(range(6), tmp_path, closed=12.0)
    settling = [r for r in rows if r[2]]
    assert all(r[3] < 1.0 for r in settling), settling
    assert sum(r[4] > 10.0 for r in settling) >= 3, settling


def test_a_settled_record_is_compared_with_the_settled_cycle():
    """The bundled draw's cycles (settled 10 s before their 30 s records) are not settling, so
    their runs are measured after the transient, over 12 to 24 periods."""
    for name in ("rec00_closed", "rec01_closed"):
        target = targets.make_target(load_recording(f"{DATA}/{name}.csv"), 5e-4)
        assert not target.settling
        assert target.window_periods >= targets.WINDOW_PERIODS


def test_a_still_growing_cycle_is_found_settling():
    """A cycle whose size approaches its limit exponentially over the record is settling; the
    same cycle at its limit is not."""
    t = np.arange(0.0, 12.0, 1e-3)
    omega = 2 * np.pi * 0.9
    rng = np.random.default_rng(0)
    noise = 2e-5 * rng.standard_normal(t.size)
    growing = 0.01 * (1 - 0.25 * np.exp(-t / 5.0)) * np.sin(omega * t) + noise
    settled = 0.01 * np.sin(omega * t) + noise
    for x, expected in ((growing, True), (settled, False)):
        tt, dd, ups = cycle_settling.stationary_tail(t, x)
        assert cycle_settling.settles(tt, dd, ups) is expected


@pytest.mark.slow
def test_transient_comparison_over_forty_drawn_scenarios(tmp_path):
    """Draws 0-39 of the wide ranges (81 closed records). Cut to 12 s, the truth costs over 1 on
    at most 3 records (measured: 3; 15 compared as settled cycles); at their full 20-40 s, on at
    most 1 (measured: 1), and the transient comparison costs no record more than 0.05 over the
    settled one."""
    short = closed_record_costs(range(40), tmp_path / "short", closed=12.0)
    assert len(short) == 81
    assert sum(r[3] > 1.0 for r in short) <= 3, [r for r in short if r[3] > 1.0]
    assert sum(r[4] > 1.0 for r in short) >= 12
    full = closed_record_costs(range(40), tmp_path / "full")
    assert sum(r[3] > 1.0 for r in full) <= 1, [r for r in full if r[3] > 1.0]
    assert all(r[3] <= r[4] + 0.05 for r in full), [r for r in full if r[3] > r[4] + 0.05]
