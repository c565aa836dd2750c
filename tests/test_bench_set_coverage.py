"""tvcid.studies.benchmarks.set_coverage and set_judge: a draw's row judges what the report prints, per
quantity: a pinned quantity on its 90 % interval, a not-pinned one on the range the recordings
allow (an open end on the prior's bound), a component the truth lacks on whether it is printed
absent or "present or absent"; the judgements that cannot fail are counted apart from the goals;
the table counts the verdicts per rule, the rows per commit, the widths and the intervals
narrower than the step error; a stored row is judged again from what it holds."""
import json

import numpy as np
import pytest

from tvcid.models import M000, M002
from tvcid.models.structures import Structure
from tvcid.studies.benchmarks.set_coverage import (GAUSSIAN_MEDIAN_POSITION, GOAL_QUANTITIES,
                                             coverage_goals, coverage_row, drop_old_layout,
                                             narrower_than_step, quantity_entry, rejudge_rows,
                                             summarise, truth_position, truth_quantities)
from tvcid.studies.benchmarks.set_judge import rejudge_entry, rejudge_row


def _q(lo, hi, mid=None, pinned=True, present=1.0, allowed=None, allowed_open=None, step=None,
       widened=False, support=None):
    """A combined quantity as ``combine`` writes it (``support``: its prior's range)."""
    return {"q05": lo, "q50": (lo + hi) / 2 if mid is None else mid, "q95": hi, "unit": "",
            "members": 1, "present": present, "depends_on_structure": False,
            "spread_over_width": 0.0, "width_over_prior": None, "pinned": pinned,
            "allowed": allowed,
            "allowed_open": (allowed_open or [False, False]) if allowed is not None else None,
            "step_error": step, "widened": widened, "support": support,
            "equal_weights": {"q05": lo, "q50": (lo + hi) / 2, "q95": hi}}


def _summary(quantities, converged=(True,), in_set=()):
    members = [{"structure": f"m{i}", "weight": 1 / len(converged), "converged": c,
                "posterior": {"not_pinned": []}} for i, c in enumerate(converged)]
    return {"indistinguishable": list(in_set),
            "set_posterior": {"quantities": quantities, "members": members}}


def _printed(truth, hit=True, at=0.0):
    """Every quantity of ``truth`` printed pinned, its interval 20 % of the truth wide with the
    truth ``at`` half-widths above its median (``hit``) or 20-40 % above the truth; the
    components it lacks printed absent (``hit``) or present."""
    out = {}
    for name, v in truth_quantities(truth).items():
        a = abs(v)
        mid = v - at * 0.1 * a
        out[name] = _q(mid - 0.1 * a, mid + 0.1 * a, mid=mid, step=1e-3 * a) if hit else \
            _q(v + 0.2 * a, v + 0.4 * a, mid=v + 0.3 * a, step=1e-3 * a)
    if not hit:
        for name in ("backlash", "friction_offset", "bandpass_gain"):
            out.setdefault(name, _q(1.0, 2.0))
    return out


def _row(truth, quantities, seed=1, **kw):
    return coverage_row(seed, truth, Structure.of_params(truth), _summary(quantities, **kw))


def test_truth_quantities_leave_out_the_components_the_truth_lacks():
    """M002 has neither a friction offset nor a band-pass loop; M000 has both and a threshold."""
    assert set(truth_quantities(M002())) == {"dead_zone[error]", "delay", "backlash", "dc_gain",
                                             "bandwidth"}
    assert {"friction_offset", "bandpass_gain", "threshold", "dead_zone[velocity]"} <= \
        set(truth_quantities(M000()))


def test_a_pinned_quantity_is_judged_on_its_interval_whatever_its_allowed_range():
    """A pinned delay whose interval just misses the truth is not covered even though the range
    the recordings allow holds it; a quantity without prior information (``pinned`` None) is
    judged on its interval too, which covers it where its allowed range does not."""
    truth = M002()
    printed = _printed(truth)
    d = truth.delay
    printed["delay"] = _q(1.01 * d, 2 * d, allowed=[0.5 * d, 3 * d])
    printed["dc_gain"] = {**printed["dc_gain"], "pinned": None, "allowed": [1.5, 2.0],
                          "allowed_open": [False, False]}
    row = _row(truth, printed, in_set=[Structure.of_params(truth).name])
    delay = row["quantities"]["delay"]
    assert delay["rule"] == "interval" and delay["covered"] is False
    assert delay["inside"] is False and delay["inside_allowed"] is True
    dc = row["quantities"]["dc_gain"]
    assert dc["rule"] == "interval" and dc["covered"] is True and dc["inside_allowed"] is False
    assert row["goals"]["dead_zone[error]"] is True and row["truth_in_set"]


