"""The posterior over the set of structures the recordings cannot tell apart.

Each distinct member of the indistinguishable set (:mod:`tvcid.discovery.structure.indistinguishable`)
is calibrated on its own (:mod:`tvcid.discovery.members.member_calibration`), every parameter the
recordings inform sampled, the linear block included; where the set leaves a component open
(backlash, friction offset, band-pass loop) and no distinct member has it, the richer structure
merged into one is calibrated too.
:func:`combine` then mixes the members' draws, each with its weight, into one posterior of the
physical quantities they share:

* ``dead_zone`` (rad on the error, rad/s on the velocity signal: members with the dead zone in
  different places are combined per place, ``dead_zone[error]`` and ``dead_zone[velocity]``);
* ``threshold``: the velocity form's ``z - off``, which motion pins (docs/models.md#what-a-recording-pins);
* ``backlash``, ``friction_offset`` and ``bandpass_gain``, in the members that have the
  component; ``present`` is the weight of those members, and where it is under 1 the set leaves
  the component open: its interval is the one *if present*;
* ``delay``;
* the linear block's ``dc_gain`` (``1/K``, rad per rad of command) and ``bandwidth`` (rad/s, the
  -3 dB frequency of ``K1/(s^3 + K2 s^2 + K3 s + K K1)``, the position loop without its delay and
  nonlinearities).

The weights come from the data (:mod:`tvcid.discovery.members.set_weights`); the equal-weight
mixture is kept beside them as the alternative the report states.

A quantity *depends on the structure* when the spread of the members' medians exceeds half the
median width of their own 90 % intervals: then the combined interval is wide because the members
disagree, not because each is uncertain.

A quantity is *not pinned* when, in a member that has it, its 90 % interval spans more than half
of the 90 % interval its prior implies (the member's priors sampled and mapped through
:func:`member_quantities`, in the quantity's own coordinate,
:class:`tvcid.discovery.calibration.profile_range.QuantityCoordinate`): composite quantities are
judged on their own draws, not through the parameters they are made of. Beside its interval,
each quantity has the range the recordings *allow*
(:func:`tvcid.discovery.calibration.profile_range.allowed_range`): where its profile log
posterior stays within 1.92 nats of the best, the members' ranges joined; an end the prior sets
is *open* (the prior's floor or ceiling).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tvcid.discovery.calibration.profile_range import QuantityCoordinate, allowed_range
from tvcid.discovery.calibration.widening import widen_draws
from tvcid.models.quantities import COMPONENT_QUANTITIES, QUANTITY_UNITS, member_quantities

from ..structure.indistinguishable import DECIDING_SHARE

__all__ = ["MemberPosterior", "SetPosterior", "combine", "not_pinned", "prior_quantities",
           "richer_members", "calibration_reasons", "decided_absent", "left_open_by_choices"]

#: A quantity depends on the structure when the members' medians spread by more than this
#: fraction of the median width of their 90 % intervals.
STRUCTURE_DEPENDENCE = 0.5
#: A quantity is not pinned when its 90 % interval spans more than this fraction of the one its
#: prior implies.
NOT_PINNED_FRACTION = 0.5
#: Prior draws that map a member's priors to its quantities' prior-implied spread.
PRIOR_DRAWS = 4000


def prior_quantities(params: dict, priors: dict, n=PRIOR_DRAWS, seed=0) -> dict:
    """The combined quantities under a member's priors alone: ``n`` draws of every prior in
    ``priors`` (name -> :class:`tvcid.discovery.calibration.priors.Prior`) mapped through
    :func:`member_quantities` with the unsampled fields at ``params``; the spread against which
    :func:`combine` judges whether the recordings pin a quantity."""
    rng = np.random.default_rng(seed)
    draws = {name: np.asarray(prior.to_natural(prior.sample_internal(rng, n)), dtype=float)
             for name, prior in priors.items()}
    return member_quantities(params, draws)


def richer_members(rows, decided) -> list:
    """The rows of the ranking to calibrate beyond the set's distinct members: for each
    component the set leaves open (``decided[component] is None``) that no distinct member has,
    the best-scored structure merged into a member that has it. ``rows`` are the ranking's rows
    (``structure``, ``indistinguishable_from_best``, ``merged_into``), best first."""
    from tvcid.models.structures import Structure

    members = [r for r in rows if r["indistinguishable_from_best"]]
    distinct = [r for r in members if r["merged_into"] is None]
    have = {c for r in distinct for c in Structure.parse(r["structure"]).components}
    out = []
    for component in COMPONENT_QUANTITIES:
        if decided.get(component, False) is not None or component in have:
            continue
        richer = [r for r in members if r["merged_into"] is not None and r not in out
                  and component in Structure.parse(r["structure"]).components]
        if richer:
            out.append(richer[0])
            have |= set(Structure.parse(richer[0]["structure"]).components)
    return out


def calibration_reasons(distinct, richer, max_members) -> dict:
    """Structure -> why the set stage calibrates it: one of the ``max_members`` best held-out
    scores among the set's ``distinct`` members (rows, best first), or, of the ``richer`` rows
    (:func:`richer_members`), the best-scored structure with a component the set leaves open
    that no distinct member calibrated has."""
    from tvcid.models.structures import Structure

    out = {r["structure"]: f"held-out score {i + 1} of the set's {len(distinct)} distinct members"
           for i, r in enumerate(distinct[:max_members])}
    have = {c for r in distinct[:max_members] for c in Structure.parse(r["structure"]).components}
    for r in richer:
        own = [c for c in Structure.parse(r["structure"]).components if c not in have]
        out[r["structure"]] = (f"the best-scored structure with {' and '.join(own)}, which the set "
                               f"leaves open (merged into `{r['merged_into']}`)")
        have |= set(own)
    return out


def not_pinned(post, priors, fraction=NOT_PINNED_FRACTION) -> list:
    """Sampled parameters whose 90 % interval spans more than ``fraction`` of their prior (in
    the prior's own coordinate): the recordings do not pin them."""
    out = []
    for j, name in enumerate(post.names):
        prior = priors.get(name)
        if prior is None:
            continue
        lo, hi = prior.internal_bounds
        q05, q95 = np.quantile(post.internal[:, j], (0.05, 0.95))
        if q95 - q05 > fraction * (hi - lo):
            out.append(name)
    return out


@dataclass
class MemberPosterior:
    """One member of the set, calibrated.

    Attributes
    ----------
    structure : str
        Its name (:meth:`tvcid.models.structures.Structure.parse` reads it).
    quantities : dict
        Combined quantity -> draws (:func:`member_quantities`).
    summary : dict
        Its calibration's summary (:meth:`tvcid.discovery.calibration.Posterior.summary`): every
        sampled parameter's quantiles, convergence, ``at_prior_bound``.
    score_over_margin : float
        ``(score - best score) / margin``: at most 1 for a distinct member of the set.
    log_prob : ndarray, optional
        The log posterior of each draw (for :func:`allowed_range`).
    prior_quantities : dict, optional
        Combined quantity -> draws under the priors alone (:func:`prior_quantities`).
    step_error : dict, optional
        Combined quantity -> how far its median moves when the integration step is halved
        (:mod:`tvcid.discovery.calibration.step_error`).
    """

    structure: str
    quantities: dict
    summary: dict = field(default_factory=dict)
    score_over_margin: float = 0.0
    log_prob: np.ndarray | None = None
    prior_quantities: dict | None = None
    step_error: dict | None = None

    @property
    def converged(self) -> bool:
        return bool(self.summary.get("converged", False))


@dataclass
class SetPosterior:
    """The members' posteriors, their weights and their mixture (:func:`combine`).

    Attributes
    ----------
    members : list of MemberPosterior
    quantities : dict
        Quantity -> its combined summary (:func:`combine`).
    criterion : str
        How the members are weighted, stated for the report.
    weights : ndarray
        Each member's weight (summing to 1).
    left_open_uncalibrated : tuple of str
        Component quantities the set leaves open that no calibrated member holds: printed
        "present or absent" without an interval.
    member_intervals : list of dict, optional
        Per member, quantity -> its ``q05``, ``q50``, ``q95`` as mixed: widened to the member's
        step error where it is narrower (``widened`` true).
    """

    members: list
    quantities: dict
    criterion: str
    weights: np.ndarray = None
    left_open_uncalibrated: tuple = ()
    member_intervals: list | None = None

    def interval(self, name, level=0.90):
        """The combined 90 % interval ``(q05, q95)`` of quantity ``name`` (each member's draws
        widened to its step error where narrower, within the quantity's support)."""
        if level != 0.90:
            raise ValueError(f"interval: only the 90 % interval is stored (got level {level})")
        q = self.quantities[name]
        return q["q05"], q["q95"]

    def to_dict(self) -> dict:
        w = self.weights if self.weights is not None else np.full(len(self.members), 1 / len(self.members))
        return {
            "criterion": self.criterion,
            "quantities": self.quantities,
            "left_open_uncalibrated": list(self.left_open_uncalibrated),
            "members": [{"structure": m.structure, "weight": float(wi),
                         "equal_weight": 1.0 / len(self.members),
                         "score_over_margin": m.score_over_margin, "converged": m.converged,
                         "quantities": intervals,
                         "step_error": m.step_error,
                         "posterior": m.summary}
                        for m, wi, intervals in zip(self.members, w, self._member_intervals())],
        }

    def _member_intervals(self):
        if self.member_intervals is not None:
            return self.member_intervals
        return [{k: _quantiles(v) for k, v in m.quantities.items()} for m in self.members]

    def plot(self, ax=None, names=("backlash", "delay", "threshold")):
        """Each member's 90 % interval and median (lines, thicker for more weight) beside the
        combined one (thick), for the quantities ``names`` the set has; returns the axes (one
        per quantity)."""
        import matplotlib.pyplot as plt

        names = [n for n in names if n in self.quantities]
        if ax is None:
            ax = plt.subplots(1, len(names), figsize=(3.2 * len(names), 2.8), squeeze=False)[1][0]
        w = self.weights if self.weights is not None else np.full(len(self.members), 1 / len(self.members))
        for a, name in zip(np.atleast_1d(ax), names):
            rows = [(m.structure, own[name], wi)
                    for m, wi, own in zip(self.members, w, self._member_intervals())
                    if name in m.quantities]
            for i, (_, q, wi) in enumerate(rows):
                a.plot([q["q05"], q["q95"]], [i, i], color="C0", lw=0.8 + 3 * wi)
                a.plot(q["q50"], i, "o", color="C0", ms=3)
            c = self.quantities[name]
            a.plot([c["q05"], c["q95"]], [-1, -1], color="C3", lw=4)
            a.plot(c["q50"], -1, "o", color="C3")
            a.set_yticks(range(-1, len(rows)), ["combined"] + [f"member {i + 1}" for i in range(len(rows))],
                         fontsize=7)
            a.set_xlabel(f"{name} ({QUANTITY_UNITS.get(name, '')})")
        return ax


def _quantiles(values) -> dict:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"q05": None, "q50": None, "q95": None}
    q05, q50, q95 = np.quantile(v, (0.05, 0.5, 0.95))
    return {"q05": float(q05), "q50": float(q50), "q95": float(q95)}


