"""What a run's work is counted in (tvcid.discovery.speed, the search's Objective, the members' tasks)
and when a timed run counts as the speed (the idle check of the speed benchmark)."""
import json
import math
from pathlib import Path

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from tvcid.discovery.speed import MAX_LOAD, MAX_REFERENCE_DRIFT, idle_check, kernel_reference
from tvcid.discovery.structure.search import Objective
from tvcid.discovery.structure.targets import make_target
from tvcid.models import hypothesis
from tvcid.models.recording import load_recording

DATA = Path(__file__).resolve().parents[1] / "data" / "m000_closed_A.csv"
RECORDS = Path(__file__).resolve().parents[1] / "studies" / "benchmarks" / "records"


def _blas_threads():
    return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def test_idle_check_flags_a_loaded_start_or_a_kernel_that_changed_speed():
    """Passed at an idle start with references 5 % apart; flagged, with every reason, above
    0.5 load average or beyond 10 % between the references (either way round)."""
    assert (MAX_LOAD, MAX_REFERENCE_DRIFT) == (0.5, 0.10)
    ok = idle_check(0.2, 1.0e-7, 1.05e-7)
    assert ok["passed"] and ok["reason"] is None
    assert ok["reference_drift"] == pytest.approx(0.05)
    loaded = idle_check(0.8, 1.0e-7, 1.0e-7)
    assert not loaded["passed"] and loaded["reason"] == "load average 0.80 at the start > 0.5"
    slower = idle_check(0.1, 1.0e-7, 1.2e-7)
    assert not slower["passed"] and "differ by 20% > 10%" in slower["reason"]
    assert not idle_check(0.1, 1.2e-7, 1.0e-7)["passed"]  # faster after: 17 % of the first
    both = idle_check(1.5, 1.0e-7, 2.0e-7)
    assert not both["passed"] and both["reason"].count(";") == 1
    assert idle_check(0.5, 10.0, 11.0)["passed"]  # the limits themselves pass


def test_kernel_reference_is_cpu_seconds_per_step_of_one_run():
    """The reference is a CPU time per kernel step: far under a microsecond and finite (the
    kernel takes tens of nanoseconds of CPU per RK4 step of one run)."""
    ref = kernel_reference(repeats=1)
    assert math.isfinite(ref) and 1e-9 < ref < 1e-5


def test_the_objective_counts_steps_and_second_starts():
    """Each run is counted at its simulator's ``t_end / dt``, a limit cycle simulated again from
    its second start included: a set far from the record (gain doubled) misses it by more than
    the second start's cost and runs twice."""
    target = make_target(load_recording(DATA), 5e-4)
    far = hypothesis("M000").replace(gain=2 * hypothesis("M000").gain)
    objective = Objective([target])
    objective.costs([hypothesis("M000"), far, None])
    runs = 2 + target.second_starts
    assert target.second_starts >= 1
    assert objective.simulated_seconds == pytest.approx(runs * target.simulator.t_end)
    assert objective.simulated_steps == pytest.approx(
        runs * target.simulator.t_end / target.simulator.dt)


def test_a_members_task_runs_blas_on_one_thread_and_reports_its_cpu(monkeypatch, tmp_path):
    """The member's task limits BLAS itself (a worker process is outside ``discover``'s own
    limit) and reports the CPU and wall seconds of its process and its id."""
    import os

    import tvcid.members as members

    seen = {}

    def work(row, *args):
        seen["blas"] = _blas_threads()
        return members.MemberRun(row["structure"])

    monkeypatch.setattr(members, "_member_task", work)
    with threadpool_limits(limits=2, user_api="blas"):
        outside = _blas_threads()
        run = members.calibrate_member_task({"structure": "s"}, [], {}, None, 0, True, 10, False,
                                            tmp_path, False)
    assert outside == {2} and seen["blas"] == {1}
    assert run.pid == os.getpid() and run.cpu_seconds >= 0.0 and run.wall_seconds > 0.0


def test_a_flagged_speed_run_is_shown_flagged_and_not_judged():
    """The stored speed run with a failed idle check: the results table says it is flagged and
    why, and does not judge its goal; with a passed one it judges it (met or NOT met)."""
    from tvcid.studies.benchmarks.claim_values import discover_speed

    record = json.loads((RECORDS / "bench_discover_speed.json").read_text())
    flag = idle_check(1.08, 1.0e-7, 1.0e-7)
    text = discover_speed({"bench_discover_speed": {**record, "idle_check": flag}})
    assert text.startswith("flagged, not the speed (load average 1.08 at the start > 0.5): ")
    assert "not judged" in text and " met" not in text.split(";")[0]
    passed = discover_speed({"bench_discover_speed": {**record,
                                                      "idle_check": idle_check(0.1, 1.0, 1.0)}})
    assert not passed.startswith("flagged") and passed.split(";")[0].endswith(" met")


