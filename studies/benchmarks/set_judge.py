"""The set-coverage benchmark's judge: one printed quantity against its truth, by one rule.

:mod:`tvcid.studies.benchmarks.set_coverage` draws a truth, runs ``tvcid discover`` and judges each
quantity of the combined posterior here (:func:`quantity_entry`); :func:`rejudge_row` judges a
stored row again from what the row holds, without its chains.

The rules (the row names each judgement's ``rule``):

* ``interval``: the truth has the quantity, the report prints it, and it is pinned (``pinned``
  true, or ``None`` where no prior judges it): covered when the truth lies inside the printed 90 %
  interval. A component the set leaves open ("present or absent; if present, ...") is judged on
  its interval if present.
* ``allowed``: as above, but not pinned: covered when the truth lies inside the range the
  recordings allow, an open end (where the draws end before the profile falls) standing for the
  prior's bound on its side (:func:`judged_range`): the report's "down to the prior's floor" and
  "or below (where the draws end)" both reach no farther than the prior, so a truth beyond the
  prior is a miss. A not-pinned quantity without an allowed range is judged on its interval and
  flagged ``allowed_missing``.
* ``absent``: the truth lacks the component (backlash, friction offset, band-pass loop): covered
  when the report prints it absent or "present or absent"; not when it prints it present. The
  report prints absent a component whose members hold under the deciding share of the weight,
  with their interval "if present" beside it.
* ``lacking``: the truth has the quantity and the report prints no interval for it, or prints
  its component absent: not covered.

A judgement *cannot fail* (``can_fail`` false) when what is printed holds the truth whatever the
posterior's numbers: a truth of 0 against "present or absent", and a truth inside the prior's
bounds against an allowed range open at both ends (the prior's whole range). The goals read on
the judgements that can fail; those that cannot are counted apart. A truth beyond the prior
against a range open at both ends is a miss and can fail: the prior the report names excludes it.

The prior's bounds of each quantity are stored in the row (``prior_bounds``: from the combined
entry's ``prior_bounds`` or ``prior_range`` where ``discover`` exports them, else its
``support``, the members' prior draws' range stretched to hold their draws). A row without them is judged on what the
code that made its priors sets whatever the member's fit (:func:`fixed_prior_edge`); a
judgement that needs a bound neither gives is *undecided* (``covered`` ``None``), counted apart.
"""
from __future__ import annotations

import math

from tvcid.discovery.members.set_posterior import decided_absent, printed_present_or_absent
from tvcid.discovery.structure.coordinates import BOUNDS
from tvcid.models.quantities import COMPONENT_QUANTITIES

#: The rules a judged quantity is judged by (the module docstring).
RULES = ("interval", "allowed", "absent", "lacking")
#: A width within this relative slack of twice the step error is not narrower: the mixture's
#: draws are its members' taken at evenly spaced ranks, quantiles to a few parts in 10^4.
STEP_SLACK = 1e-3
#: The delay's prior floors of the stored rows' sampling commit (1.2e-3 s for a fit delay above
#: it, else 6e-4 s, each lowered to 0.9 x the fit where that is lower): those rows hold no prior
#: bounds, fresh rows store their own (``prior_bounds``).
DELAY_FLOORS = (1.2e-3, 6e-4)
#: Per quantity, the prior's floors and ceilings ``member_priors`` sets whatever the fit (the
#: box of :data:`tvcid.discovery.structure.coordinates.BOUNDS`; a fit within 1.5x of an edge widens
#: it). The velocity dead zone's box is scaled by the fit's gain, the friction offset's by its
#: dead zone, and the linear block's quantities are composites: none has a fixed edge.
FIXED_PRIOR_EDGES = {
    "delay": (DELAY_FLOORS, (BOUNDS["delay"][1],)),
    "backlash": ((math.exp(BOUNDS["log_r"][0]),), (math.exp(BOUNDS["log_r"][1]),)),
    "bandpass_gain": ((math.exp(BOUNDS["log_G"][0]),), (math.exp(BOUNDS["log_G"][1]),)),
    "dead_zone[error]": ((math.exp(BOUNDS["log_z"][0]),), (math.exp(BOUNDS["log_z"][1]),)),
}
#: An open end's outermost draw within this relative distance inside a fixed edge is taken to
#: be stopped by it: the walkers of a flat profile reach a prior wall to a few parts in 10^4
#: over thousands of draws, while a widened edge lies at least 10 % (the delay) or 1.5x away.
EDGE_TOLERANCE = 5e-3


def printed_as(q, left_open=False) -> str:
    """How the report prints combined quantity ``q`` (``None``: no calibrated member has it), as
    :mod:`tvcid.report` does: ``present or absent`` (the weights leave the component open, or
    the set does: ``left_open``, or ``q``'s own ``left_open``), ``absent`` (no member has it, or
    the members with it hold under the deciding share of the weight) or ``present``."""
    if left_open or (q is not None and printed_present_or_absent(q)):
        return "present or absent"
    return "absent" if q is None or decided_absent(q) else "present"