def width_over_prior(values, prior_values) -> float | None:
    """The 90 % width of a quantity's draws over the 90 % width its prior implies, both in the
    prior draws' :class:`~tvcid.discovery.calibration.profile_range.QuantityCoordinate`; ``None``
    without prior draws."""
    if prior_values is None:
        return None
    p = np.asarray(prior_values, dtype=float)
    v = np.asarray(values, dtype=float)
    p, v = p[np.isfinite(p)], v[np.isfinite(v)]
    if p.size < 20 or v.size < 20:
        return None
    coordinate = QuantityCoordinate.of_range(p.min(), p.max())
    if coordinate.log:
        v = v[v > 0]
        if v.size < 20:
            return None
    p, v = coordinate.to(p), coordinate.to(v)
    prior_width = float(np.diff(np.quantile(p, (0.05, 0.95)))[0])
    width = float(np.diff(np.quantile(v, (0.05, 0.95)))[0])
    return width / prior_width if prior_width > 0 else (0.0 if width == 0 else float("inf"))


#: Members with less than this share of the weight of those having a quantity neither flag it
#: as depending on the structure nor widen its allowed range.
NEGLIGIBLE_WEIGHT = 0.01


def partly_present(q) -> bool:
    """Whether the members with combined quantity ``q``'s component and those without it both
    keep at least :data:`~tvcid.discovery.structure.indistinguishable.DECIDING_SHARE` of the
    weight."""
    return DECIDING_SHARE <= q.get("present", 1.0) <= 1.0 - DECIDING_SHARE


