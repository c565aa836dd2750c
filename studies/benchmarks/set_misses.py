"""Why a quantity the report prints misses its truth: the truth's own member against the set.

The set-coverage benchmark judges the combined posterior (:mod:`.set_judge`); a miss there has
one of these causes, told apart by the truth's member (the calibrated member of the set whose
structure is the truth's, or into which the truth's is merged):

* ``out of the set``: the truth's structure is not in the reported set;
* ``not calibrated``: in the set but not calibrated (beyond the calibration's cap, or failed),
  so no member posterior holds it;
* ``weight elsewhere``: the truth's member's own 90 % interval holds the truth, and the members
  the weights favour print it away;
* ``member misses, converged`` and ``member misses, stopped at the cap``: the truth's member's
  own interval misses the truth, its chain converged or not;
* ``presence``: a component printed present or absent against the truth (rules ``absent`` and
  ``lacking``), with the weight its members hold.

Each cause records the facts it rests on: the truth's member, its weight and whether its chain
converged, its own interval, and the heaviest member with its weight and interval. The causes are
read from the draw's ``discovery.json`` (no sampling), so rows sampled at one commit are
explained at another.
"""
from __future__ import annotations

import json
from pathlib import Path

__all__ = ["CAUSES", "cause_counts", "miss_causes", "truth_member", "with_miss_causes"]

#: Every cause a miss can have, in the order the table counts them.
CAUSES = ("out of the set", "not calibrated", "weight elsewhere", "member misses, converged",
          "member misses, stopped at the cap", "presence")


def truth_member(truth_name, discovery):
    """The calibrated member of ``discovery``'s set (a ``discovery.json`` dict) that is the
    truth's structure or into which it is merged; ``None`` where the truth's structure is out of
    the set or its member is not calibrated."""
    members = {m["structure"]: m for m in discovery["set_posterior"]["members"]}
    if truth_name in members:
        return members[truth_name]
    entry = next((s for s in discovery["structures"] if s["structure"] == truth_name), None)
    if entry is None or not entry["indistinguishable_from_best"]:
        return None
    return members.get(entry.get("merged_into"))


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
        elif member.get("converged"):
            cause = "member misses, converged"
        else:
            cause = "member misses, stopped at the cap"
        out.append({**entry, "cause": cause})
    return out


def with_miss_causes(row, draw_dir):
    """``row`` with ``misses`` (:func:`miss_causes`) read from ``draw_dir/discover/discovery.json``;
    unchanged where that file is not there (a row copied without its draw's directory)."""
    path = Path(draw_dir) / "discover" / "discovery.json"
    if "error" in row or not path.is_file():
        return row
    return {**row, "misses": miss_causes(row, json.loads(path.read_text()))}


def cause_counts(rows) -> dict:
    """Over the rows that explain their misses: ``draws`` and per cause of :data:`CAUSES` the
    misses, each ``[seed, quantity]``."""
    explained = [r for r in rows if "misses" in r]
    return {"draws": len(explained),
            "causes": {c: [[r["seed"], m["quantity"]] for r in explained for m in r["misses"]
                           if m["cause"] == c] for c in CAUSES}}