def inside_interval(value, q) -> bool:
    """Whether ``value`` lies inside ``q``'s printed 90 % interval (none printed: no)."""
    return q["q05"] is not None and q["q95"] is not None and q["q05"] <= value <= q["q95"]


def prior_bounds_of(q):
    """``(bounds, source)``: the prior's ``[floor, ceiling]`` of combined quantity ``q`` (an end
    ``None`` where nothing bounds it) and where they come from, ``"prior"`` (the entry's
    ``prior_bounds`` or ``prior_range``, its members' priors) or ``"support"`` (their prior
    draws' range stretched to hold their draws); ``(None, None)`` where the entry has none."""
    for key, source in (("prior_bounds", "prior"), ("prior_range", "prior"), ("support", "support")):
        if q.get(key) is not None:
            return [None if b is None else float(b) for b in q[key]], source
    return None, None


def fixed_prior_edge(name, side, outermost):
    """The prior's bound on ``side`` (0 floor, 1 ceiling) of quantity ``name`` whose draws end at
    ``outermost`` against it, where that lies within :data:`EDGE_TOLERANCE` inside an edge of
    :data:`FIXED_PRIOR_EDGES`; ``None`` otherwise."""
    for edge in FIXED_PRIOR_EDGES.get(name, ((), ()))[side]:
        inside = (outermost - edge) if side == 0 else (edge - outermost)
        if 0 <= inside <= EDGE_TOLERANCE * abs(edge):
            return edge
    return None


def judged_range(name, value, allowed, allowed_open, prior_bounds=None):
    """``(range, source, decided)``: the range ``value`` is judged on, ``allowed``
    (``[low, high]``) with each end ``allowed_open`` marks replaced by the prior's bound on its
    side (``None``: unbounded); ``source`` names where a bound came from (``"prior"``,
    ``"support"``, ``"fixed edge"``, or ``None`` where no open end is used); an open end whose
    bound neither ``prior_bounds`` nor :func:`fixed_prior_edge` gives stays at the outermost
    draw, which decides a ``value`` inside it; ``decided`` is false for a ``value`` beyond it."""
    low_open, high_open = allowed_open or (False, False)
    bounds, source = prior_bounds if prior_bounds is not None else (None, None)
    out, decided, used = list(allowed), True, None
    for side, is_open in ((0, low_open), (1, high_open)):
        if not is_open:
            continue
        if bounds is not None:
            out[side], used = bounds[side], source
            continue
        edge = fixed_prior_edge(name, side, allowed[side])
        beyond = value < allowed[0] if side == 0 else value > allowed[1]
        if edge is not None:
            out[side], used = edge, "fixed edge"
        elif beyond:
            decided = False
    return out, used, decided


def inside_range(value, bounds) -> bool:
    """Whether ``value`` lies inside ``bounds`` (``[low, high]``, ``None`` unbounded)."""
    return bool((bounds[0] is None or value >= bounds[0]) and (bounds[1] is None or value <= bounds[1]))


def judge(name, value, q, printed, prior_bounds=None) -> dict:
    """The verdict on quantity ``name`` with truth ``value`` (``None``: the truth lacks it)
    against the combined summary ``q`` (``None``: the set lacks it), printed ``printed``
    (:func:`printed_as`), the prior's bounds ``prior_bounds`` (:func:`prior_bounds_of`).

    Returns
    -------
    dict
        ``rule`` (``None`` where the quantity is not judged), ``covered`` (``None`` where not
        judged or undecided), ``can_fail``, ``allowed_missing``, ``judged_range`` (for the
        ``allowed`` rule) with ``prior_bound_source`` and ``undecided``.
    """
    out = {"rule": None, "covered": None, "can_fail": None, "allowed_missing": False,
           "judged_range": None, "prior_bound_source": None, "undecided": False}
    component = name in COMPONENT_QUANTITIES.values()
    if value is None or not math.isfinite(value):
        if component and value is None:
            out.update(rule="absent", covered=printed != "present",
                       can_fail=printed != "present or absent")
        return out
    if q is None or printed == "absent":  # nothing printed, or printed absent
        return {**out, "rule": "lacking", "covered": False, "can_fail": True}
    if q.get("pinned") is False and q.get("allowed") is not None:
        bounds, source, decided = judged_range(name, value, q["allowed"], q.get("allowed_open"),
                                               prior_bounds)
        covered = inside_range(value, bounds) if decided else None
        both_open = all(q.get("allowed_open") or (False, False))
        return {**out, "rule": "allowed", "covered": covered,
                "can_fail": None if covered is None else not (both_open and covered),
                "judged_range": bounds, "prior_bound_source": source, "undecided": not decided}
    return {**out, "rule": "interval", "covered": inside_interval(value, q), "can_fail": True,
            "allowed_missing": q.get("pinned") is False}


def narrower_than_step(q):
    """Whether ``q``'s printed interval is narrower than twice its step error, or, where the
    quantity's support cuts ``q50 +- step error`` (a delay's prior floor), narrower than what
    the support leaves of it (``None`` without a step error or an interval)."""
    step = q.get("step_error")
    if not step or None in (q["q05"], q["q50"], q["q95"]):
        return None
    floor, ceiling = q.get("support") or (None, None)
    low = q["q50"] - step if floor is None else max(q["q50"] - step, floor)
    high = q["q50"] + step if ceiling is None else min(q["q50"] + step, ceiling)
    return bool(q["q95"] - q["q05"] < (high - low) * (1 - STEP_SLACK))


