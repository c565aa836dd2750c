"""The structure search's race: classes dropped only by a lower bound over the ranking's screen.

The rule is tested with the searches replaced by a table of costs (each top's open-loop optimum
and its fit on all recordings), so that the test is about the decisions; the drop rule's error
rate on drawn truths is the discovery benchmark's (``--race measure``; docs/methods/discovery.md).
"""
from types import SimpleNamespace

import numpy as np
import pytest

from tvcid.discovery.structure import structure_search as ss
from tvcid.discovery.structure.coordinates import SearchSpace
from tvcid.discovery.structure.ranking import in_sample_screen
from tvcid.discovery.structure.search import FitResult
from tvcid.models.hypotheses import ActuatorParams
from tvcid.models.structures import Structure, structure_space

#: Two recordings, one of each kind.
TARGETS = [SimpleNamespace(kind="closed", name="cycle"), SimpleNamespace(kind="open", name="square")]


def _bound(s):
    """Each class's open-loop optimum: the velocity dead zone's band-pass classes fit, the rest
    do not (the error dead zone's band-pass classes by 20, every class without the loop by 50+)."""
    if s.bandpass:
        base = 0.5 if s.dead_zone_position.value == "velocity" else 20.0
    else:
        base = 50.0 if s.dead_zone_position.value == "velocity" else 60.0
    return base + 0.1 * ["output", "before_integrator", "before_first_integrator"].index(
        s.delay_position.value)


def _search(race, monkeypatch):
    structures, _ = structure_space({})
    spaces = {s: SearchSpace(s, ActuatorParams(**ss.TEMPLATE), {}, 5e-4) for s in structures}
    calls = {"open": [], "whole": []}

    def fit_tops(search, wave, starts, seeds, firsts=None, open_loop_only=False):
        for s in wave:
            calls["open" if open_loop_only else "whole"].append(s)
            theta = 0.5 * (spaces[s].low + spaces[s].high)
            if open_loop_only:
                yield FitResult(theta, _bound(s), np.array([_bound(s)]), 1)
            else:  # on all recordings: the open-loop share at its optimum, and 0.8 more
                yield FitResult(theta, _bound(s) + 0.8, np.array([0.8, _bound(s)]), 1)

    monkeypatch.setattr(ss, "fit_tops", fit_tops)
    monkeypatch.setattr(ss.StructureSearch, "cross_seed", lambda self, fits: None)
    search = ss.StructureSearch(SimpleNamespace(targets=TARGETS), ss.SEARCHES["standard"],
                                np.random.default_rng(0), spaces, race=race)
    fits = search.search_classes(structures, {})
    return search, fits, calls, structures


def test_the_race_drops_the_classes_whose_open_loop_bound_exceeds_the_screen(monkeypatch):
    search, fits, calls, structures = _search("on", monkeypatch)
    record = search.race_record
    best = min(_bound(s) for s in structures) + 0.8
    assert record["best_cost"] == pytest.approx(best)
    assert record["screen"] == pytest.approx(in_sample_screen(best, len(TARGETS)))
    assert len(calls["open"]) == 12  # every top's open-loop stage
    # the error dead zone's classes go, with every structure nested in their tops
    error_dz = {s for s in structures if s.dead_zone_position.value == "error"}
    assert set(search.dropped) == error_dz
    assert all("raced out" in why for why in search.dropped.values())
    # the velocity dead zone's tops without the loop fit badly, but each is nested in its
    # class's band-pass top, which stays: they are searched, not dropped
    velocity_tops = {s for s in ss._class_tops(structures)
                     if s.dead_zone_position.value == "velocity"}
    assert set(fits) == velocity_tops == set(calls["whole"])
    assert record["applied"] and set(record["dropped"]) == {s.name for s in error_dz}


def test_measuring_the_race_searches_every_class_and_records_what_it_would_drop(monkeypatch):
    search, fits, calls, structures = _search("measure", monkeypatch)
    assert len(fits) == 12 and len(calls["whole"]) == 12 and not search.dropped
    assert not search.race_record["applied"]
    assert len(search.race_record["dropped"]) == 12
    # the bound held: each searched top's open-loop share is its open-loop optimum
    shares = search.race_record["open_loop_share"]
    assert all(shares[n] >= b - 1e-12 for n, b in search.race_record["bounds"].items())


