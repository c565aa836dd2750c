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