def test_a_not_pinned_quantity_is_judged_on_the_allowed_range_an_open_end_on_the_priors_bound():
    """A not-pinned backlash whose interval lies under the truth (the prior's mass) is covered by
    an allowed range open at its ceiling when the prior's ceiling lies above the truth, even
    though the range's closed number lies under it; the same range closed there does not cover
    it; without an allowed range the interval judges, and the row says so."""
    truth = M002()
    b = truth.backlash
    printed = _printed(truth)
    printed["backlash"] = _q(0.01 * b, 0.5 * b, pinned=False, allowed=[1e-6, 0.8 * b],
                             allowed_open=[False, True], support=[1e-6, 3e-3])
    entry = _row(truth, printed)["quantities"]["backlash"]
    assert entry["rule"] == "allowed" and entry["covered"] is True and entry["inside"] is False
    assert entry["judged_range"] == [1e-6, 3e-3] and entry["prior_bound_source"] == "support"
    assert entry["prior_bounds"] == [1e-6, 3e-3] and entry["can_fail"] is True
    printed["backlash"] = _q(0.01 * b, 0.5 * b, pinned=False, allowed=[1e-6, 0.8 * b])
    entry = _row(truth, printed)["quantities"]["backlash"]
    assert entry["rule"] == "allowed" and entry["covered"] is False
    # a floor left open does not rescue a truth above the closed ceiling
    printed["backlash"] = _q(0.01 * b, 0.5 * b, pinned=False, allowed=[2 * b, 0.8 * b],
                             allowed_open=[True, False], support=[1e-6, 3e-3])
    assert _row(truth, printed)["quantities"]["backlash"]["covered"] is False
    printed["backlash"] = _q(0.01 * b, 0.5 * b, pinned=False)
    entry = _row(truth, printed)["quantities"]["backlash"]
    assert entry["rule"] == "interval" and entry["allowed_missing"] and entry["covered"] is False
    table = summarise([_row(truth, printed)])
    assert table["quantities"]["backlash"]["allowed_missing"] == 1


def test_a_truth_below_the_priors_floor_is_a_miss_on_a_range_open_at_its_lower_end():
    """A not-pinned delay printed "down to the prior's floor" (1.2 ms) with a true delay of
    0.9 ms: a miss, counted among the judgements that can fail and named beyond the prior; the
    same with the floor at 0.6 ms covers it. A stored row without the prior's bounds is judged
    on the floor the priors set whatever the fit where its draws end within 0.5 % above it; where
    they end elsewhere the row cannot say, and the judgement is undecided, counted apart."""
    truth = M002().replace(delay=9e-4)
    printed = _printed(truth)
    printed["delay"] = _q(1.5e-3, 8e-3, pinned=False, allowed=[1.2005e-3, 9e-3],
                          allowed_open=[True, False], support=[1.2e-3, 0.02])
    row = _row(truth, printed)
    e = row["quantities"]["delay"]
    assert (e["rule"], e["covered"], e["can_fail"]) == ("allowed", False, True)
    assert e["judged_range"] == [1.2e-3, 9e-3] and e["inside_allowed"] is False
    table = summarise([row])
    assert table["beyond_prior"] == [[1, "delay"]]
    assert (table["quantities"]["delay"]["covered"], table["quantities"]["delay"]["draws"]) == (0, 1)
    printed["delay"] = {**printed["delay"], "support": [6e-4, 0.02]}
    assert _row(truth, printed)["quantities"]["delay"]["covered"] is True

    stored = {**e, "prior_bounds": None, "prior_bounds_from": None}
    again = rejudge_row({**row, "quantities": {**row["quantities"], "delay": stored}}, "abc")
    d = again["quantities"]["delay"]
    assert (d["covered"], d["prior_bound_source"], d["judged_range"][0]) == (False, "fixed edge", 1.2e-3)
    assert again["goals"]["delay"] is False and again["judged_commit"] == "abc"
    far = {**stored, "allowed": [1.1e-3, 9e-3]}  # neither floor lies within 0.5 % under 1.1 ms
    again = rejudge_row({**row, "quantities": {**row["quantities"], "delay": far}}, "abc")
    d = again["quantities"]["delay"]
    assert d["covered"] is None and d["undecided"] and d["can_fail"] is None
    table = summarise([again])["quantities"]["delay"]
    assert (table["undecided"], table["draws"], table["cannot_fail"]) == (1, 0, 0)


