"""One verdict per component: the summary's "decided" / "not decided", its table's "present or
absent" and the members' weights come from one rule
(:func:`tvcid.discovery.members.set_weights.weighed_choices`, :data:`DECIDING_SHARE`), and every
row's words agree with each other."""
import numpy as np
import pytest

from tvcid.discovery.members.set_posterior import MemberPosterior, combine, decided_absent
from tvcid.discovery.members.set_weights import weighed_choices
from tvcid.discovery.structure.indistinguishable import DECIDING_SHARE
from tvcid.report import summary_lines

A = "dz_velocity+delay_before_first_integrator+friction+backlash"
B = "dz_velocity+delay_output+friction+backlash"
C = "dz_velocity+delay_before_first_integrator+friction+backlash+bandpass"
D = "dz_velocity+delay_output+friction+backlash+bandpass"
DECIDED = {"dead_zone_position": "velocity", "delay_position": None, "friction": True,
           "backlash": True, "bandpass": None}


def _member(name, rng, bandpass=False, n=4000):
    q = {"delay": 2e-3 + 1e-5 * rng.standard_normal(n),
         "dead_zone[velocity]": 8e-3 + 1e-5 * rng.standard_normal(n)}
    if bandpass:
        q["bandpass_gain"] = 70 + rng.standard_normal(n)
    return MemberPosterior(name, q, {"converged": True}, 0.0)


def _summary(weights, choices_weights=None):
    rng = np.random.default_rng(1)
    members = [_member(n, rng, bandpass=n == C) for n in weights]
    sp = combine(members, weights=list(weights.values()), seed=1).to_dict()
    sp["choices"] = weighed_choices(DECIDED, choices_weights or weights, list(weights))
    rows = [{"structure": n, "indistinguishable_from_best": True, "merged_into": None,
             "components": {}} for n in weights]
    return {"structures": rows, "decided": DECIDED, "set_posterior": sp}


def _screen(summary):
    return "\n".join(summary_lines(summary))


def test_a_choice_is_decided_by_the_set_by_the_weights_or_left_open_with_each_side_s_share():
    """The set decides what its structures share; the weights decide a choice whose other side
    holds under 5 % together; otherwise every value's share is given, and a value held only by
    a structure without a weight (beyond the cap) keeps the choice open."""
    c = weighed_choices(DECIDED, {A: 0.97, B: 0.01, C: 0.02}, [A, B, C])
    assert c["friction"] == {"value": "on", "by": "set", "weights": {"on": 1.0}, "unsure": []}
    assert c["delay_position"]["value"] == "before_first_integrator"
    assert c["delay_position"]["by"] == "weights"
    assert c["bandpass"]["value"] == "off" and c["bandpass"]["weights"]["on"] == pytest.approx(0.02)
    c = weighed_choices(DECIDED, {A: 0.6, B: 0.3, C: 0.1}, [A, B, C])
    assert c["delay_position"] == {"value": None, "by": "open", "weights": {
        "before_first_integrator": pytest.approx(0.7), "output": pytest.approx(0.3)},
        "unsure": []}
    c = weighed_choices(DECIDED, {A: 1.0}, [A, C])  # C beyond the cap: no weight
    assert c["bandpass"] == {"value": None, "by": "open", "weights": {"off": 1.0, "on": None},
                             "unsure": []}
    assert DECIDING_SHARE == 0.05


def test_the_summary_names_each_open_choice_s_alternatives_and_the_weights_decisions():
    """"Not decided" names every alternative with its share, the largest first; a choice the weights decide reads
    as decided with its weight, never also as not decided; and a component the weights decide
    absent prints "absent", not "present or absent"."""
    text = _screen(_summary({A: 0.6, B: 0.38, C: 0.02}))
    decided_line = next(li for li in text.splitlines() if li.startswith("Decided:"))
    assert "band-pass loop off (98 % of the weight)" in decided_line
    assert ("Not decided: delay position before_first_integrator (62 %) or output (38 %)."
            in decided_line)
    assert "band-pass loop" not in decided_line.split("Not decided:")[1]
    row = next(li for li in text.splitlines() if li.startswith("| bandpass_gain |"))
    assert "| absent (the members with it hold 2.0 % of the weight) |" in row
    assert "present or absent" not in row


