"""How a discovery's reported set stands to the truth that made its recordings.

The discovery benchmark's verdicts on one draw, shared with the benchmarks that judge a set
(:mod:`.next_test`, :mod:`.loop`) and with the set rule weighed again on finished rows
(:mod:`.rederive`): the winner and the set against the truth's structure, each structural
choice decided right, wrong or left open, the structures no fit-based rule can tell from the
truth, and the coordinates the recordings leave open.
"""
from __future__ import annotations

import math

import numpy as np

from tvcid.models.structures import CHOICES, Structure, shared_choices


def set_verdict(ranked, truth):
    """How a ranking (winner first, its indistinguishable set marked:
    :func:`tvcid.discovery.structure.indistinguishable.indistinguishable_set`) stands to the ``truth``
    structure.

    Returns ``winner``; ``right_winner``; ``set`` (every structure in the set, merged ones too);
    ``members`` (the unmerged ones) and ``set_size`` (their number); ``truth_member`` (the member
    the truth is or is merged into, ``None`` outside the set) and ``truth_in_set``; and
    ``right_or_in_small_set``, the goal's verdict: the right winner, or the truth in a set of at
    most 3 members.
    """
    inside = [f for f in ranked if f.indistinguishable_from_best]
    members = [f.structure.name for f in inside if f.merged_into is None]
    truth_member = next((f.merged_into or f.structure.name for f in inside if f.structure == truth),
                        None)
    right = ranked[0].structure == truth
    return {"winner": ranked[0].structure.name, "right_winner": right,
            "truth_in_set": truth_member is not None, "truth_member": truth_member,
            "set_size": len(members), "set": [f.structure.name for f in inside], "members": members,
            "right_or_in_small_set": right or (truth_member is not None and len(members) <= 3)}


def choice_verdicts(row):
    """Per structural choice: ``right`` or ``wrong`` where the reported set decides it (every
    member shares one value, :func:`tvcid.models.structures.shared_choices`), ``open`` where it does not."""
    if not row.get("set"):
        return {c: "open" for c in CHOICES}
    decided = shared_choices(row["set"])
    truth = Structure.parse(row["structure"]).to_dict()
    return {c: "open" if v is None else ("right" if v == truth[c] else "wrong")
            for c, v in decided.items()}


def as_well_as_truth(row, against="truth"):
    """The structures no fit-based rule can tell from the truth on ``row``'s recordings, reduced
    to the minimal ones (a structure containing another of them,
    :func:`tvcid.discovery.structure.indistinguishable._contains`, is that one at its added components'
    zero), the truth's own structure among them.

    ``against="truth"``: every ranked structure whose fitted in-sample cost is at most the cost of
    the true parameters themselves (``cost_at_truth``). The recordings are at least as likely
    under each of them, at its fit, as under the truth; the truth's structure fits below the
    truth by what the noise lets a fit gain, so a structure within that is within the noise.
    ``against="fit"``: at most the truth's structure's own fit (or the truth's cost where that
    search failed above it): an oracle that knows the true structure and ignores the noise.

    A search that missed a structure's optimum leaves it out, so the count is a lower bound and
    :func:`.discovery.summarise`'s ``ceiling_set_le3`` and ``oracle_set_le3`` (at most 3 of them) upper
    bounds on the draws whose truth a set of at most 3 can hold. Rows without a stored truth
    cost give ``None``.
    """
    from tvcid.discovery.structure.indistinguishable import _contains

    if against not in ("truth", "fit"):
        raise ValueError(f"against must be 'truth' or 'fit', not {against!r}")
    threshold = row.get("cost_at_truth")
    if threshold is None or not row.get("ranking"):
        return None
    own = row.get("truth_structure_cost")
    if against == "fit" and own is not None:
        threshold = min(threshold, own)
    names = {x["structure"] for x in row["ranking"] if x["cost"] <= threshold} | {row["structure"]}
    fitting = [Structure.parse(n) for n in sorted(names)]
    return [s.name for s in fitting if not any(_contains(s, o) for o in fitting)]


def fit_ceiling(rows, against="truth"):
    """Fraction of ``rows`` where at most 3 minimal structures fit as well as the truth
    (:func:`as_well_as_truth` with ``against``); NaN where no row has a stored truth cost."""
    counts = [len(m) for m in (as_well_as_truth(r, against) for r in rows) if m is not None]
    return float(np.mean([c <= 3 for c in counts])) if counts else math.nan