def _allowed_test(value, allowed, allowed_open, name, prior_bounds):
    """Whether ``value`` lies inside the allowed range judged on the prior's bounds (``None``
    where undecided)."""
    bounds, _, decided = judged_range(name, value, allowed, allowed_open, prior_bounds)
    return inside_range(value, bounds) if decided else None


def quantity_entry(name, value, q, left_open=False) -> dict:
    """One quantity of a row: what is printed, the prior's bounds, the truth, the verdict
    (:func:`judge`), the step error's check and, for an interval the rule judges, its relative
    width."""
    printed = printed_as(q, left_open)
    prior = prior_bounds_of(q) if q else (None, None)
    verdict = judge(name, value, q, printed, prior if prior[0] is not None else None)
    q = q or {}
    q05, q50, q95 = q.get("q05"), q.get("q50"), q.get("q95")
    allowed = q.get("allowed")
    known = value is not None and math.isfinite(value)
    width = None
    if verdict["rule"] == "interval" and None not in (q05, q50, q95) and q50 != 0:
        width = (q95 - q05) / abs(q50)
    return {
        "truth": value, "printed": printed, "present": q.get("present", 0.0),
        "q05": q05, "q50": q50, "q95": q95, "pinned": q.get("pinned"),
        "allowed": allowed, "allowed_open": q.get("allowed_open"),
        "allowed_at_prior": q.get("allowed_at_prior"),
        "prior_bounds": prior[0], "prior_bounds_from": prior[1],
        **verdict,
        # both tests, whatever the rule: how the interval and the range would have judged
        "inside": inside_interval(value, q) if known and q else None,
        "inside_allowed": (_allowed_test(value, allowed, q.get("allowed_open"), name,
                                         prior if prior[0] is not None else None)
                           if known and allowed is not None else None),
        "relative_width": width, "step_error": q.get("step_error"),
        "widened": bool(q.get("widened", False)),
        "narrower_than_step": narrower_than_step(q) if q else None,
    }


def _stored_summary(entry):
    """The combined summary a stored entry was judged against (``None`` where the set lacked the
    quantity: nothing printed but its presence)."""
    if all(entry.get(k) is None for k in ("q05", "q50", "q95", "allowed", "pinned")):
        return None
    return {k: entry.get(k) for k in ("q05", "q50", "q95", "pinned", "allowed", "allowed_open")}


def rejudge_entry(name, entry) -> dict:
    """``entry`` (a stored :func:`quantity_entry`) judged again by :func:`judge` from what it
    holds: its truth, what was printed, its interval, its allowed range and, where stored, the
    prior's bounds; a stored entry without them is judged on :func:`fixed_prior_edge`."""
    q = _stored_summary(entry)
    value = entry.get("truth")
    bounds = entry.get("prior_bounds")
    prior = (bounds, entry.get("prior_bounds_from")) if bounds is not None else None
    printed = entry["printed"]
    if printed == "present" and decided_absent({"present": entry.get("present", 1.0)}):
        printed = "absent"  # as the report prints it (:func:`printed_as`)
    verdict = judge(name, value, q, printed, prior)
    known = value is not None and math.isfinite(value)
    allowed = entry.get("allowed")
    return {**entry, "printed": printed, "prior_bounds": bounds,
            "prior_bounds_from": entry.get("prior_bounds_from"), **verdict,
            "inside_allowed": (_allowed_test(value, allowed, entry.get("allowed_open"), name, prior)
                               if known and allowed is not None else None)}


def beyond_prior(entry) -> bool:
    """Whether ``entry`` (judged on the ``allowed`` rule) misses because its truth lies beyond an
    open end, that is beyond the prior's bound the end stands for."""
    if entry.get("rule") != "allowed" or entry.get("covered") is not False:
        return False
    (low, high), (low_open, high_open) = entry["judged_range"], entry["allowed_open"]
    t = entry["truth"]
    return bool((low_open and low is not None and t < low)
                or (high_open and high is not None and t > high))


def row_verdicts(quantities) -> dict:
    """A row's ``goals`` (each judged quantity's verdict) and ``cannot_fail`` (the judged
    quantities whose judgement cannot fail)."""
    return {"goals": {n: e["covered"] for n, e in quantities.items() if e["rule"] is not None},
            "cannot_fail": [n for n, e in quantities.items() if e["can_fail"] is False]}


def rejudge_row(row, judged_commit) -> dict:
    """``row`` (a finished set-coverage row) with every quantity judged again
    (:func:`rejudge_entry`) and ``judged_commit`` recorded beside the commit that sampled its
    chains (``commit``), where the two differ."""
    quantities = {n: rejudge_entry(n, e) for n, e in row["quantities"].items()}
    out = {**row, "quantities": quantities, **row_verdicts(quantities)}
    out.pop("judged_commit", None)
    if judged_commit != row.get("commit"):
        out["judged_commit"] = judged_commit
    return out
