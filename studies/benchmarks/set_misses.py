"""Why a quantity the report prints misses its truth: the truth's own member against the set.

The set-coverage benchmark judges the combined posterior (:mod:`.set_judge`); a miss there has
one of these causes, told apart by the truth's member (the calibrated member of the set whose
structure is the truth's, or into which the truth's is merged):

* ``out of the set``: the truth's structure is not in the reported set;
* ``not calibrated``: in the set but not calibrated (beyond the calibration's cap, or failed),
  so no member posterior holds it;
* ``weight elsewhere``: the truth's member's own 90 % interval holds the truth, and the members
  the weights favour print it away;
* ``merged into a simpler member``: the truth's structure is merged into a member without some
  of its components (which did not beat it by the set's margin), and that member's own interval
  misses the truth: the components it lacks moved the quantity;
* ``member misses, converged`` and ``member misses, stopped at the cap``: the truth's member, of
  the truth's own structure, has its own interval miss the truth, its chain converged or not;
* ``presence``: a component printed present or absent against the truth (rules ``absent`` and
  ``lacking``), with the weight its members hold.

Each cause records the facts it rests on: the truth's member, its weight and whether its chain
converged, its own interval, and the heaviest member with its weight and interval. Where the
truth's member misses, the row also records the structure search's fit of the truth's structure
against the true parameters' own cost on the same recordings (``fit_against_truth``): a fit at
least as good as the truth away from it is a second mode the recordings hold (the fit is not
unique), not a search that stopped short. The causes are read from the draw's directory (no
sampling), so rows sampled at one commit are explained at another.
"""
from __future__ import annotations

import json
from pathlib import Path

__all__ = ["CAUSES", "cause_counts", "causes_text", "fit_against_truth", "miss_causes",
           "truth_member", "with_miss_causes"]

#: Every cause a miss can have, in the order the table counts them.
CAUSES = ("out of the set", "not calibrated", "weight elsewhere", "merged into a simpler member",
          "member misses, converged", "member misses, stopped at the cap", "presence")


def truth_member(truth_name, discovery):
    """The calibrated member of ``discovery``'s set (a ``discovery.json`` dict) that is the
    truth's structure or into which it is merged (through every merge: a structure merged into
    one that is merged in turn); ``None`` where the truth's structure is out of the set or its
    member is not calibrated."""
    members = {m["structure"]: m for m in discovery["set_posterior"]["members"]}
    entries = {s["structure"]: s for s in discovery["structures"]}
    name, seen = truth_name, set()
    while name not in members:
        entry = entries.get(name)
        if entry is None or not entry["indistinguishable_from_best"] or name in seen:
            return None
        seen.add(name)
        name = entry.get("merged_into")
    return members[name]


def _interval(member, name):
    q = (member or {}).get("quantities", {}).get(name)
    if not q or q.get("q05") is None or q.get("q95") is None:
        return None
    return [q["q05"], q["q95"]]


def miss_causes(row, discovery) -> list:
    """One entry per judged quantity of ``row`` (a set-coverage row) that misses its truth: the
    ``quantity``, its ``rule``, its ``cause`` (one of :data:`CAUSES`) and the facts it rests on."""
    name = row["structure"]
    inside = set(discovery.get("indistinguishable") or ())
    member = truth_member(name, discovery)
    members = discovery["set_posterior"]["members"]
    heaviest = max(members, key=lambda m: m.get("weight") or 0.0) if members else None
    out = []
    for q, e in row["quantities"].items():
        if e.get("rule") is None or e.get("covered") is not False or not e.get("can_fail"):
            continue
        own = _interval(member, q)
        entry = {"quantity": q, "rule": e["rule"], "truth": e.get("truth"),
                 "truth_member": None if member is None else member["structure"],
                 "truth_member_weight": None if member is None else member.get("weight"),
                 "truth_member_converged": None if member is None else member.get("converged"),
                 "truth_member_interval": own,
                 "heaviest": None if heaviest is None else heaviest["structure"],
                 "heaviest_weight": None if heaviest is None else heaviest.get("weight"),
                 "heaviest_interval": _interval(heaviest, q)}
        if e["rule"] in ("absent", "lacking"):
            cause = "presence"
            entry["present"] = e.get("present")
        elif name not in inside:
            cause = "out of the set"
        elif member is None:
            cause = "not calibrated"
        elif own is not None and e.get("truth") is not None and own[0] <= e["truth"] <= own[1]:
            cause = "weight elsewhere"
        elif member["structure"] != name:
            cause = "merged into a simpler member"
        elif member.get("converged"):
            cause = "member misses, converged"
        else:
            cause = "member misses, stopped at the cap"
        out.append({**entry, "cause": cause})
    return out