def decided_absent(q) -> bool:
    """Whether the weights decide combined quantity ``q``'s component absent: the members with
    it hold under :data:`~tvcid.discovery.structure.indistinguishable.DECIDING_SHARE` of the weight
    (and the set does not leave it open to uncalibrated members)."""
    return q.get("present", 1.0) < DECIDING_SHARE and not q.get("left_open")


def printed_present_or_absent(q) -> bool:
    """Whether combined quantity ``q`` (a :func:`combine` entry) is a component the report prints
    "present or absent": the members with it and those without both keep at least the deciding
    share of the weight (:func:`partly_present`), or the set leaves the component open to members
    that could not be calibrated (``left_open``)."""
    return bool(q.get("left_open")) or partly_present(q)


def left_open_quantities(decided) -> tuple:
    """The component quantities (:data:`COMPONENT_QUANTITIES`) whose component the set's decisions
    leave open (``decided[component] is None``), in :data:`QUANTITY_UNITS`' order."""
    names = {COMPONENT_QUANTITIES[c] for c, v in decided.items()
             if v is None and c in COMPONENT_QUANTITIES}
    return tuple(n for n in QUANTITY_UNITS if n in names)


def left_open_by_choices(choices) -> dict:
    """Component quantity -> why its component prints "present or absent" whatever the calibrated
    members' weights say, from the choices of
    :func:`tvcid.discovery.members.set_weights.weighed_choices`: ``True`` where a value of the
    open choice is held only by members without a weight (beyond the cap, or failed),
    ``"weight not final"`` where a value under the deciding share is held by a member whose
    weight is not final (``unsure``; an unsure member on the side over the share leaves the
    other side decided against as far as it goes). ``combine``'s ``left_open``."""
    def side(test):
        return left_open_quantities({c: None if v["by"] == "open" and test(v) else True
                                     for c, v in choices.items()})

    uncalibrated = side(lambda v: None in v["weights"].values())
    not_final = side(lambda v: any(v["weights"].get(u) is not None
                                   and v["weights"][u] < DECIDING_SHARE
                                   for u in v.get("unsure") or ()))
    return {**dict.fromkeys(not_final, "weight not final"), **dict.fromkeys(uncalibrated, True)}


