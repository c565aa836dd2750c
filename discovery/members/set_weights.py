"""The weights of the set's members: each structure's posterior probability, from its evidence.

The set (:mod:`tvcid.discovery.structure.indistinguishable`) holds the structures whose held-out scores
the ranking cannot separate from the best; each member is calibrated on its own
(:func:`tvcid.discovery.members.member_calibration.calibrate_member`). A member's weight is its
posterior probability given the recordings, with every member equally probable beforehand:
``w_m = Z_m / sum_k Z_k``, ``Z_m`` its evidence (the likelihood averaged over its prior), each
estimated by importance sampling from the member's chain
(:mod:`tvcid.discovery.members.member_evidence`).

**A common temperature.** Each member's chain samples its likelihood divided, recording by
recording, by its own discrepancy factor (:func:`tvcid.discovery.calibration.likelihood.base.tempered`):
a worse member gets a larger factor, which would flatten exactly the misfit that should cost it
weight. The evidences are therefore all taken at one temperature per recording, the smallest
factor any member needs there (1 where some member fits that recording within its noise): a
member that needs more pays for its misfit at the temperature the best one shows is enough.

**What the evidence weighs.** A member's evidence charges it for the prior volume its extra
parameters leave unused: a superset whose added component the recordings allow anywhere from 0
to a tenth of its prior range keeps about that share of its nested member's weight, and one whose
component the recordings pin away from 0 gains the weight its fit earns. Two members that fit
alike get about equal weights; a member that fits worse by a few units of its noise gets a weight
near 0.

**At half the step.** A member's likelihood is its kernel's at a fixed step, and two structures
whose switching events fall differently converge differently as the step shrinks: their evidences
can differ by what the step leaves unresolved, not by what the recordings tell
(``docs/methods/calibration.md``, "Weights", measures it on two delay positions). Each member's
step-error measurement (:func:`tvcid.discovery.calibration.step_error.measure_step_error`) gives its
log evidence's change when the step is halved (``log_evidence_shift``, exact in expectation), and
the weights are taken from the evidences at half the step. What half the step still leaves, at first
order the change halving made, is part of the allowance: between two members, the difference of
their shifts. A member whose weight that allowance lifts to the deciding share is not final
(:func:`unsure_members`): the step, not the data, would decide against it.

Beside the weights, the result keeps the members' shares by the ranking's held-out scores
(:func:`.ranking_shares.ranking_shares`) and equal weights, as comparisons the report prints;
neither is used as the weights.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tvcid.discovery.calibration.importance import GOOD_K
from tvcid.discovery.structure.indistinguishable import DECIDING_SHARE

from .member_evidence import ImportanceDraws, log_evidence
from .ranking_shares import RANKING_RULE, ranking_shares

__all__ = ["SetWeights", "evidence_weights", "common_temperature", "weighed_choices",
           "unsure_members", "stored_unsure", "decided_against", "merged_structures",
           "shown_choice", "EVIDENCE_RULE", "EQUAL_RULE", "UNSURE_NATS"]

#: Standard errors of a member's log evidence added before it is judged under the share.
SE_ALLOWANCE = 2.0
#: How far under the deciding share (in nats: a factor of 5e8) a member's weight, even at its
#: allowance, must be before the data decide against it when its weight is not final: its chain
#: stopped at its cap, or its evidence rests on unreliable ratios. Such an estimate of the log
#: evidence errs low by an amount its standard error does not bound (a chain that has not reached
#: part of its posterior leaves that part's likelihood out), so the margin is a choice, not a
#: bound; the set-coverage benchmark judges it.
UNSURE_NATS = 20.0
#: The equal-weight alternative's rule.
EQUAL_RULE = "equal weights: 1/n for each of the n calibrated members"
#: The weights' rule (:func:`evidence_weights`).
EVIDENCE_RULE = ("posterior probability of each structure: its evidence (the likelihood averaged "
                 "over its prior, by importance sampling from its chain, taken at half the "
                 "simulation step) over the members' sum, each recording's likelihood at the "
                 "smallest discrepancy factor any member needs there")


@dataclass
class SetWeights:
    """The members' weights (:func:`evidence_weights`).

    Attributes
    ----------
    weights : dict
        Member -> weight, summing to 1 (the members' order kept).
    method : str
        ``"evidence"``; ``"single member"``; ``"held-out scores"`` only where no member's
        evidence is finite (``notes`` say so).
    rule : str
        How ``weights`` are made, in words.
    upper : dict
        Member -> its weight with its log evidence raised, and every other's lowered, by
        ``SE_ALLOWANCE`` standard errors, and each gap to another member widened by the
        difference of their step shifts: what the estimate's noise and the step allow at most.
    evidence : dict
        Member -> its :class:`.member_evidence.Evidence` as a dict (``log_z``, ``se``, ``ess``,
        ``pareto_k``, ``n``, ``temperature``, ``reliable``).
    temperature : dict
        Recording -> the common temperature its likelihood is taken at.
    equal : dict
        Member -> ``1/n``; ``equal_rule`` states it.
    held_out : dict or None
        Member -> its share by the ranking's held-out scores; ``held_out_rule`` states it.
    notes : list of str
    step_shift : dict
        Member -> ``{"shift", "se"}``: its log evidence's change when the step is halved, added
        to its ``evidence`` for the weights (a member without a measured one takes the others'
        median shift, ``"measured"`` false); empty where none was given.
    """

    weights: dict
    method: str
    rule: str
    upper: dict = field(default_factory=dict)
    evidence: dict = field(default_factory=dict)
    temperature: dict = field(default_factory=dict)
    equal: dict = field(default_factory=dict)
    equal_rule: str = EQUAL_RULE
    held_out: dict | None = None
    held_out_rule: str = RANKING_RULE
    notes: list = field(default_factory=list)
    step_shift: dict = field(default_factory=dict)

    def of(self, names) -> list:
        """The weights of ``names``, in that order (``combine``'s ``weights`` argument)."""
        return [self.weights[n] for n in names]

    def screened(self, share=DECIDING_SHARE) -> list:
        """Members whose weight, even at its :attr:`upper` allowance, stays under ``share``."""
        return [n for n in self.weights if self.upper.get(n, self.weights[n]) < share]

    def to_dict(self) -> dict:
        return {"weights": dict(self.weights), "method": self.method, "rule": self.rule,
                "upper": dict(self.upper), "evidence": dict(self.evidence),
                "temperature": dict(self.temperature), "step_shift": dict(self.step_shift),
                "equal": dict(self.equal),
                "equal_rule": self.equal_rule,
                "held_out": None if self.held_out is None else dict(self.held_out),
                "held_out_rule": self.held_out_rule, "notes": list(self.notes)}


def common_temperature(draws) -> dict:
    """Recording -> the smallest discrepancy factor any member's chain was sampled at there.

    ``draws``: member -> :class:`.member_evidence.ImportanceDraws`, every member holding the
    same recordings (a one-line error otherwise)."""
    names = list(draws)
    records = draws[names[0]].records
    for n in names[1:]:
        if set(draws[n].records) != set(records):
            raise ValueError(f"common_temperature: {n} holds recordings {list(draws[n].records)}, "
                             f"{names[0]} holds {list(records)}")
    return {r: min(float(d.inflation[d.records.index(r)]) for d in draws.values())
            for r in records}


def evidence_weights(draws, rows=None, seed=0, step_shifts=None) -> SetWeights:
    """The members' posterior probabilities from their evidence.

    Parameters
    ----------
    draws : dict
        Member name (its structure) -> :class:`.member_evidence.ImportanceDraws`
        (:func:`.member_evidence.member_importance_draws`), or its ``to_dict()``.
    rows : list of dict, optional
        The members' rows of ``discovery.json``'s ``structures`` (``structure``, ``score``,
        ``margin``): their held-out-score shares are kept for comparison.
    seed : int
        Seeds the held-out-score shares' draws.
    step_shifts : dict, optional
        Member -> ``(shift, se)``: its log evidence's change when the step is halved
        (:attr:`tvcid.discovery.calibration.step_error.StepError.log_evidence_shift`). Given,
        the weights are the evidences' at half the step, and each pair's allowance is widened by
        the difference of their shifts (the module's docstring); a member left out takes the
        others' median shift and no allowance for it.

    Returns
    -------
    SetWeights
    """
    draws = {n: d if isinstance(d, ImportanceDraws) else ImportanceDraws.from_dict(d)
             for n, d in draws.items()}
    names = list(draws)
    if not names:
        raise ValueError("evidence_weights: no member")
    equal = {n: 1.0 / len(names) for n in names}
    held = None
    if rows:
        shares = ranking_shares([r for r in rows if r["structure"] in draws], seed=seed)
        total = sum(shares.values())
        held = {n: shares.get(n, 0.0) / total for n in names} if total > 0 else None
    temperature = common_temperature(draws)
    evidence = {n: log_evidence(d, [temperature[r] for r in d.records]) for n, d in draws.items()}
    notes = [f"{n}: its evidence is approximate (Pareto k {e.pareto_k:.2f}"
             f"{' >= ' + format(GOOD_K, 'g') if e.pareto_k >= GOOD_K else ''}, "
             f"{e.ess:.0f} effective points of {e.n})"
             for n, e in evidence.items() if not e.reliable and math.isfinite(e.log_z)]
    if len(names) == 1:
        return SetWeights({names[0]: 1.0}, "single member", "a single member takes all the weight",
                          {names[0]: 1.0}, {names[0]: evidence[names[0]].to_dict()}, temperature,
                          equal, held_out=held, notes=notes)
    log_z = np.array([evidence[n].log_z for n in names])
    if not np.any(np.isfinite(log_z)):
        weights = held or equal
        notes.append("no member's evidence is finite (every proposal point's run failed): "
                     + ("the held-out scores' shares are used" if held else "equal weights"))
        return SetWeights(dict(weights), "held-out scores" if held else "equal",
                          RANKING_RULE if held else EQUAL_RULE, dict(weights),
                          {n: e.to_dict() for n, e in evidence.items()}, temperature, equal,
                          held_out=held, notes=notes)
    shifts = _step_shifts(names, step_shifts)
    shift = np.array([shifts[n]["shift"] for n in names]) if shifts else np.zeros(len(names))
    log_z = log_z + shift
    weights = _normalised(log_z)
    se = np.array([evidence[n].se if math.isfinite(evidence[n].se) else 0.0 for n in names])
    allowance = SE_ALLOWANCE * (se[:, None] + se[None, :])
    if shifts:
        measured = np.array([shifts[n]["measured"] for n in names])
        step_se = np.array([shifts[n]["se"] for n in names])
        both = measured[:, None] & measured[None, :]
        allowance = allowance + np.where(
            both, np.abs(shift[:, None] - shift[None, :])
            + SE_ALLOWANCE * (step_se[:, None] + step_se[None, :]), 0.0)
    upper = {n: _upper(log_z, allowance, i) for i, n in enumerate(names)}
    return SetWeights({n: float(w) for n, w in zip(names, weights)}, "evidence", EVIDENCE_RULE,
                      upper, {n: e.to_dict() for n, e in evidence.items()}, temperature, equal,
                      held_out=held, notes=notes, step_shift=shifts)


def _step_shifts(names, step_shifts) -> dict:
    """Member -> ``{"shift", "se", "measured"}`` from ``evidence_weights``' ``step_shifts``; a
    member without a finite one takes the measured members' median shift; empty where no member
    has one."""
    given = {n: (float(v[0]), float(v[1])) for n, v in (step_shifts or {}).items()
             if n in names and math.isfinite(float(v[0]))}
    if not given:
        return {}
    median = float(np.median([v[0] for v in given.values()]))
    return {n: {"shift": given[n][0], "se": given[n][1] if math.isfinite(given[n][1]) else 0.0,
                "measured": True} if n in given
            else {"shift": median, "se": 0.0, "measured": False} for n in names}


def _upper(log_z, allowance, i) -> float:
    """Member ``i``'s weight with each gap to another member narrowed by ``allowance[i, k]``
    (``log_z`` ``-inf`` for a member without evidence)."""
    if not math.isfinite(log_z[i]):
        return 0.0
    others = [k for k in range(len(log_z)) if k != i and math.isfinite(log_z[k])]
    return float(1.0 / (1.0 + sum(math.exp(min(log_z[k] - log_z[i] - allowance[i, k], 700.0))
                                  for k in others)))


def _normalised(log_z) -> np.ndarray:
    """``exp(log_z)`` normalised to sum 1 (0 for ``-inf``)."""
    log_z = np.asarray(log_z, dtype=float)
    w = np.exp(log_z - np.max(log_z[np.isfinite(log_z)]))
    w = np.where(np.isfinite(log_z), w, 0.0)
    return w / w.sum()


def unsure_members(set_posterior) -> list:
    """The calibrated members whose weight is not final, so that the data cannot yet decide
    against them: each member of ``set_posterior`` (``discovery.json``'s, or :func:`combine`'s
    dict with its ``weighting``) under :data:`DECIDING_SHARE` whose weight at its allowance
    (:attr:`SetWeights.upper`: the evidence's noise and the step) reaches that share, and each
    whose chain stopped at its cap (not converged) or whose evidence is not reliable
    (:attr:`.member_evidence.Evidence.reliable`), unless its weight even at its allowance is
    under the share by :data:`UNSURE_NATS`. A member screened by its weight
    (``tvcid.set_stage``) is not unsure for its short chain or its evidence: the screening
    decided against it by its own rule, with the same margin for an unreliable run; the
    screening did not know its step, so the allowance's clause holds for it too.

    A set of one member, or one without evidence weights, has none. The members' order is kept.
    """
    members = (set_posterior or {}).get("members") or []
    weighting = (set_posterior or {}).get("weighting") or {}
    if len(members) < 2 or weighting.get("method") != "evidence":
        return []
    evidence, upper = weighting.get("evidence") or {}, weighting.get("upper") or {}
    floor = DECIDING_SHARE * math.exp(-UNSURE_NATS)
    out = []
    for m in members:
        name = m["structure"]
        screened = bool((m.get("posterior") or {}).get("screened"))
        unreliable = not (evidence.get(name) or {}).get("reliable", False)
        weight = m.get("weight", 1.0)
        at_most = upper.get(name, weight)
        if ((not screened and (not m.get("converged") or unreliable) and at_most >= floor)
                or weight < DECIDING_SHARE <= at_most):
            out.append(name)
    return out


def stored_unsure(set_posterior) -> list:
    """The run's own ``set_posterior.unsure``, or :func:`unsure_members` worked out from its
    stored members and weighting where it stores none."""
    stored = (set_posterior or {}).get("unsure")
    return list(stored) if stored is not None else unsure_members(set_posterior)


def merged_structures(structures) -> dict:
    """Structure of the set merged into another -> that member, from the rows of
    ``discovery.json``'s ``structures`` (``weighed_choices``' ``merged``)."""
    return {s["structure"]: s["merged_into"] for s in structures
            if s["indistinguishable_from_best"] and s.get("merged_into")}


def shown_choice(value) -> str:
    """A structural choice's value as the report shows it: a position's name, ``"on"`` or
    ``"off"`` for a component."""
    return value if isinstance(value, str) else ("on" if value else "off")


def decided_against(weights, unsure=(), share=DECIDING_SHARE) -> list:
    """The members the data decide against: under ``share`` of the weight, their weight final
    (not in ``unsure``, :func:`unsure_members`). ``weights``: member -> weight, or ``None`` (no
    member is decided against). The members' order is kept."""
    if weights is None:
        return []
    return [n for n, w in weights.items() if w < share and n not in set(unsure)]


def weighed_choices(decided, weights, set_structures=(), unsure=(), merged=None) -> dict:
    """Each structural choice decided by the set or by the members' weights, one rule for all.

    A choice the set's structures agree on (``decided[choice]`` not ``None``) is decided by the
    set. One they leave open is decided by the weights when the calibrated members holding every
    other value keep under :data:`DECIDING_SHARE` of the weight together, none of them is in
    ``unsure`` (:func:`unsure_members`: its weight is not final), and no structure of the set
    outside the calibrated members (beyond the cap, or failed) holds another value; otherwise
    it is not decided, and every value's share is given.

    A structure merged into another (``merged``: a superset that is its member at its added
    components' zero) is not calibrated, but its member speaks for it where the weights decide
    its added components off: it then counts outside the calibrated members only for a component
    value no calibrated member holds. Where the weights leave an added component open or decide
    it on, the superset could hold weight its member lacks (the truth's structure with a
    backlash its member has not), and its positions keep their choices open.

    Parameters
    ----------
    decided : dict
        Choice -> its value where the set's structures agree, else ``None``
        (:func:`tvcid.models.structures.shared_choices`).
    weights : dict
        Calibrated member (structure name) -> weight.
    set_structures : iterable of str
        Every structure of the set (merged ones included).
    unsure : iterable of str
        Calibrated members whose weight is not final (:func:`unsure_members`).
    merged : dict, optional
        Structure of ``set_structures`` merged into another -> that member.

    Returns
    -------
    dict
        Choice -> ``{"value": v or None, "by": "set" | "weights" | "open", "weights": {value:
        share}, "unsure": [values held by a member in unsure]}`` (values as the report shows
        them: ``"on"``/``"off"`` for a component).
    """
    from tvcid.models.structures import COMPONENT_FIELDS, Structure

    shown = shown_choice
    merged = dict(merged or {})
    parsed = {n: Structure.parse(n).to_dict()
              for n in set(weights) | set(set_structures) | set(merged.values())}
    added = {n: {c for c, v in parsed[n].items() if v is True and parsed[m][c] is not True}
             for n, m in merged.items()}
    without = [n for n in set_structures if n not in weights]
    components = set(COMPONENT_FIELDS)
    out = {}
    # the components first: whether the weights decide a merged superset's additions off
    for choice in sorted(decided, key=lambda c: c not in components):
        value = decided[choice]
        if value is not None:
            out[choice] = {"value": shown(value), "by": "set", "weights": {shown(value): 1.0},
                           "unsure": []}
            continue
        shares = {}
        for name, w in weights.items():
            v = shown(parsed[name][choice])
            shares[v] = shares.get(v, 0.0) + float(w)
        if choice in components:
            spoken = {n for n in without if n in merged}
        else:
            spoken = {n for n in without if n in merged
                      and all(out.get(c, {}).get("value") == "off" for c in added[n])}
        elsewhere = ({shown(parsed[n][choice]) for n in without if n not in spoken}
                     | ({shown(parsed[n][choice]) for n in spoken} - set(shares)))
        not_final = sorted({shown(parsed[n][choice]) for n in unsure if n in weights})
        best = max(shares, key=shares.get) if shares else None
        decisive = (best is not None and 1.0 - shares[best] < DECIDING_SHARE
                    and elsewhere | set(not_final) <= {best})
        for v in sorted(elsewhere - set(shares)):
            shares[v] = None  # held only by members without a weight
        out[choice] = {"value": best if decisive else None, "by": "weights" if decisive else "open",
                       "weights": shares, "unsure": not_final}
    return {c: out[c] for c in decided}