def fit_against_truth(row, discovery, recordings_dir):
    """The in-sample cost of the structure search's fit of the truth's structure
    (``truth_structure_cost``) and of the true parameters themselves (``cost_at_truth``,
    :func:`.discovery.recordings_cost_at_truth`) on the recordings in ``recordings_dir``;
    ``None`` where the truth's structure was not fitted or the recordings are not there."""
    from tvcid.models.recording import load_recordings

    from .discovery import recordings_cost_at_truth
    from .draws import row_ranges
    from .scenarios import draw_scenario

    own = next((s for s in discovery["structures"] if s["structure"] == row["structure"]), None)
    paths = sorted(Path(recordings_dir).glob("*.csv"))
    if own is None or own.get("cost") is None or not paths:
        return None
    truth = draw_scenario(row["seed"], ranges=row_ranges(row)).truth
    at_truth = recordings_cost_at_truth(load_recordings(paths), truth)
    return {"truth_structure_cost": own["cost"], "cost_at_truth": at_truth,
            "as_good_as_truth": own["cost"] <= at_truth}


def with_miss_causes(row, draw_dir):
    """``row`` with ``misses`` (:func:`miss_causes`) read from ``draw_dir/discover/discovery.json``,
    and where the truth's member misses, ``fit_against_truth`` (:func:`fit_against_truth`, on
    ``draw_dir/recordings``); unchanged where that file is not there (a row copied without its
    draw's directory)."""
    path = Path(draw_dir) / "discover" / "discovery.json"
    if "error" in row or not path.is_file():
        return row
    discovery = json.loads(path.read_text())
    misses = miss_causes(row, discovery)
    out = {**row, "misses": misses}
    if any(m["cause"].startswith("member misses") for m in misses):
        if row.get("fit_against_truth") is None:
            out["fit_against_truth"] = fit_against_truth(row, discovery,
                                                         Path(draw_dir) / "recordings")
    return out


def cause_counts(rows) -> dict:
    """Over the rows that explain their misses: ``draws``; per cause of :data:`CAUSES` the
    misses, each ``[seed, quantity]``; ``second_mode``: the member misses whose draw's fit of
    the truth's structure is at least as good as the truth (:func:`fit_against_truth`)."""
    explained = [r for r in rows if "misses" in r]
    second = [[r["seed"], m["quantity"]] for r in explained for m in r["misses"]
              if m["cause"].startswith("member misses")
              and (r.get("fit_against_truth") or {}).get("as_good_as_truth")]
    return {"draws": len(explained),
            "causes": {c: [[r["seed"], m["quantity"]] for r in explained for m in r["misses"]
                           if m["cause"] == c] for c in CAUSES},
            "second_mode": second}


def causes_text(counts) -> str:
    """:func:`cause_counts` as the table and ``docs/results.md`` print it; empty where no row
    explains its misses."""
    if not counts.get("draws"):
        return ""
    text = (f"misses by cause ({counts['draws']} draws explained): " + (", ".join(
        f"{c} {len(counts['causes'][c])} ("
        + ", ".join(f"{q} of draw {seed}" for seed, q in counts["causes"][c]) + ")"
        for c in CAUSES if counts["causes"][c]) or "none"))
    if counts.get("second_mode"):
        text += ("; of the truth's member's misses, where its structure fits elsewhere at least "
                 "as well as the truth: " + ", ".join(f"{q} of draw {seed}"
                                                      for seed, q in counts["second_mode"]))
    return text