def test_a_truth_of_0_against_present_or_absent_cannot_fail_and_leaves_the_goals_denominator():
    """M002 lacks a friction offset: printed "present or absent" it is covered but cannot fail,
    counted apart; printed absent (the set lacks it) or present it can fail. Over 30 draws the
    goal reads only the draws that can fail: 26 of 29 with three cannot-fail draws apart."""
    truth = M002()
    printed = _printed(truth)
    printed["friction_offset"] = _q(-0.01, 0.01, present=0.4)
    e = _row(truth, printed)["quantities"]["friction_offset"]
    assert (e["rule"], e["covered"], e["can_fail"]) == ("absent", True, False)
    assert _row(truth, printed)["cannot_fail"] == ["friction_offset"]
    del printed["friction_offset"]
    assert _row(truth, printed)["quantities"]["friction_offset"]["can_fail"] is True
    printed["friction_offset"] = _q(-0.01, 0.01)
    e = _row(truth, printed)["quantities"]["friction_offset"]
    assert (e["covered"], e["can_fail"]) == (False, True)

    rows = []
    for seed in range(30):
        printed = _printed(truth)
        if seed < 3:
            printed["friction_offset"] = _q(-0.01, 0.01, present=0.4)
        elif seed < 6:
            printed["friction_offset"] = _q(-0.01, 0.01)
        rows.append(_row(truth, printed, seed=seed))
    table = summarise(rows)
    f = table["quantities"]["friction_offset"]
    assert (f["covered"], f["draws"], f["cannot_fail"]) == (24, 27, 3)
    assert f["by_rule"]["absent"] == {"covered": 24, "draws": 27, "cannot_fail": 3}
    assert table["cannot_fail"] == {"present_or_absent": 3, "open_at_both_ends": 0}
    goal = next(g for g in coverage_goals(table) if g.what.startswith("friction_offset"))
    assert goal.measured == pytest.approx(24 / 27) and goal.met
    assert "24 of 27 = 89% (3 that cannot fail apart)" in goal.line()


def test_a_range_open_at_both_ends_holding_the_truth_cannot_fail_and_leaves_the_goals_denominator():
    """A not-pinned band-pass gain allowed over its prior's whole range (both ends open) holds
    the truth by what it prints: covered, cannot fail, out of the goal's count; over 30 draws,
    10 of them so, the goal reads 20 covered of 20."""
    truth = M000()
    g = truth.bandpass_gain
    printed = _printed(truth)
    printed["bandpass_gain"] = _q(0.1 * g, 5 * g, pinned=False, allowed=[3.001, 299.7],
                                  allowed_open=[True, True], support=[3.0, 300.0])
    e = _row(truth, printed)["quantities"]["bandpass_gain"]
    assert (e["rule"], e["covered"], e["can_fail"]) == ("allowed", True, False)
    rows = [_row(truth, printed if s < 10 else _printed(truth), seed=s) for s in range(30)]
    table = summarise(rows)
    b = table["quantities"]["bandpass_gain"]
    assert (b["covered"], b["draws"], b["cannot_fail"]) == (20, 20, 10)
    assert b["by_rule"]["allowed"] == {"covered": 0, "draws": 0, "cannot_fail": 10}
    assert table["cannot_fail"] == {"present_or_absent": 0, "open_at_both_ends": 10}
    assert table["beyond_prior"] == []


def test_rows_are_counted_by_the_commit_that_sampled_them_and_the_one_that_judged_them():
    """Three rows sampled at one commit, two judged again at another from the row alone (no
    chain), one sampled elsewhere: the summary counts them by each; judging a row again at its
    own sampling commit records no second commit."""
    truth = M002()
    rows = [{**_row(truth, _printed(truth), seed=s), "commit": c}
            for s, c in ((1, "aaa"), (2, "aaa"), (3, "aaa"), (4, "bbb"))]
    rows, n = rejudge_rows(rows[:2], everything=True, commit="ccc")
    rows += [{**_row(truth, _printed(truth), seed=s), "commit": c} for s, c in ((3, "aaa"), (4, "bbb"))]
    assert n == 2 and [r.get("judged_commit") for r in rows] == ["ccc", "ccc", None, None]
    assert summarise(rows)["commits"] == {"sampled": {"aaa": 3, "bbb": 1},
                                          "judged": {"ccc": 2, "aaa": 1, "bbb": 1}}
    assert "judged_commit" not in rejudge_row(rows[0], "aaa")
    # a row judged before the judge said which judgements can fail is not counted until judged
    bare = {**rows[2], "quantities": {n: {k: v for k, v in e.items() if k != "can_fail"}
                                      for n, e in rows[2]["quantities"].items()}}
    assert summarise([bare])["old_layout"] == 1
    again, n = rejudge_rows([bare, rows[3]], commit="ccc")
    assert n == 1 and again[0]["judged_commit"] == "ccc" and "judged_commit" not in again[1]
    assert summarise(again)["draws"] == 2


