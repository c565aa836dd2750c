"""``discovery.json`` as a typed record: :class:`tvcid.run_record.RunRecord` writes every key the
stages filled, reads it back to the same record, and refuses what it did not write."""
import json

import pytest

from tvcid.run_record import DISCOVERY_FORMAT, RunCost, RunRecord

ROW = {"structure": "dz_error+delay_output", "score": 1.0, "params": {}, "merged_into": None,
       "indistinguishable_from_best": True}


def test_a_ranking_alone_writes_no_key_of_the_later_stages():
    """A record straight from the ranking has no set stage and no next test in its JSON; the
    cost's ledgers sit under their ``discovery.json`` keys."""
    record = RunRecord([ROW], seed=3, cost=RunCost(wall={"global": 2.0}))
    d = record.to_dict()
    assert not {"posterior", "set_posterior", "set_screening", "next_test", "added"} & set(d)
    assert d["timings"] == {"global": 2.0} and d["simulated_steps"] == {}
    assert d["format"] == DISCOVERY_FORMAT and d["seed"] == 3


def test_a_record_survives_its_json_round_trip_and_a_next_test_of_none_stays_named():
    """Every field comes back equal after ``json`` and :meth:`RunRecord.from_dict`; a set of one
    names no next test (``None``), which is not the same as a next test not yet run."""
    record = RunRecord([ROW, {**ROW, "structure": "x", "merged_into": "dz_error+delay_output"}],
                       recordings=["a.csv"], decided={"delay_position": "output"},
                       sensor_noise={"a.csv": 1e-5}, set_posterior={"members": [
                           {"structure": "dz_error+delay_output", "weight": 1.0}]})
    record.cost.add("mcmc", wall=4.0, cpu=7.5, simulated_steps=1e6)
    record.next_test, record.next_test_named = None, True
    back = RunRecord.from_dict(json.loads(json.dumps(record.to_dict())))
    assert back == record and back.next_test_named and back.to_dict()["next_test"] is None
    assert back.set_rows() == [ROW] and back.member_weights() == {"dz_error+delay_output": 1.0}
    assert back.cost.cpu == {"mcmc": 7.5}
    assert not RunRecord.from_dict({"structures": [ROW]}).next_test_named


def test_a_runs_totals_count_each_stage_once():
    """The whole run's cost is the search (its ``discovery`` entry where the ledger has one, else
    its stages' sum), the set's calibration and the next test; a stage's parts are left out."""
    cost = RunCost(wall={"sindy": 1.0, "global": 5.0, "global_open_loop_stage": 2.0,
                         "ranking": 1.5, "discovery": 8.0, "total": 8.0, "mcmc": 20.0,
                         "next_test": 3.0},
                   simulated_steps={"global": 1e9, "nested": 2e8, "ranking": 1e8, "mcmc": 3e9,
                                    "mcmc_start": 5e8, "mcmc_evidence": 1e8, "next_test": 4e8})
    totals = cost.totals()
    assert totals["wall_seconds"] == 8.0 + 20.0 + 3.0
    assert totals["kernel_steps"] == 1e9 + 2e8 + 1e8 + 3e9 + 4e8
    assert totals["cpu_seconds"] == 0.0 and totals["simulated_seconds"] == 0.0


def test_an_adds_refit_counts_in_its_search():
    """An ``--add``'s search refits every structure (``refit``) instead of the global and nested
    stages; its kernel steps are the search's, and its CPU ledger's ``discovery`` entry holds
    them already."""
    cost = RunCost(cpu={"refit": 1652.0, "ranking": 89.0, "discovery": 1749.0, "mcmc": 1056.0},
                   simulated_steps={"refit": 6.9e9, "ranking": 3.8e8, "mcmc": 6.3e9,
                                    "mcmc_start": 7e8, "next_test": 0.0})
    totals = cost.totals()
    assert totals["kernel_steps"] == 6.9e9 + 3.8e8 + 6.3e9
    assert totals["cpu_seconds"] == 1749.0 + 1056.0


@pytest.mark.parametrize("content, message", [
    ([], r"^not a discovery\.json \(no 'structures'\)$"),
    ({"format": 2}, r"^not a discovery\.json \(no 'structures'\)$"),
    ({"structures": [], "summary_of": 1}, r"^not a discovery\.json of this version \(unknown key "
                                          r"'summary_of'\)$"),
])
def test_what_the_record_did_not_write_is_a_one_line_error(content, message):
    with pytest.raises(ValueError, match=message):
        RunRecord.from_dict(content)