def combine(members, weights=None, n_draws=4000, seed=0, criterion=None,
            left_open=()) -> SetPosterior:
    """Mix the members' draws, each with its weight, into one posterior per shared quantity.

    Parameters
    ----------
    members : list of MemberPosterior
    weights : array_like, optional
        Each member's weight (normalised here); equal where omitted.
    n_draws : int
        Draws of the mixture, shared among the members by weight (each member's resampled
        with a seeded ``numpy.random.Generator``).
    criterion : str, optional
        How the weights were made, for the report.
    left_open : iterable of str, or dict, optional
        Component quantities whose component the set leaves open
        (:func:`left_open_quantities`): whatever the calibrated members' weights say, they print
        "present or absent" (``left_open`` true), since a member on the other side may be one
        that could not be calibrated. A dict maps each to why (:func:`left_open_by_choices`):
        ``True`` (the default: the other side's structures were not calibrated), or ``"weight
        not final"`` (the side under the deciding share holds a member whose weight is not
        final, :func:`tvcid.discovery.members.set_weights.unsure_members`); ``left_open`` then
        holds it.

    Returns
    -------
    SetPosterior
        ``quantities``: name -> ``q05``, ``q50``, ``q95`` (of the members that have the
        quantity, by their weights), ``unit``, ``members`` (how many have it), ``present`` (their
        share of the weight: under 1 where the set leaves the component or place open),
        ``depends_on_structure`` and ``spread_over_width`` (the module docstring's rule),
        ``width_over_prior`` (the largest over the members that have it) and ``pinned``
        (``None`` without prior draws), ``allowed`` (``[low, high]``, the members'
        :func:`allowed_range` joined, or ``None``) with ``allowed_open`` (``[low end, high
        end]``: the profile has not fallen by the drop where the draws end) and
        ``allowed_at_prior`` (that open end is the prior's: the prior stops the draws there;
        an open end short of it is where a chain's draws end), ``prior_range`` (``[floor,
        ceiling]`` of the members' priors, mapped to the quantity), ``step_error`` (the
        members' step errors averaged by their weights: a draw's expected error), ``widened``
        (some member's draws were widened to its own step error before the mixing,
        :func:`tvcid.discovery.calibration.widening.widen_draws`: a member's interval narrower than
        twice its error becomes at least its median +- the error, within the quantity's
        support, ``support``: ``[floor, ceiling]``, ``None`` for an open end) with
        ``step_error_widened`` (the largest error that widened one) and the
        mixture's ends before the widening (``q05_sampled``, ``q95_sampled``), and
        ``equal_weights`` (the equal-weight mixture's ``q05``, ``q50``, ``q95``).
    """
    if not members:
        raise ValueError("combine: no member to combine")
    w = np.full(len(members), 1.0) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (len(members),) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"combine: weights must be {len(members)} non-negative numbers, not all 0 "
                         f"(got {weights!r})")
    w = w / w.sum()
    rng = np.random.default_rng(seed)
    present = {n for m in members for n in m.quantities}
    names = [n for n in QUANTITY_UNITS if n in present] + sorted(present - set(QUANTITY_UNITS))
    quantities = {}
    # each member's draws widened to its own step error (:func:`widen_draws`), within the support
    supports = [{n: _support(n, m) for n in m.quantities} for m in members]
    widened_draws = [{n: widen_draws(v, (m.step_error or {}).get(n), support[n])
                      for n, v in m.quantities.items()} for m, support in zip(members, supports)]
    for name in names:
        having = [i for i, m in enumerate(members) if name in m.quantities]
        share = float(w[having].sum())
        inner = w[having] / share if share > 0 else np.full(len(having), 1 / len(having))
        draws = [widened_draws[i][name][0] for i in having]
        mixed = _mix(draws, inner, n_draws, rng)
        equal = _mix(draws, np.full(len(having), 1 / len(having)), n_draws, rng)
        q = _quantiles(mixed)
        counted = [i for i, wi in zip(having, inner) if wi >= NEGLIGIBLE_WEIGHT] or having
        own = [_quantiles(widened_draws[i][name][0]) for i in counted]
        medians = [o["q50"] for o in own if o["q50"] is not None]
        widths = [o["q95"] - o["q05"] for o in own if o["q50"] is not None]
        spread = (max(medians) - min(medians)) if medians else 0.0
        width = float(np.median(widths)) if widths else 0.0
        ratio = spread / width if width > 0 else (0.0 if spread == 0 else float("inf"))
        ranges = [allowed_range(members[i].quantities[name], members[i].log_prob) for i in counted
                  if members[i].log_prob is not None]
        ranges = [r for r in ranges if r is not None]
        allowed, allowed_open, allowed_prior = None, None, None
        bounds = _prior_bounds([(members[i].prior_quantities or {}).get(name) for i in counted])
        if ranges:
            low = min(ranges, key=lambda r: r.low)
            high = max(ranges, key=lambda r: r.high)
            allowed = [low.low, high.high]
            allowed_open = [any(r.low_open for r in ranges if r.low <= low.low),
                            any(r.high_open for r in ranges if r.high >= high.high)]
            allowed_prior = [bool(allowed_open[0] and bounds is not None
                                  and _near(allowed[0], bounds[0], bounds)),
                             bool(allowed_open[1] and bounds is not None
                                  and _near(allowed[1], bounds[1], bounds))]
        over = [width_over_prior(members[i].quantities[name],
                                 (members[i].prior_quantities or {}).get(name)) for i in counted]
        over = [o for o in over if o is not None]
        errors = np.array([_finite_or_zero((members[i].step_error or {}).get(name))
                           for i in having])
        step = float(inner @ errors)  # a draw's expected error: each member's at its weight
        widened_by = [i for i in counted if widened_draws[i][name][1]]
        widened = bool(widened_by)
        if widened:  # what the members' draws give before their widening, for the record
            sampled = _quantiles(_mix([members[i].quantities[name] for i in having], inner,
                                      n_draws, np.random.default_rng(seed)))
            q = {**q, "q05_sampled": sampled["q05"], "q95_sampled": sampled["q95"]}
        quantities[name] = {**q, "unit": QUANTITY_UNITS.get(name, ""), "members": len(having),
                            "present": share,
                            "spread_over_width": ratio,
                            "depends_on_structure": bool(len(counted) > 1 and ratio > STRUCTURE_DEPENDENCE),
                            "width_over_prior": max(over) if over else None,
                            "pinned": (max(over) <= NOT_PINNED_FRACTION) if over else None,
                            "allowed": allowed, "allowed_open": allowed_open,
                            "allowed_at_prior": allowed_prior,
                            "prior_range": None if bounds is None else list(bounds),
                            "step_error": step or None, "widened": widened,
                            "step_error_widened": (max(float(errors[having.index(i)])
                                                       for i in widened_by) if widened else None),
                            "support": _joined_support([supports[i][name] for i in counted]),
                            "equal_weights": _quantiles(equal)}
    why = left_open if isinstance(left_open, dict) else dict.fromkeys(left_open, True)
    for name, reason in why.items():
        if name in quantities:
            quantities[name]["left_open"] = reason
    if criterion is None:
        criterion = ("equal weights" if weights is None else "weights given")
    intervals = [{n: {**_quantiles(v), **({"widened": True} if was else {})}
                  for n, (v, was) in d.items()} for d in widened_draws]
    return SetPosterior(list(members), quantities, criterion, w,
                        left_open_uncalibrated=tuple(n for n in left_open if n not in quantities),
                        member_intervals=intervals)