def test_the_stored_rows_are_what_their_judging_commit_gives_them():
    """The stored record's rows judged again from the rows alone, at their own judging commit
    (the sampling one where the row names no other), come out as stored: every verdict,
    cannot-fail mark and judged range."""
    from tvcid.studies.benchmarks.results_table import load_records

    rows = load_records()["bench_set_coverage"]["rows"]
    assert rows
    for r in rows:
        judged = r.get("judged_commit", r["commit"])
        assert r.get("judged_commit") != r["commit"]
        assert rejudge_row(r, judged) == r


def test_a_component_the_truth_lacks_is_covered_only_where_it_is_not_printed_present():
    """M002 lacks a friction offset and a band-pass loop: printed absent (the set lacks them) or
    "present or absent" (``present`` under 1) covers the truth; printed present does not, even
    with an interval reaching 0."""
    truth = M002()
    printed = _printed(truth)
    row = _row(truth, printed)
    for name in ("friction_offset", "bandpass_gain"):
        e = row["quantities"][name]
        assert (e["rule"], e["covered"], e["printed"], e["truth"]) == ("absent", True, "absent", None)
    printed["friction_offset"] = _q(-0.01, 0.01, present=0.4)
    printed["bandpass_gain"] = _q(0.0, 80.0, present=1.0)
    row = _row(truth, printed)
    assert row["quantities"]["friction_offset"]["printed"] == "present or absent"
    assert row["goals"]["friction_offset"] is True
    assert row["quantities"]["bandpass_gain"]["rule"] == "absent"
    assert row["goals"]["bandpass_gain"] is False
    # members holding under the deciding share: the report prints the component absent
    printed["bandpass_gain"] = _q(0.0, 80.0, present=0.03)
    row = _row(truth, printed)
    assert row["quantities"]["bandpass_gain"]["printed"] == "absent"
    assert row["goals"]["bandpass_gain"] is True
    # a stored row judged by the earlier rule ("present") is judged again as printed
    stored = {**row["quantities"]["bandpass_gain"], "printed": "present", "covered": False}
    again = rejudge_entry("bandpass_gain", stored)
    assert (again["printed"], again["covered"]) == ("absent", True)


def test_a_component_the_truth_has_and_the_report_prints_absent_is_a_miss():
    """The truth has a backlash; the members with one hold 3 % of the weight, so the report
    prints it absent (its interval only "if present"): not covered, whatever that interval."""
    truth = M002()
    printed = _printed(truth)
    b = truth.backlash
    printed["backlash"] = _q(0.5 * b, 2.0 * b, present=0.03)
    e = _row(truth, printed)["quantities"]["backlash"]
    assert (e["printed"], e["rule"], e["covered"], e["can_fail"]) == ("absent", "lacking", False,
                                                                       True)


def test_a_component_the_set_leaves_open_is_printed_present_or_absent_whichever_members_calibrated():
    """Only members with a band-pass loop calibrated (``present`` 1.0), but the set leaves the
    loop open: printed "present or absent", so M002's absent loop is covered; a friction offset
    the set leaves open and no calibrated member holds is printed "present or absent" without an
    interval: covered where the truth lacks it, ``lacking`` where the truth has it."""
    truth = M002()
    printed = _printed(truth)
    printed["bandpass_gain"] = {**_q(0.0, 80.0), "left_open": True}
    summary = _summary(printed)
    summary["set_posterior"]["left_open_uncalibrated"] = ["friction_offset"]
    row = coverage_row(1, truth, Structure.of_params(truth), summary)
    for name in ("bandpass_gain", "friction_offset"):
        e = row["quantities"][name]
        assert (e["rule"], e["covered"], e["printed"]) == ("absent", True, "present or absent")
    truth = M000()
    printed = _printed(truth)
    del printed["friction_offset"]
    summary = _summary(printed)
    summary["set_posterior"]["left_open_uncalibrated"] = ["friction_offset"]
    e = coverage_row(1, truth, Structure.of_params(truth), summary)["quantities"]["friction_offset"]
    assert (e["rule"], e["covered"], e["printed"]) == ("lacking", False, "present or absent")


