"""``docs/results.md`` and what the benchmarks share at their end (tvcid.studies.benchmarks.results_table,
tvcid.studies.benchmarks.goals): the table is the rendering of the stored records, a changed record changes it,
every claim names a real test, goal lines say met or NOT met on the right side of a target, and
the JSON written is strict."""
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from tvcid.models.strict_json import write_json
from tvcid.studies.benchmarks.goals import Goal, report
from tvcid.studies.benchmarks.results_table import (
    CLAIMS,
    OUT,
    RECORDS,
    Claim,
    commits_text,
    find_test,
    load_records,
    main,
    render,
)


def test_docs_results_md_is_the_rendering_of_the_current_records(capsys):
    """The committed table equals the rendering of ``studies/benchmarks/records`` by the current code
    (``python -m tvcid.studies.benchmarks.results_table --check`` exits 0), so a quoted number cannot drift from
    its record."""
    assert OUT.read_text() == render()
    assert main(["--check"]) == 0
    assert "up to date" in capsys.readouterr().out


def test_a_changed_record_changes_the_rendered_value(tmp_path, capsys):
    """In a copy of the records, a fresh discovery draw's verdict turned into a miss and its
    commit changed: the rendered rate falls from 3 of 4 to 2 of 4 and the commit column says
    the rows come from two commits; ``--check`` against the committed table then exits 1."""
    records = tmp_path / "records"
    shutil.copytree(RECORDS, records)
    path = records / "bench_discovery_fresh.json"
    data = json.loads(path.read_text())
    hit = next(r for r in data["rows"] if r["right_or_in_small_set"])
    hit["right_or_in_small_set"] = False
    hit["commit"] = "0000000"
    write_json(path, data)
    before, after = render(), render(load_records(records))
    assert before != after
    row = next(line for line in after.splitlines() if "fresh draws" in line)
    assert "at most 3: 3 of 4 = 75 %" in before and "at most 3: 2 of 4 = 50 %" in row
    assert "**rows at 2 commits**" in row and "`0000000` (1)" in row
    assert main(["--check", "--records", str(records)]) == 1
    assert "differs" in capsys.readouterr().out
    out = tmp_path / "results.md"
    assert main(["--records", str(records), "--out", str(out)]) == 0
    assert out.read_text() == after


@pytest.mark.parametrize("value, met", [(299.0, False), (300.0, True), (301.0, True),
                                        (None, False), (math.nan, False)])
def test_a_lower_bound_is_met_at_and_above_its_target(value, met):
    goal = Goal.at_least("kernel over reference", value, 300.0, fmt="{:.0f}x")
    assert goal.met is met
    assert goal.line().startswith("goal kernel over reference: ")
    assert goal.line().endswith(" (>= 300x) met" if met else " (>= 300x) NOT met")


@pytest.mark.parametrize("value, met", [(0.099, True), (0.1, True), (0.101, False)])
def test_an_upper_bound_is_met_at_and_below_its_target(value, met):
    goal = Goal.at_most("amplitude error", value, 0.1, fmt="{:.3g} %")
    assert goal.met is met and goal.line().endswith("met") and ("NOT met" in goal.line()) != met


@pytest.mark.parametrize("value, met", [(0.79, False), (0.8, True), (0.9, True), (0.97, True),
                                        (0.98, False)])
def test_a_range_is_met_inside_it_only(value, met):
    assert Goal("coverage", value, low=0.8, high=0.97).met is met


def test_speed_goals_are_judged_in_reference_seconds_not_seconds():
    """The same 900 s meet a 600 s goal on a machine whose reference runs 3x slower than the
    nominal one, and miss it on a nominal machine; the line prints both seconds and the ratio."""
    from tvcid.studies.benchmarks.goals import NOMINAL_REFERENCE

    slow = Goal.speed("discover", 900.0, 3 * NOMINAL_REFERENCE, 600.0)
    nominal = Goal.speed("discover", 900.0, NOMINAL_REFERENCE, 600.0)
    assert slow.met and not nominal.met
    assert slow.measured == pytest.approx(900.0 / (3 * NOMINAL_REFERENCE))
    assert "900 s = " in slow.line() and "reference seconds" in slow.line()
    assert "<= 600 s = " in slow.line() and slow.line().endswith(") met")
    assert nominal.line().endswith(") NOT met")
    assert not Goal.speed("discover", 500.0, None, 600.0).met  # no reference: nothing judged