#: An open end of the allowed range within this fraction of the prior's range (in the
#: quantity's coordinate) of the prior's own end reaches it: the prior stops the draws there.
PRIOR_END = 0.05


def _prior_bounds(prior_draws):
    """The prior's range of a quantity (the extremes of its members' prior draws), or ``None``."""
    parts = [np.asarray(p, dtype=float) for p in prior_draws if p is not None]
    parts = [p[np.isfinite(p)] for p in parts]
    parts = [p for p in parts if p.size]
    if not parts:
        return None
    return float(min(p.min() for p in parts)), float(max(p.max() for p in parts))


def _near(value, end, bounds) -> bool:
    """Whether ``value`` lies within :data:`PRIOR_END` of the prior's range from its ``end``, in
    the prior range's :class:`~tvcid.discovery.calibration.profile_range.QuantityCoordinate`
    (its own units for a value not positive)."""
    lo, hi = bounds
    coordinate = QuantityCoordinate(bool(QuantityCoordinate.of_range(lo, hi).log and value > 0))
    value, end, lo, hi = (coordinate.to(v) for v in (value, end, lo, hi))
    return abs(value - end) <= PRIOR_END * (hi - lo)


#: Combined quantities that cannot be negative: a widened interval stops at 0.
NON_NEGATIVE = frozenset({"dead_zone[error]", "dead_zone[velocity]", "backlash", "bandpass_gain",
                          "delay", "dc_gain", "bandwidth"})