def test_a_component_present_or_absent_is_never_also_decided_regardless_of_the_structure():
    """Both sides over 5 %: the row reads "present or absent" and its verdict never says
    "decided regardless of the structure" (it depends on which member is right)."""
    rng = np.random.default_rng(2)
    with_it = _member(C, rng, bandpass=True)
    without = _member(A, rng)
    other = _member(D, rng, bandpass=True)
    prior = {"bandpass_gain": np.exp(rng.uniform(np.log(1), np.log(1000), 4000))}
    with_it.prior_quantities = other.prior_quantities = prior
    sp = combine([with_it, without, other], weights=[0.45, 0.11, 0.44], seed=1).to_dict()
    q = sp["quantities"]["bandpass_gain"]
    assert q["members"] == 2 and q["pinned"] and not q["depends_on_structure"]
    assert not decided_absent(q)
    sp["choices"] = weighed_choices(DECIDED, {C: 0.45, A: 0.11, D: 0.44}, [A, C, D])
    rows = [{"structure": n, "indistinguishable_from_best": True, "merged_into": None}
            for n in (C, A, D)]
    text = _screen({"structures": rows, "decided": DECIDED, "set_posterior": sp})
    row = next(li for li in text.splitlines() if li.startswith("| bandpass_gain |"))
    assert "present or absent (89 % of the weight present)" in row
    assert "decided regardless of the structure" not in row
    assert "Not decided: delay position before_first_integrator (56 %) or output (44 %); band-pass loop on (89 %) or off (11 %)." in text


def test_where_equal_weights_print_another_interval_both_are_printed_with_their_rules():
    """Two members whose delays differ, weighted 0.95 / 0.05: the equal-weight interval differs
    and is printed beside the weighted one; weighted 0.5 / 0.5 it is the same, and not printed."""
    rng = np.random.default_rng(3)
    a, b = _member(A, rng), _member(B, rng)
    b.quantities["delay"] = b.quantities["delay"] + 5e-4
    for weights, printed in (([0.95, 0.05], True), ([0.5, 0.5], False)):
        sp = combine([a, b], weights=weights, seed=1).to_dict()
        sp["choices"] = weighed_choices(DECIDED, dict(zip((A, B), weights)), [A, B])
        rows = [{"structure": n, "indistinguishable_from_best": True, "merged_into": None}
                for n in (A, B)]
        text = _screen({"structures": rows, "decided": DECIDED, "set_posterior": sp})
        line = [li for li in text.splitlines() if li.startswith("With equal weights instead")]
        assert bool(line) == printed, text
        if printed:
            e = sp["quantities"]["delay"]["equal_weights"]
            assert f"delay [{e['q05']:.4g}, {e['q95']:.4g}] s (by weight [" in line[0]


def test_pinned_combinations_are_printed_per_member_with_the_free_directions():
    from tvcid.report import _pinned_lines

    members = [
        {"structure": "a", "posterior": {"pinned": {"free": 2, "pinned": [
            {"terms": {"dead_zone": 1.0, "backlash": 0.62},
             "text": "dead_zone * backlash^0.62 = 1.0e-05 (90 % 9.9e-06 to 1.01e-05; 0.001 of the "
                     "prior's sd)"},
            {"terms": {"delay": 1.0}, "text": "delay = 0.005 (...)"}]}}},
        {"structure": "b", "posterior": {"pinned": {"free": 0, "pinned": [
            {"terms": {"delay": 1.0}, "text": "delay = 0.005 (...)"}]}}},
        {"structure": "c", "posterior": {}},
    ]
    (blank, head, blank2, line) = _pinned_lines(members)
    assert blank == blank2 == "" and head.startswith("Pinned together")
    assert line.startswith("- `a`: dead_zone * backlash^0.62 = 1.0e-05")
    assert line.endswith("2 direction(s) free within the prior")
    assert "`b`" not in line and "delay = " not in line  # one parameter alone: the table's row
    assert _pinned_lines(members[1:]) == []
    # with weights: a member under the deciding share is named, its combinations left out
    heavy = {**members[0], "weight": 0.97}
    light = {**members[0], "structure": "d", "weight": 0.01}
    lines = _pinned_lines([heavy, light])
    assert lines[3].startswith("- `a` (97 % of the weight): dead_zone * backlash^0.62")
    assert not any("- `d`" in li for li in lines)
    assert lines[-1] == ("Under 5 % of the weight, their combinations in `discovery.json` "
                         "(`set_posterior.members[].posterior.pinned`): `d`.")