def test_a_loop_refit_keeps_a_raced_out_class_out_only_while_its_bound_exceeds_the_screen(
        monkeypatch):
    search, fits, _, structures = _search("on", monkeypatch)
    record = search.race_record
    later = ss.StructureSearch(SimpleNamespace(targets=TARGETS + TARGETS), ss.SEARCHES["standard"],
                               np.random.default_rng(0), search.spaces)
    previous = {s.name: None for s in structures if s not in search.dropped}
    refits = {s: SimpleNamespace(cost=c) for s, c in zip(fits, [1.5] + [9.0] * (len(fits) - 1))}
    later._dropped_again(structures, previous, refits, record)
    assert set(later.dropped) == set(search.dropped)  # screen 2 x 1.5 + 2 = 5 < 20
    worse = {s: SimpleNamespace(cost=12.0) for s in fits}  # screen 26: the error classes return
    again = ss.StructureSearch(SimpleNamespace(targets=TARGETS + TARGETS), ss.SEARCHES["standard"],
                               np.random.default_rng(0), search.spaces)
    again._dropped_again(structures, previous, worse, record)
    assert not again.dropped and again.race_record["dropped"] == []


def test_an_unknown_race_mode_is_refused():
    with pytest.raises(ValueError, match="race='fast'"):
        ss.StructureSearch(SimpleNamespace(targets=TARGETS), ss.SEARCHES["standard"],
                           np.random.default_rng(0), race="fast")


def test_without_open_loop_recordings_there_is_no_race(monkeypatch):
    structures, _ = structure_space({})
    spaces = {s: SearchSpace(s, ActuatorParams(**ss.TEMPLATE), {}, 5e-4) for s in structures}
    seen = []

    def fit_tops(search, wave, starts, seeds, firsts=None, open_loop_only=False):
        for s in wave:
            seen.append(open_loop_only)
            yield FitResult(0.5 * (spaces[s].low + spaces[s].high), 1.0, np.array([1.0]), 1)

    monkeypatch.setattr(ss, "fit_tops", fit_tops)
    monkeypatch.setattr(ss.StructureSearch, "cross_seed", lambda self, fits: None)
    search = ss.StructureSearch(SimpleNamespace(targets=TARGETS[:1]), ss.SEARCHES["standard"],
                                np.random.default_rng(0), spaces, race="on")
    assert len(search.search_classes(structures, {})) == 12
    assert seen == [False] * 12 and search.race_record is None
    assert Structure.parse(structures[0].name) == structures[0]


def test_the_stored_race_measurement_is_its_rows_summary():
    """The stored measurement of the drop rule (``--race measure``: every class searched, what the
    race would drop recorded per draw): each row's errors are its own dropped structures that are
    the truth's or in its reported set, and the results table's value counts them."""
    import json
    from pathlib import Path

    from tvcid.studies.benchmarks.discovery import race_summary
    from tvcid.studies.benchmarks.claim_values import discovery_race
    from tvcid.studies.benchmarks.results_table import load_records

    path = Path(__file__).parents[1] / "studies/benchmarks/records/bench_discovery_race.json"
    rows = [r for r in json.loads(path.read_text())["rows"] if r.get("race")]
    assert rows
    for r in rows:
        assert r["race"]["applied"] is False  # measured: nothing was dropped from its set
        wrong = set(r["race"]["dropped"]) & ({r["structure"]} | set(r["set"]))
        assert sorted(wrong) == r["race"]["errors"], r["seed"]
        assert set(r["race"]["dropped"]) <= {n for t in r["race"]["dropped_tops"]
                                             for n in _nested_names(t)}, r["seed"]
    t = race_summary(rows)
    assert t["wrong"] == sum(bool(r["race"]["errors"]) for r in rows)
    text = discovery_race(load_records())
    assert f"in {t['wrong']} of {len(rows)}" in text and f"{t['dropped']} structures" in text


def _nested_names(top):
    """The names of ``top`` and of every structure nested in it (same positions)."""
    from tvcid.discovery.structure.indistinguishable import _contains

    t = Structure.parse(top)
    return {s.name for s in structure_space({})[0] if s == t or _contains(t, s)}