def test_a_quantity_the_truth_has_and_the_report_prints_absent_is_not_covered():
    """M002's backlash decided absent, and M000's dead zone on the velocity signal where every
    member puts it on the error: rule ``lacking``, not covered; the error place M000 lacks is
    printed but not judged. A component the set leaves open and the truth has is judged on its
    interval if present."""
    truth = M002()
    printed = _printed(truth)
    del printed["backlash"]
    e = _row(truth, printed)["quantities"]["backlash"]
    assert (e["rule"], e["covered"], e["printed"]) == ("lacking", False, "absent")

    truth = M000()
    printed = _printed(truth)
    printed["dead_zone[error]"] = printed.pop("dead_zone[velocity]")
    printed["backlash"] = {**printed["backlash"], "present": 0.3}
    row = _row(truth, printed)
    assert row["quantities"]["dead_zone[velocity]"]["rule"] == "lacking"
    assert row["goals"]["dead_zone[velocity]"] is False
    assert row["quantities"]["dead_zone[error]"]["rule"] is None
    assert "dead_zone[error]" not in row["goals"]
    backlash = row["quantities"]["backlash"]
    assert backlash["printed"] == "present or absent" and backlash["rule"] == "interval"
    assert backlash["covered"] is True


def test_widths_are_relative_to_the_median_for_intervals_judged_on_them_and_the_table_takes_the_median():
    """``(q95 - q05) / |q50|`` for a pinned interval, none for one judged on its allowed range;
    the table's median runs over the rows."""
    truth = M002()
    d = truth.delay
    rows = []
    for seed, half in ((1, 0.1), (2, 0.2), (3, 0.4)):
        printed = _printed(truth)
        printed["delay"] = _q(d * (1 - half), d * (1 + half), mid=d)
        printed["backlash"] = _q(0.0, 2 * truth.backlash, pinned=False,
                                 allowed=[0.0, 3 * truth.backlash])
        rows.append(_row(truth, printed, seed=seed))
    assert rows[0]["quantities"]["delay"]["relative_width"] == pytest.approx(0.2)
    assert rows[0]["quantities"]["backlash"]["relative_width"] is None
    table = summarise(rows)
    assert table["quantities"]["delay"]["median_relative_width"] == pytest.approx(0.4)
    assert table["quantities"]["delay"]["widths"] == 3
    assert table["quantities"]["backlash"]["median_relative_width"] is None
    assert table["quantities"]["backlash"]["by_rule"]["allowed"] == {"covered": 3, "draws": 3,
                                                                     "cannot_fail": 0}


def test_an_interval_narrower_than_twice_its_step_error_is_counted_and_fails_its_goal():
    """A DC gain interval 8e-5 wide with a step error of 5e-5, not widened: narrower; one widened
    to exactly the median +- the step error is not; without a step error nothing is judged. The
    count fails the goal over 30 draws."""
    truth = M002()
    printed = _printed(truth)
    printed["dc_gain"] = _q(1.0 - 4e-5, 1.0 + 4e-5, mid=1.0, step=5e-5)
    printed["delay"] = _q(truth.delay - 1e-4, truth.delay + 1e-4, mid=truth.delay, step=1e-4,
                          widened=True)
    printed["backlash"] = {**printed["backlash"], "step_error": None}
    row = _row(truth, printed)
    assert row["narrower_than_step"] == ["dc_gain"]
    assert row["quantities"]["dc_gain"]["narrower_than_step"] is True
    assert row["quantities"]["delay"]["narrower_than_step"] is False
    assert row["quantities"]["delay"]["widened"] is True
    assert row["quantities"]["backlash"]["narrower_than_step"] is None
    # a delay widened to its prior's floor (the support cuts the median - the step error) is not
    # narrower; the same interval without the support it stops at is
    cut = {**_q(6e-4, 6e-3, mid=2e-3, step=4e-3, widened=True), "support": [6e-4, 0.05]}
    assert narrower_than_step(cut) is False
    assert narrower_than_step({**cut, "support": None}) is True
    table = summarise([row])
    # dead zone and bandwidth carry _printed's step error of 1e-3 of their value: wide enough
    assert table["step"] == {"intervals": 4, "narrower": 1, "widened": 1, "without_step_error": 1}
    table = summarise([row] + [_row(truth, _printed(truth), seed=s) for s in range(2, 31)])
    step_goal = coverage_goals(table)[-1]
    assert table["step"]["narrower"] == 1 and not step_goal.met