def test_a_member_whose_weight_is_not_final_keeps_its_choice_open_and_its_component_open():
    """A member under 5 % whose chain stopped at its cap (``unsure``) is not decided against: the
    delay position it holds stays open, named with its share and "weight not final", and the
    band-pass loop only its kind of member holds prints "present or absent", not "absent"."""
    from tvcid.discovery.members.set_posterior import left_open_by_choices

    weights = {A: 0.93, B: 0.005, C: 0.065}
    settled = weighed_choices(DECIDED, weights, list(weights))
    assert settled["delay_position"]["by"] == "weights"
    choices = weighed_choices(DECIDED, weights, list(weights), unsure=[B])
    assert choices["delay_position"] == {"value": None, "by": "open", "weights": {
        "before_first_integrator": pytest.approx(0.995), "output": pytest.approx(0.005)},
        "unsure": ["output"]}
    assert left_open_by_choices(choices) == {}  # the delay position is no component

    rng = np.random.default_rng(4)
    members = [_member(A, rng), _member(C, rng, bandpass=True)]
    choices = weighed_choices(DECIDED, {A: 0.99, C: 0.01}, [A, C], unsure=[C])
    assert choices["bandpass"]["by"] == "open"
    left_open = left_open_by_choices(choices)
    assert left_open == {"bandpass_gain": "weight not final"}
    sp = combine(members, weights=[0.99, 0.01], seed=1, left_open=left_open).to_dict()
    q = sp["quantities"]["bandpass_gain"]
    assert not decided_absent(q)
    sp["choices"] = choices
    rows = [{"structure": n, "indistinguishable_from_best": True, "merged_into": None}
            for n in (A, C)]
    text = _screen({"structures": rows, "decided": DECIDED, "set_posterior": sp})
    row = next(li for li in text.splitlines() if li.startswith("| bandpass_gain |"))
    assert "| present or absent (1.0 % of the weight present; a member under 5 % stopped" in row
    assert "absent (the members with it" not in row
    assert "band-pass loop off (99 %) or on (1.0 %, weight not final)" in text
    assert "A weight not final is a member's whose chain stopped at its cap" in text
    assert "whose weight halving the simulation step would lift over the share" in text
    assert "a weight the step does not resolve, so its weight is not final" in row


def test_a_merged_structure_is_spoken_for_by_its_member_where_its_additions_are_decided_off():
    """A superset merged into a member holds its member's positions: where the weights decide its
    added components off, its member speaks for it and the weights decide the delay position,
    where a structure beyond the cap with the other position keeps it open. Where the weights
    decide its added component on, the superset (the truth's structure with a backlash its
    member lacks) keeps its position open. A component only merged structures hold stays open;
    one a calibrated member also holds is decided by the weights, as the table's "absent" says."""
    weights = {A: 0.99, B: 0.01}
    b_bandpass = B + "+bandpass"  # merged into B: adds the band-pass loop
    spoken = weighed_choices(DECIDED, {A: 0.989, B: 0.01, C: 0.001}, [A, B, C, b_bandpass],
                             merged={b_bandpass: B})
    assert spoken["bandpass"]["by"] == "weights" and spoken["bandpass"]["value"] == "off"
    assert spoken["delay_position"]["by"] == "weights"
    assert spoken["delay_position"]["value"] == "before_first_integrator"
    assert weighed_choices(DECIDED, {A: 0.989, B: 0.01, C: 0.001},
                           [A, B, C, b_bandpass])["delay_position"]["by"] == "open"  # beyond cap
    only_merged = weighed_choices(DECIDED, weights, [A, B, b_bandpass], merged={b_bandpass: B})
    assert only_merged["bandpass"] == {"value": None, "by": "open",
                                       "weights": {"off": 1.0, "on": None}, "unsure": []}
    assert only_merged["delay_position"]["by"] == "open"  # its addition is not decided off

    # the truth dz_error+delay_before_first_integrator+backlash+bandpass merged into the member
    # without backlash; the member with backlash, at the other position, takes the weight
    decided = {**DECIDED, "dead_zone_position": "error", "friction": False, "backlash": None,
               "bandpass": True}
    truth = "dz_error+delay_before_first_integrator+backlash+bandpass"
    member = "dz_error+delay_before_first_integrator+bandpass"
    heavy = "dz_error+delay_before_integrator+backlash+bandpass"
    c = weighed_choices(decided, {member: 1e-30, heavy: 1.0}, [member, heavy, truth],
                        merged={truth: member})
    assert c["backlash"]["value"] == "on" and c["backlash"]["by"] == "weights"
    assert c["delay_position"]["by"] == "open"
    assert c["delay_position"]["weights"] == {"before_integrator": 1.0,
                                              "before_first_integrator": pytest.approx(1e-30)}


def test_an_unsure_member_on_the_heavy_side_leaves_the_light_side_absent():
    """The heaviest member stopped at its cap, the band-pass loop held open by a structure beyond
    the cap: the component's row is not "weight not final", since the member whose weight is not
    final holds the side over the share; only an unsure member under the share opens it."""
    from tvcid.discovery.members.set_posterior import left_open_by_choices

    heavy = weighed_choices(DECIDED, {A: 0.99, C: 0.01}, [A, C, D], unsure=[A])
    assert heavy["bandpass"]["by"] == "open" and heavy["bandpass"]["unsure"] == ["off"]
    assert left_open_by_choices(heavy) == {}
    light = weighed_choices(DECIDED, {A: 0.99, C: 0.01}, [A, C, D], unsure=[C])
    assert left_open_by_choices(light) == {"bandpass_gain": "weight not final"}