def test_evaluation_steps_split_a_points_cost_by_record_and_part(tmp_path):
    """One point of M000's features likelihood on its cycle A and its open-loop square: the
    cycle's settling (6 s) and window (10 s) at 5e-4 s, nothing simulated beyond the window; the
    square's whole record at the step its edges and solver check chose, the steps that choice
    added apart. The parts add up to the steps."""
    from tvcid.discovery.calibration.likelihood import FeatureTerm, OpenLoopTerm
    from tvcid.discovery.speed import evaluation_steps

    truth = hypothesis("M000")
    cycle = FeatureTerm(load_recording(DATA), 10.0, 6.0, 5e-4).setup(truth)
    square = OpenLoopTerm(load_recording(DATA.with_name("m000_open_square.csv")), None, 0.0,
                          5e-4).setup(truth)
    rows = {r["kind"]: r for r in evaluation_steps([cycle, square])}
    c, o = rows["cycle"], rows["open"]
    assert c["parts"]["settle"] == pytest.approx(6.0 / 5e-4)
    assert c["parts"]["window"] == pytest.approx(cycle.tau[-1] / 5e-4)
    assert c["parts"]["beyond"] < 5
    assert o["parts"]["record"] == pytest.approx(square.tau[-1] / 5e-4)
    # M000's square needs a finer step than 5e-4 s (its solver load 184 there)
    assert square.sim_dt < 5e-4 and o["parts"]["refined"] > 0
    assert o["parts"]["refined"] == pytest.approx(square.tau[-1] / square.sim_dt
                                                  - square.tau[-1] / 5e-4)
    for r in (c, o):
        assert sum(r["parts"].values()) == pytest.approx(r["steps"])


def test_stored_evaluation_cost_record_is_its_rows_summary():
    """The evaluation-cost record's table is what its rows give; the parts' shares add to one;
    every cycle record's settling and window are counted; and what docs/limits.md reads from it
    holds: the runs have not finished settling by their windows (a run's features move by about
    two of the data's sd from one window to the next, in the median), and the open-loop records'
    finer steps cost more than those records at the given step."""
    from tvcid.studies.benchmarks.evaluation_cost import summarise

    record = json.loads((RECORDS / "bench_evaluation_cost.json").read_text())
    rows = record["rows"]
    assert len(rows) >= 10 and all(r["commit"] for r in rows)
    table = summarise(rows)
    assert json.loads(json.dumps(table)) == record["table"]
    assert sum(table["share_by_part"].values()) == pytest.approx(1.0)
    for r in rows:
        for rec in r["records"]:
            assert sum(rec["parts"].values()) == pytest.approx(rec["steps"])
            if rec["kind"] == "cycle":
                assert rec["parts"]["settle"] > 0 and rec["parts"]["window"] > 0
    assert 1.0 < table["next_window_sd"]["median"] < 4.0
    assert table["steps_by_part"]["open:refined"] > table["steps_by_part"]["open:record"]


def test_two_runs_answers_are_compared_member_by_member():
    """The speed benchmark's comparison of two runs' answers: an interval of a member carrying
    weight moved by a quarter of its width is not the same answer, the same move in a member of
    weight 0.01 is not judged, a changed winner is named, and the set is compared as a set."""
    from tvcid.studies.benchmarks.discover_speed import compare_answers

    def run(winner, lo_a, lo_b, weight_b=0.01):
        return {"winner": winner, "set": ["a", "b"], "members": {
            "a": {"weight": 0.99, "intervals": {"delay": [lo_a, lo_a + 1.0]}},
            "b": {"weight": weight_b, "intervals": {"delay": [lo_b, lo_b + 1.0]}}}}

    before = run("a", 0.0, 0.0)
    same = compare_answers(run("a", 0.05, 5.0), before)
    assert same["same"] and same["largest_move"] == pytest.approx(0.1)
    assert "b" not in same["moves"]  # under 5 % of the weight in both runs
    moved = compare_answers(run("a", 0.125, 0.0), before)
    assert not moved["same"] and moved["largest_move"] == pytest.approx(0.25)
    heavy_b = compare_answers(run("a", 0.0, 0.3, weight_b=0.4), before)
    assert not heavy_b["same"] and heavy_b["moves"]["b"]["delay"] == pytest.approx(0.6)
    other = compare_answers(run("b", 0.0, 0.0), before)
    assert not other["same"] and not other["same_winner"] and other["same_set"]
    reordered = run("a", 0.0, 0.0)
    reordered["set"] = ["b", "a"]  # the ranking's scores swapped, the same members
    assert compare_answers(reordered, before)["same_set"]
    grown = run("a", 0.0, 0.0)
    grown["set"] = ["a", "b", "c"]
    assert not compare_answers(grown, before)["same_set"]
