"""Why a printed quantity misses its truth (tvcid.studies.benchmarks.set_misses)."""
import json

from tvcid.studies.benchmarks.set_misses import (
    CAUSES,
    cause_counts,
    miss_causes,
    truth_member,
    with_miss_causes,
)

TRUTH = "dz_velocity+delay_before_integrator+backlash"
NEIGHBOUR = "dz_velocity+delay_output+backlash"
RICHER = "dz_velocity+delay_before_integrator+friction+backlash"


def _member(name, weight, converged, delay, bandwidth):
    return {"structure": name, "weight": weight, "converged": converged,
            "quantities": {"delay": {"q05": delay[0], "q50": sum(delay) / 2, "q95": delay[1]},
                           "bandwidth": {"q05": bandwidth[0], "q50": sum(bandwidth) / 2,
                                         "q95": bandwidth[1]}}}


def _discovery(members, inside=(TRUTH, NEIGHBOUR), merged=None):
    structures = [{"structure": n, "indistinguishable_from_best": n in inside,
                   "merged_into": (merged or {}).get(n)} for n in (TRUTH, NEIGHBOUR, RICHER)]
    return {"indistinguishable": list(inside), "structures": structures,
            "set_posterior": {"members": members}}


def _entry(rule, truth, covered=False, can_fail=True):
    return {"rule": rule, "truth": truth, "covered": covered, "can_fail": can_fail,
            "present": 0.02}


def _row(quantities, structure=TRUTH, seed=7):
    return {"seed": seed, "structure": structure, "quantities": quantities}


def test_each_miss_is_told_by_the_truths_own_member():
    """The truth's member's own interval holds the truth: the weights printed it away; it
    misses: its chain converged or stopped at the cap; out of the set or not calibrated: no
    member to read; a component printed against the truth: presence. Covered quantities and
    judgements that cannot fail are not misses; the facts behind each cause are kept."""
    held = _discovery([_member(TRUTH, 0.01, True, (2e-3, 3e-3), (30.0, 40.0)),
                       _member(NEIGHBOUR, 0.99, True, (0.5e-3, 1e-3), (42.0, 45.0))])
    row = _row({"delay": _entry("interval", 2.5e-3), "bandwidth": _entry("interval", 50.0),
                "backlash": _entry("interval", 1e-4, covered=True),
                "friction_offset": _entry("lacking", 1e-3),
                "bandpass_gain": _entry("allowed", 30.0, can_fail=False)})
    causes = {m["quantity"]: m for m in miss_causes(row, held)}
    assert set(causes) == {"delay", "bandwidth", "friction_offset"}
    assert causes["delay"]["cause"] == "weight elsewhere"
    assert causes["delay"]["truth_member_interval"] == [2e-3, 3e-3]
    assert (causes["delay"]["heaviest"], causes["delay"]["heaviest_weight"]) == (NEIGHBOUR, 0.99)
    assert causes["bandwidth"]["cause"] == "member misses, converged"
    assert causes["friction_offset"]["cause"] == "presence"

    stuck = _discovery([_member(TRUTH, 0.01, False, (7e-3, 9e-3), (28.0, 31.0))])
    assert miss_causes(row, stuck)[0]["cause"] == "member misses, stopped at the cap"
    out = _discovery([_member(NEIGHBOUR, 1.0, True, (0.5e-3, 1e-3), (42.0, 45.0))],
                     inside=(NEIGHBOUR,))
    assert miss_causes(row, out)[0]["cause"] == "out of the set"
    uncalibrated = _discovery([_member(NEIGHBOUR, 1.0, True, (0.5e-3, 1e-3), (42.0, 45.0))])
    assert miss_causes(row, uncalibrated)[0]["cause"] == "not calibrated"


def test_a_truth_merged_into_a_member_is_read_on_that_member():
    """A truth whose structure is merged into a calibrated member, directly or through a
    structure merged in turn, is that member's: its interval holding the truth, the weights
    printed it away; missing it, the member lacks components the truth has."""
    discovery = _discovery([_member(TRUTH, 1.0, True, (2e-3, 3e-3), (30.0, 40.0))],
                           inside=(TRUTH, RICHER), merged={RICHER: TRUTH})
    assert truth_member(RICHER, discovery)["structure"] == TRUTH
    row = _row({"delay": _entry("interval", 2.5e-3), "bandwidth": _entry("interval", 50.0)},
               structure=RICHER)
    causes = [m["cause"] for m in miss_causes(row, discovery)]
    assert causes == ["weight elsewhere", "merged into a simpler member"]
    chained = _discovery([_member(TRUTH, 1.0, True, (2e-3, 3e-3), (30.0, 40.0))],
                         inside=(TRUTH, NEIGHBOUR, RICHER),
                         merged={RICHER: NEIGHBOUR, NEIGHBOUR: TRUTH})
    assert truth_member(RICHER, chained)["structure"] == TRUTH
    looped = _discovery([], inside=(NEIGHBOUR, RICHER),
                        merged={RICHER: NEIGHBOUR, NEIGHBOUR: RICHER})
    assert truth_member(RICHER, looped) is None


def test_causes_are_read_from_the_draws_directory_and_counted(tmp_path):
    """A row is explained from its draw's discovery.json, left as it is without one, and the
    counts list each miss under its cause."""
    held = _discovery([_member(TRUTH, 0.01, True, (2e-3, 3e-3), (30.0, 40.0)),
                       _member(NEIGHBOUR, 0.99, True, (0.5e-3, 1e-3), (42.0, 45.0))])
    (tmp_path / "draw7" / "discover").mkdir(parents=True)
    (tmp_path / "draw7" / "discover" / "discovery.json").write_text(json.dumps(held))
    row = _row({"delay": _entry("interval", 2.5e-3)})
    explained = with_miss_causes(row, tmp_path / "draw7")
    assert with_miss_causes(row, tmp_path / "draw8") is row
    counts = cause_counts([explained, _row({}, seed=8)])
    assert counts["draws"] == 1 and list(counts["causes"]) == list(CAUSES)
    assert counts["causes"]["weight elsewhere"] == [[7, "delay"]]
    assert sum(map(len, counts["causes"].values())) == 1


def test_the_truths_fit_is_weighed_against_the_true_parameters_on_the_draws_recordings():
    """On the bundled draw 1000 (two limit cycles within the papers' ranges), the true
    parameters' own cost is computed from the recordings; a fit of the truth's structure at or
    below it is a second mode as good as the truth, one above it is not."""
    from pathlib import Path

    from tvcid.studies.benchmarks.scenarios import draw_scenario
    from tvcid.studies.benchmarks.set_misses import fit_against_truth

    bundled = Path(__file__).resolve().parents[1] / "data" / "bench" / "draw1000"
    name = draw_scenario(1000, ranges="papers").structure.name
    row = {"seed": 1000, "structure": name, "design": {"ranges": "papers"}}

    def discovery(cost):
        return {"structures": [{"structure": name, "cost": cost}]}

    at_truth = fit_against_truth(row, discovery(0.0), bundled)["cost_at_truth"]
    assert 0.0 < at_truth < 10.0
    assert fit_against_truth(row, discovery(0.9 * at_truth), bundled)["as_good_as_truth"]
    assert not fit_against_truth(row, discovery(1.1 * at_truth), bundled)["as_good_as_truth"]
    assert fit_against_truth(row, discovery(0.0), bundled / "absent") is None
    counts = cause_counts([{"seed": 1000, "misses": [
        {"quantity": "delay", "cause": "member misses, converged"}],
        "fit_against_truth": {"as_good_as_truth": True}}])
    assert counts["second_mode"] == [[1000, "delay"]]
