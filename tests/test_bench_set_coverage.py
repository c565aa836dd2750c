"""studies.benchmarks.set_coverage: a draw's row says, per combined quantity, whether the printed
90 % interval holds the truth; the goals read the threshold for a velocity-form truth."""
from models import M000, M002
from models.structures import Structure
from studies.benchmarks.set_coverage import coverage_goals, coverage_row, summarise


def _summary(intervals, members=("a",), converged=True, in_set=(), allowed=None):
    allowed = allowed or {}
    return {"indistinguishable": list(in_set),
            "set_posterior": {"quantities": {k: {"q05": lo, "q95": hi, "allowed": allowed.get(k)}
                                             for k, (lo, hi) in intervals.items()},
                              "members": [{"structure": m, "converged": converged,
                                           "posterior": {"not_pinned": []}} for m in members]}}


def test_row_reads_the_threshold_for_a_velocity_truth_and_counts_a_missing_place_outside():
    """M000 (dead zone on the velocity signal): the dead-zone goal is the threshold z - off; a
    set whose members all put the dead zone on the error has no ``dead_zone[velocity]``, which
    counts as outside; an interval just missing the truth is outside."""
    truth = M000()
    c = truth.dead_zone - truth.friction_offset
    summary = _summary({"threshold": (0.9 * c, 1.1 * c), "backlash": (0.0, 0.5 * truth.backlash),
                        "delay": (truth.delay, 2 * truth.delay), "dead_zone[error]": (1e-3, 2e-3)},
                       in_set=[Structure.of_params(truth).name])
    row = coverage_row(1, truth, Structure.of_params(truth), summary)
    assert row["goals"] == {"dead zone": True, "backlash": False, "delay": True}
    assert row["quantities"]["dead_zone[velocity]"]["inside"] is False
    assert row["truth_in_set"] and row["converged"]


def test_error_form_truth_and_the_goals_over_rows():
    """M002 (dead zone on the error): the goal reads ``dead_zone[error]``; the table counts the
    rows, and the goals are not met under 30 draws whatever the share."""
    truth = M002()
    summary = _summary({"dead_zone[error]": (0.5 * truth.dead_zone, 2 * truth.dead_zone),
                        "backlash": (0.5 * truth.backlash, 2 * truth.backlash),
                        "delay": (0.5 * truth.delay, 0.9 * truth.delay)}, converged=False)
    row = coverage_row(2, truth, Structure.of_params(truth), summary)
    assert row["goals"] == {"dead zone": True, "backlash": True, "delay": False}
    table = summarise([row, {"seed": 3, "error": "boom"}])
    assert table["draws"] == 1 and table["failed"] == 1 and table["converged"] == 0
    assert table["inside"] == {"dead zone": 1, "backlash": 1, "delay": 0}
    assert not any(g.met for g in coverage_goals(table))


def test_the_table_splits_coverage_by_the_chains_convergence_and_counts_cycles_only_draws():
    """A draw whose chains stopped at their cap and one whose chains converged are counted apart,
    each with its goals' truths inside; a draw without open-loop tests counts as limit cycles
    alone, one with a test does not."""
    truth = M002()
    good = {"dead_zone[error]": (0.5 * truth.dead_zone, 2 * truth.dead_zone),
            "backlash": (0.5 * truth.backlash, 2 * truth.backlash),
            "delay": (0.5 * truth.delay, 2 * truth.delay)}
    bad = {**good, "backlash": (0.1 * truth.backlash, 0.5 * truth.backlash)}
    rows = []
    for seed, intervals, converged, kinds in ((1, good, True, ("closed", "open")),
                                              (2, bad, False, ("closed", "closed")),
                                              (3, good, False, ("closed",))):
        row = coverage_row(seed, truth, Structure.of_params(truth),
                           _summary(intervals, converged=converged))
        row["design"] = {"recordings": [{"kind": k} for k in kinds]}
        rows.append(row)
    table = summarise(rows)
    assert table["by_chains"]["converged"] == {
        "draws": 1, "inside": {"dead zone": 1, "backlash": 1, "delay": 1}}
    assert table["by_chains"]["stopped at the cap"] == {
        "draws": 2, "inside": {"dead zone": 2, "backlash": 1, "delay": 2}}
    assert table["cycles_only"] == {"draws": 2, "converged": 0}


def test_the_claim_counts_the_stored_draws_and_judges_none_under_thirty():
    """docs/results.md's row for the set coverage: the finished draws, each goal's count, the
    failed draw and the set sizes; under 30 draws no coverage goal is met, whatever the share."""
    from studies.benchmarks.results_table import set_coverage

    truth = M002()
    summary = _summary({"dead_zone[error]": (0.5 * truth.dead_zone, 2 * truth.dead_zone),
                        "backlash": (0.5 * truth.backlash, 2 * truth.backlash),
                        "delay": (0.5 * truth.delay, 0.9 * truth.delay)},
                       members=("a", "b"), in_set=[Structure.of_params(truth).name])
    rows = [coverage_row(s, truth, Structure.of_params(truth), summary) for s in (1000, 1001)]
    text = set_coverage({"bench_set_coverage": {"rows": rows + [{"seed": 1002, "error": "boom"}]}})
    assert text.startswith("2 of 30 draws finished (seeds 1000-1002, 1 failed)")
    assert "dead zone: truth inside the combined 90 % interval: 2 of 2 = 100%" in text
    assert "delay: truth inside the combined 90 % interval: 0 of 2 = 0%" in text
    assert text.count("NOT met") == 3  # three coverage goals under 30 draws; the chains' goal met
    assert "truth's structure in the set in 2 of 2" in text and "per draw 2-2" in text
    assert "draws whose every chain converged: 2 (dead zone 2 inside, backlash 2 inside, delay 0 " \
        "inside); draws with a chain stopped at its cap: 0;" in text


def test_the_row_and_the_table_count_truths_inside_the_range_the_recordings_allow():
    """A backlash interval under the truth (the prior's mass) with an allowed range that holds it:
    outside the interval, inside the range; a delay without a range counts in neither the
    range's hits nor its draws; a quantity the set lacks is outside both. The claim's text
    prints the counts."""
    from studies.benchmarks.results_table import set_coverage

    truth = M002()
    intervals = {"dead_zone[error]": (0.5 * truth.dead_zone, 2 * truth.dead_zone),
                 "backlash": (0.01 * truth.backlash, 0.8 * truth.backlash),
                 "delay": (0.5 * truth.delay, 2 * truth.delay)}
    allowed = {"dead_zone[error]": [0.4 * truth.dead_zone, 3 * truth.dead_zone],
               "backlash": [1e-6, 1.2 * truth.backlash]}
    in_set = [Structure.of_params(truth).name]
    row = coverage_row(1, truth, Structure.of_params(truth),
                       _summary(intervals, allowed=allowed, in_set=in_set))
    assert row["goals"] == {"dead zone": True, "backlash": False, "delay": True}
    assert row["goals_allowed"] == {"dead zone": True, "backlash": True, "delay": None}
    table = summarise([row])
    assert table["allowed"] == {"dead zone": {"inside": 1, "draws": 1},
                                "backlash": {"inside": 1, "draws": 1},
                                "delay": {"inside": 0, "draws": 0}}
    text = set_coverage({"bench_set_coverage": {"rows": [row]}})
    assert "truth inside the range the recordings allow: dead zone 1 of 1, backlash 1 of 1, " \
        "delay 0 of 0" in text
    lacking = coverage_row(2, M000(), Structure.of_params(M000()), _summary(intervals, allowed=allowed))
    assert lacking["goals_allowed"]["dead zone"] is False