def _mixed_rows(misses_per_truth):
    """30 rows, 15 of M000 and 15 of M002, ``misses_per_truth`` of each printing every interval
    20-40 % above the truth and every component the truth lacks present."""
    rows = []
    for i in range(30):
        truth = M000() if i % 2 else M002()
        hit = i // 2 >= misses_per_truth
        rows.append(_row(truth, _printed(truth, hit=hit, at=0.4), seed=1000 + i,
                         converged=(True,) if i % 3 else (True, False)))
    return rows


def test_over_thirty_draws_every_printed_quantity_meets_its_band_and_full_coverage_does_not():
    """2 misses in each truth's 15 draws: 13 of 15 for each dead-zone place and the threshold,
    26 of 30 for the shared quantities, the covered truths 0.4 half-widths from their medians, no
    narrower interval: every goal met. With no miss, 100 % is above the band: coverage bought by
    width fails; with every truth at its median, so does the position's goal. The same shares
    over 29 draws judge nothing."""
    rows = _mixed_rows(2)
    table = summarise(rows)
    assert table["draws"] == 30 and table["quantities"]["dead_zone[velocity]"]["draws"] == 15
    assert table["quantities"]["delay"]["covered"] == 26
    assert table["quantities"]["friction_offset"]["by_rule"] == {
        "interval": {"covered": 13, "draws": 15, "cannot_fail": 0},
        "allowed": {"covered": 0, "draws": 0, "cannot_fail": 0},
        "absent": {"covered": 13, "draws": 15, "cannot_fail": 0},
        "lacking": {"covered": 0, "draws": 0, "cannot_fail": 0}}
    goals = coverage_goals(table)
    assert len(goals) == len(GOAL_QUANTITIES) + 2 and all(g.met for g in goals)
    assert table["position"]["median_abs"] == pytest.approx(0.4)
    assert not any(g.met for g in coverage_goals(summarise(rows[:-1])))
    goals = coverage_goals(summarise(_mixed_rows(0)))
    assert not any(g.met for g in goals[:len(GOAL_QUANTITIES)]) and all(g.met for g in goals[-2:])
    at_median = [_row(r_truth, _printed(r_truth), seed=s)
                 for s, r_truth in enumerate([M000(), M002()] * 15)]
    position_goal = coverage_goals(summarise(at_median))[-2]
    assert position_goal.what.startswith("the truths' median distance") and not position_goal.met


def test_the_table_counts_chains_stopped_at_the_cap_apart_and_old_or_failed_rows_apart():
    """Draws with a member stopped at its cap are counted, in their own part; a failed row and a
    row of the earlier layout (no ``rule``) are counted and not judged; under 30 draws no goal
    is met."""
    rows = _mixed_rows(2)[2:8]  # i = 2..7: i = 2, 3 miss, the others hit
    rows[0]["design"] = {"recordings": [{"kind": "closed"}]}
    old = {"seed": 5, "structure": "s", "truth_in_set": True, "members": ["s"], "converged": True,
           "quantities": {"delay": {"truth": 1.0, "q05": 0.0, "q95": 2.0, "inside": True}},
           "goals": {"delay": True}}
    table = summarise(rows + [old, {"seed": 7, "error": "boom"}])
    assert (table["draws"], table["old_layout"], table["failed"]) == (6, 1, 1)
    stopped = table["by_chains"]["stopped at the cap"]
    assert stopped["draws"] == 2 and table["by_chains"]["converged"]["draws"] == 4
    # i = 3 (a miss) and 6 (a hit) stop at the cap; of the converged, i = 2 misses
    assert stopped["quantities"]["delay"] == {"covered": 1, "draws": 2, "cannot_fail": 0,
                                              "undecided": 0}
    assert table["by_chains"]["converged"]["quantities"]["delay"]["covered"] == 3
    assert table["by_chains"]["converged"]["quantities"]["delay"]["draws"] == 4
    assert table["converged"] == 4 and table["cycles_only"] == {"draws": 1, "converged": 1}
    assert [r["stopped_at_cap"] for r in rows[:2]] == [[], ["m1"]]
    assert not any(g.met for g in coverage_goals(table))