def undecided_marked(row):
    """``row`` with the coordinates the recordings leave open marked, and its verdict.

    When the truth's structure fitted at least as well as the truth itself, what that fit moves by
    over 5 % the recordings do not pin, however sharp the optimum at the truth: such coordinates
    are not counted as identifiable (idempotent; applied to resumed rows too).
    """
    own, at_truth = row.get("truth_structure_cost"), row.get("cost_at_truth")
    if own is not None and at_truth is not None and own <= at_truth:
        for v in row["coordinates"].values():
            if v["identifiable"] and not v["within"]:
                v["identifiable"] = False
                v["undecided"] = "an optimum fitting at least as well as the truth differs"
    row["identifiable_within"] = all(v["within"] for v in row["coordinates"].values()
                                     if v["identifiable"])
    return row


def printed_choices(discovery, truth) -> dict:
    """Each structural choice as ``discovery.json``'s report prints it, against the ``truth``
    structure's name: the set's and the weights' decisions worked out again by this code's rule
    (:func:`tvcid.discovery.members.set_weights.weighed_choices`) from the run's stored weights,
    members whose weight is not final and merges, and the run's own stored ones beside them.

    Returns choice -> ``{"value", "by", "verdict"}`` (``verdict``: ``right``, ``wrong`` or
    ``open``) with ``stored`` (the stored choice's ``value`` and ``verdict``, ``None`` where the
    run stores none); ``None`` without a set posterior.
    """
    from tvcid.discovery.members.set_weights import (
        merged_structures,
        shown_choice,
        stored_unsure,
        weighed_choices,
    )

    sp = discovery.get("set_posterior") or {}
    if not sp.get("members"):
        return None
    weights = {m["structure"]: m.get("weight", 1.0 / len(sp["members"])) for m in sp["members"]}
    now = weighed_choices(discovery["decided"], weights, discovery["indistinguishable"],
                          stored_unsure(sp), merged_structures(discovery["structures"]))
    true = {c: shown_choice(v) for c, v in Structure.parse(truth).to_dict().items()}

    def verdict(choice, value):
        return "open" if value is None else ("right" if value == true[choice] else "wrong")

    out = {}
    for c, v in now.items():
        stored = (sp.get("choices") or {}).get(c)
        out[c] = {"value": v["value"], "by": v["by"], "verdict": verdict(c, v["value"]),
                  "stored": None if stored is None else
                  {"value": stored["value"], "verdict": verdict(c, stored["value"])}}
    return out


def printed_choice_counts(rows) -> dict:
    """Over the rows with :func:`printed_choices` (``printed_choices``): ``draws``; ``right``,
    ``open`` and ``wrong`` choices (the wrong ones each ``[seed, choice, printed, by]``), and
    ``by_weights`` (the right ones the weights decided); ``stored_wrong``: the choices the runs'
    own stored decisions got wrong, each ``[seed, choice, printed]``."""
    with_choices = [r for r in rows if r.get("printed_choices")]
    entries = [(r["seed"], c, v) for r in with_choices for c, v in r["printed_choices"].items()]
    return {"draws": len(with_choices),
            "right": sum(v["verdict"] == "right" for _, _, v in entries),
            "by_weights": sum(v["verdict"] == "right" and v["by"] == "weights"
                              for _, _, v in entries),
            "open": sum(v["verdict"] == "open" for _, _, v in entries),
            "wrong": [[s, c, v["value"], v["by"]] for s, c, v in entries
                      if v["verdict"] == "wrong"],
            "stored_wrong": [[s, c, v["stored"]["value"]] for s, c, v in entries
                             if v["stored"] and v["stored"]["verdict"] == "wrong"]}


def with_printed_choices(row, draw_dir):
    """``row`` with ``printed_choices`` (:func:`printed_choices`) read from
    ``draw_dir/discover/discovery.json``; unchanged where that file is not there (a row copied
    without its draw's directory) or the row failed."""
    import json
    from pathlib import Path

    path = Path(draw_dir) / "discover" / "discovery.json"
    if "error" in row or not path.is_file():
        return row
    return {**row, "printed_choices": printed_choices(json.loads(path.read_text()),
                                                      row["structure"])}


def choices_text(counts) -> str:
    """:func:`printed_choice_counts` in words (empty where no row has printed choices)."""
    if not counts or not counts.get("draws"):
        return ""
    wrong = "; ".join(f"draw {s} {c} {v} (by the {by})" for s, c, v, by in counts["wrong"])
    stored = "; ".join(f"draw {s} {c} {v}" for s, c, v in counts["stored_wrong"])
    return (f"structural choices as printed over {counts['draws']} draws: {counts['right']} right "
            f"({counts['by_weights']} of them by the weights), {counts['open']} open, "
            f"{len(counts['wrong'])} wrong" + (f" ({wrong})" if wrong else "")
            + (f"; as the sampling commit printed them, wrong: {stored}" if stored else ""))