def _finite_or_zero(value) -> float:
    return float(value) if value is not None and math.isfinite(float(value)) else 0.0


def _support(name, member):
    """Where combined quantity ``name`` of ``member`` can lie: not below 0 where it cannot be
    negative, and within its prior draws' range (stretched to hold the member's own draws);
    ``None`` where nothing bounds it."""
    floor = 0.0 if name in NON_NEGATIVE else None
    ceiling = None
    prior = _prior_bounds([(member.prior_quantities or {}).get(name)])
    if prior is not None:
        v = np.asarray(member.quantities[name], dtype=float)
        v = v[np.isfinite(v)]
        low, high = (min(prior[0], v.min()), max(prior[1], v.max())) if v.size else prior
        floor = low if floor is None else max(floor, low)
        ceiling = high
    return None if floor is None and ceiling is None else (floor, ceiling)


def _joined_support(supports):
    """The members' supports of one quantity joined: ``[floor, ceiling]``, ``None`` for an end
    one member leaves open."""
    if not supports or any(b is None for b in supports):
        return [None, None] if supports else None
    floors, ceilings = [b[0] for b in supports], [b[1] for b in supports]
    return [None if None in floors else float(min(floors)),
            None if None in ceilings else float(max(ceilings))]


def _mix(draws, weights, n_draws, rng):
    """``n_draws`` draws of the mixture of ``draws`` (one array a member) by ``weights``: each
    member's share (rounded, at least one draw for a positive weight) taken systematically over
    its sorted draws (one seeded offset, evenly spaced ranks), so that a member's quantiles
    pass into the mixture without resampling noise."""
    counts = np.maximum(np.round(np.asarray(weights) * n_draws).astype(int),
                        (np.asarray(weights) > 0).astype(int))
    parts = []
    for d, k in zip(draws, counts):
        v = np.sort(np.asarray(d, dtype=float))
        if k > 0 and v.size:
            parts.append(v[np.minimum(((np.arange(k) + rng.uniform()) * v.size / k).astype(int),
                                      v.size - 1)])
    return np.concatenate(parts) if parts else np.array([])