def test_report_prints_every_goal_and_its_status_is_whether_all_are_met(capsys):
    met, missed = Goal.count("draws", 3, 3), Goal.count("draws", 2, 3)
    assert report([met, met]) == 0 and report([met, missed]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines == ["goal draws: 3 of 3 (all) met"] * 3 + ["goal draws: 2 of 3 (all) NOT met"]
    assert report([]) == 0 and capsys.readouterr().out == "goals: none stated\n"
    assert not Goal.count("draws", 0, 0).met  # nothing counted is not a goal met


def test_json_is_written_strict_with_null_for_non_finite_numbers(tmp_path):
    data = {"a": math.nan, "b": [math.inf, -math.inf, 1.5], "c": np.float64("nan"),
            "d": np.array([1.0, np.inf]), "e": (np.int64(3), np.bool_(True)), "f": None}
    path = write_json(tmp_path / "x.json", data)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"a": None, "b": [None, None, 1.5], "c": None, "d": [1.0, None],
                                "e": [3, True], "f": None}
    with pytest.raises(TypeError):
        write_json(tmp_path / "y.json", {"p": Path("x")})
    assert json.loads(write_json(tmp_path / "y.json", {"p": Path("x")}, default=str)
                      .read_text()) == {"p": "x"}


def test_a_record_with_nan_tokens_is_refused(tmp_path):
    (tmp_path / "bad.json").write_text('{"rows": [{"seconds": NaN}]}')
    with pytest.raises(ValueError, match="bad.json: NaN is not JSON"):
        load_records(tmp_path)


def test_every_claim_names_a_test_that_exists_and_a_missing_one_is_refused():
    for claim in CLAIMS:
        assert find_test(claim.test) is not None, claim.test
    assert find_test("tests/test_results_table.py::test_no_such_test") is None
    assert find_test("tests/no_such_file.py::test_x") is None
    bad = Claim("x", lambda r: "1", lambda r: [], "cmd", "bench_next_test",
                "tests/test_results_table.py::test_no_such_test")
    with pytest.raises(ValueError, match="no test tests/test_results_table.py::test_no_such_test"):
        render(claims=(bad,))


def test_commits_are_named_once_or_counted_when_rows_come_from_several():
    assert commits_text([{"commit": "abc"}, {"commit": "abc"}]) == "`abc`"
    text = commits_text([{"commit": "abc"}, {"commit": "def"}, {"commit": "def"}, {}])
    assert text == "**rows at 3 commits**: `def` (2), no commit recorded (1), `abc` (1)"


def test_speed_claim_judges_the_stored_run_in_reference_seconds():
    """The speed claim: the stored run's wall time judged against 600 s in kernel-reference
    seconds of the same run (met at half the budget, NOT met at twice it; a run its idle check
    flagged is shown as flagged, its goal not judged), with the search's and the chains' seconds,
    simulated seconds and kernel steps."""
    from tvcid.studies.benchmarks.claim_values import discover_speed

    record = json.loads((RECORDS / "bench_discover_speed.json").read_text())
    text = discover_speed({"bench_discover_speed": record})
    stages = record["stages"]
    search = stages["sindy"] + stages["global"] + stages["nested"] + stages["ranking"]
    assert f"structure search and ranking {search:.0f} s" in text
    assert f"the set's calibration {stages['mcmc']:.0f} s" in text
    assert "million in the set's calibration" in text
    compared = record.get("compared_with")
    if compared:  # the answers against an earlier run's on the same recordings
        assert f"moved by at most {compared['largest_move']:.2f} of their width" in text
        for name in compared.get("missing") or ():  # a member carrying weight in one run only
            assert f"`{name}` carries weight" in text
    if record.get("sampler") == "importance":
        assert f"the winner importance sampled, {record['mcmc_steps']} points" in text
    steps = record.get("simulated_steps")
    if steps:
        assert f"{steps['mcmc'] / 1e9:.3g} billion in the set's calibration" in text
    flag = record.get("idle_check")
    if flag and not flag["passed"]:  # a run on a busy machine is shown, its goal not judged
        assert text.startswith("flagged, not the speed") and flag["reason"] in text
    idle = {"passed": True}
    reference = record["kernel_seconds_per_simulated_second"]
    for wall, verdict in ((300 * reference / 2e-4, " met"), (1200 * reference / 2e-4, "NOT met")):
        judged = discover_speed({"bench_discover_speed": {**record, "wall_seconds": wall,
                                                          "idle_check": idle}})
        assert judged.split(";")[0].endswith(verdict), judged


def test_the_next_tests_default_seeds_are_the_discovery_records_misses_that_hold_the_truth():
    from tvcid.studies.benchmarks.next_test import DEFAULT_SEEDS

    rows = load_records()["bench_discovery_quick"]["rows"]
    misses = {r["seed"] for r in rows if r["truth_in_set"] and not r["right_or_in_small_set"]}
    assert set(DEFAULT_SEEDS) == misses


def test_every_record_holds_rows_of_one_commit_of_clean_code():
    """A record's figures come from one version of the code: every row of it names the same
    commit, and none was made from modified files (``+dirty``)."""
    for name, record in load_records().items():
        rows = record.get("rows") or record.get("plain_rows") or [record]
        commits = {row.get("commit") for row in rows}
        assert len(commits) == 1 and None not in commits, f"{name}: rows at {sorted(map(str, commits))}"
        assert not next(iter(commits)).endswith("+dirty"), f"{name}: made from modified code"