def test_the_claim_counts_the_stored_draws_and_judges_none_under_thirty():
    """docs/results.md's row for the set coverage: the finished draws, the rows of an earlier
    layout counted apart, each printed quantity's count, the chains' split, the allowed ranges'
    counts, the widths and the misses by cause; under 30 draws no goal is met, whatever the
    share."""
    from tvcid.studies.benchmarks.claim_values import set_coverage

    truth = M002()
    printed = _printed(truth)
    printed["backlash"] = _q(0.0, 0.5 * truth.backlash, pinned=False,
                             allowed=[0.0, 2 * truth.backlash])
    rows = [{**_row(truth, printed, seed=s, converged=(True, True), in_set=["x"]), "commit": "aaa"}
            for s in (1000, 1001)]
    rows[1]["judged_commit"] = "bbb"
    rows[0]["cost"] = {"kernel_steps": 4e9, "cpu_seconds": 900.0, "wall_seconds": 600.0}
    rows[1].update(cost={"kernel_steps": 9e9, "cpu_seconds": 2000.0, "wall_seconds": 1300.0},
                   chains_carried_over=True)
    rows[1]["misses"] = [{"quantity": "delay", "cause": "weight elsewhere"}]
    old = {"seed": 1003, "structure": "s", "truth_in_set": True, "members": ["s"],
           "converged": True, "quantities": {"delay": {"truth": 1.0, "inside": True}}}
    text = set_coverage({"bench_set_coverage": {
        "rows": rows + [{"seed": 1002, "error": "boom"}, old]}})
    assert text.startswith("2 of 30 draws finished (seeds 1000-1003, 1 failed, 1 of an earlier "
                           "layout, not counted; rows sampled at `aaa` (2); rows judged at "
                           "`aaa` (1), `bbb` (1))")
    assert "goal delay: truth covered by what the report prints, where that can fail: 2 of 2" in text
    assert ("goal friction_offset: truth covered by what the report prints, where that can fail: "
            "2 of 2 = 100%") in text
    assert ("judgements that cannot fail, apart from the goals: 0 (a truth of 0 against \"present "
            "or absent\" 0, a truth inside the prior against a range open at both ends 0); misses "
            "whose truth lies beyond the prior's bound an open end stands for: none") in text
    assert text.count("NOT met") == len(GOAL_QUANTITIES) + 2
    # a draw resumed from an earlier run's directory counts only its last run: left out
    assert ("cost of a draw run in one piece (1 draws), median [largest]: 4e+09 [4e+09] kernel "
            "steps, 900 [900] CPU s, 600 [600] wall s") in text
    assert "draws whose every chain converged: 2 (dead_zone[error] 2 of 2 covered" in text
    assert "draws with a chain stopped at its cap: 0;" in text
    assert "truth inside the range the recordings allow: backlash 2 of 2" in text
    assert "median relative width of the intervals judged: dead_zone[error] 0.2" in text
    assert "members calibrated per draw 1-2" in text
    assert "misses by cause (1 draws explained): weight elsewhere 1 (delay of draw 1001)" in text


def test_a_rerun_drops_the_rows_of_the_earlier_layout_so_their_draws_run_again(tmp_path):
    """``bench.json``'s rows without rules are removed (a failed row and a current one stay)."""
    truth = M002()
    current = _row(truth, _printed(truth), seed=1000)
    old = {"seed": 1001, "structure": "s", "truth_in_set": True, "members": ["s"],
           "converged": True, "quantities": {"delay": {"truth": 1.0, "inside": True}}}
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({"quick": False, "rows": [current, old, {"seed": 1002, "error": "x"}]}))
    assert drop_old_layout(path) == 1
    assert [r["seed"] for r in json.loads(path.read_text())["rows"]] == [1000, 1002]
    assert drop_old_layout(path) == 0 and drop_old_layout(tmp_path / "none.json") == 0


def test_the_truths_position_tells_calibrated_intervals_from_too_wide_ones():
    """Truths drawn (seeded) from a Gaussian around each printed median: with the Gaussian's own
    90 % half-width (1.645 sd) the median |position| comes out near 0.41, its calibrated value;
    with intervals twice as wide, near half that; a truth at an end sits at +-1, one outside
    beyond it, and an entry judged on another rule has no position."""
    rng = np.random.default_rng(11)

    def median_position(scale):
        entries = []
        for _ in range(400):
            truth = rng.standard_normal()
            half = 1.6449 * scale
            entries.append(quantity_entry("delay", truth, _q(-half, half, mid=0.0)))
        rows = [{"seed": 1, "quantities": {f"q{i}": e for i, e in enumerate(entries)},
                 "members": ["a"], "converged": True, "truth_in_set": True}]
        return summarise(rows)["position"]

    calibrated, wide = median_position(1.0), median_position(2.0)
    assert calibrated["intervals"] == 400
    assert calibrated["median_abs"] == pytest.approx(GAUSSIAN_MEDIAN_POSITION, abs=0.06)
    assert wide["median_abs"] == pytest.approx(GAUSSIAN_MEDIAN_POSITION / 2, abs=0.04)
    assert wide["within_half"] > calibrated["within_half"] + 0.2
    entry = {"rule": "interval", "truth": 1.3, "q05": 1.0, "q50": 1.1, "q95": 1.3}
    assert truth_position(entry) == pytest.approx(1.0)
    assert truth_position({**entry, "truth": 0.8}) == pytest.approx(-3.0)
    assert truth_position({**entry, "rule": "allowed"}) is None


def test_the_printed_choices_are_judged_against_the_truth_by_this_codes_rule_and_the_runs(tmp_path):
    """A run whose truth (backlash on, before the first integrator) is merged into a member
    without backlash, and whose member with backlash at another place takes the weight: its
    stored choices print that other place, wrong; this code's rule leaves the place open. The
    counts, the goal (none wrong) and their words say both."""
    from tvcid.studies.benchmarks.set_coverage import read_from_draw
    from tvcid.studies.benchmarks.verdicts import choices_text, printed_choice_counts

    truth = "dz_error+delay_before_first_integrator+backlash+bandpass"
    member = "dz_error+delay_before_first_integrator+bandpass"
    heavy = "dz_error+delay_before_integrator+backlash+bandpass"
    rows_ = [{"structure": n, "indistinguishable_from_best": True, "merged_into": into}
             for n, into in ((heavy, None), (member, None), (truth, member))]
    stored = {"value": "before_integrator", "by": "weights", "weights": {}, "unsure": []}
    discovery = {"structures": rows_, "indistinguishable": [heavy, member, truth],
                 "decided": {"dead_zone_position": "error", "delay_position": None,
                             "friction": False, "backlash": None, "bandpass": True},
                 "set_posterior": {"members": [{"structure": heavy, "weight": 1.0},
                                               {"structure": member, "weight": 1e-30}],
                                   "unsure": [], "choices": {"delay_position": stored}}}
    (tmp_path / "discover").mkdir()
    (tmp_path / "discover" / "discovery.json").write_text(json.dumps(discovery))
    row = read_from_draw({"seed": 3015, "structure": truth, "quantities": {}}, tmp_path)
    choices = row["printed_choices"]
    assert choices["delay_position"] == {"value": None, "by": "open", "verdict": "open",
                                         "stored": {"value": "before_integrator",
                                                    "verdict": "wrong"}}
    assert choices["backlash"]["verdict"] == "right" and choices["backlash"]["by"] == "weights"
    assert choices["friction"]["verdict"] == "right" and choices["friction"]["stored"] is None
    wrong = {**row, "seed": 3016, "printed_choices": {
        **choices, "delay_position": {"value": "output", "by": "weights", "verdict": "wrong",
                                      "stored": None}}}
    counts = printed_choice_counts([row, wrong, {"seed": 1, "error": "boom"}])
    assert counts["draws"] == 2 and counts["open"] == 1 and counts["right"] == 8
    assert counts["by_weights"] == 2
    assert counts["wrong"] == [[3016, "delay_position", "output", "weights"]]
    assert counts["stored_wrong"] == [[3015, "delay_position", "before_integrator"]]
    assert choices_text(counts) == (
        "structural choices as printed over 2 draws: 8 right (2 of them by the weights), 1 "
        "open, 1 wrong (draw 3016 delay_position output (by the weights)); as the sampling "
        "commit printed them, wrong: draw 3015 delay_position before_integrator")
    goal = coverage_goals({**summarise(_mixed_rows(2)), "choices": counts})[-1]
    assert goal.what.startswith("structural choices printed wrongly") and not goal.met
    assert read_from_draw({"seed": 1, "error": "boom"}, tmp_path) == {"seed": 1, "error": "boom"}


def test_a_row_names_the_machine_whose_arithmetic_sampled_it():
    """Beside its commit, a row names the processor and the SIMD target numpy dispatches to on
    it: the widest of numpy's targets whose features this processor has."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    from tvcid.studies.benchmarks.set_coverage import MACHINE

    truth = M002()
    assert _row(truth, _printed(truth))["machine"] == MACHINE
    has = [t for t in __cpu_dispatch__ if __cpu_features__[t]]
    assert MACHINE["numpy_simd"] == (has[-1] if has else None)
    assert MACHINE["cpu"] and MACHINE["numba_cpu"]
