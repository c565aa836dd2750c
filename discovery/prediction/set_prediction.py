"""Predictions over the set of structures the recordings cannot tell apart: does the ambiguity
matter at this controller?

Each member of a discover directory's set predicts the cycle with its own posterior
(:func:`.cycles.predict_cycle`). The set's band is the mixture of the members' oscillating draws,
member ``i``'s draws carrying together the mass ``w_i f_i`` (its weight ``w_i``, e.g. the set
posterior's stored weight, times the fraction ``f_i`` of its draws that oscillate), so that a
member oscillating in few of its draws holds as small a share of the band as its cycle has of
the set's probability; the mixture oscillates with probability ``sum_i w_i f_i``.

The members *agree* at a setting when every pair of them agrees on whether the loop oscillates
(both oscillate in most draws, or both do not) and, where both oscillate, on the amplitude and on
the frequency. Two members ``a`` and ``b`` agree on a quantity when the difference of their
medians is within the 90 % half-width of the difference of two independent measurements, one
under each:

    |m_a - m_b| <= sqrt(h_a^2 + r_a^2 + h_b^2 + r_b^2),

with ``h`` a member's 90 % half-width on the side facing the other (its band, moved out by the
solver error) and ``r = 1.645 s m`` the 90 % half-width of a recording's measurement of the cycle at
relative sd ``s`` (:func:`measurement_resolution`; 0 without one). Independent spreads add in
quadrature: the sum of the half-widths (``2 h`` for two equal ones, against ``sqrt(2) h``) bounds
the difference of two Gaussian measurements of one value at 98 %, not 90 %. Otherwise the choice of
structure changes the answer there, and the output says so. Where the members carry weights, a
member under the deciding share (:data:`tvcid.discovery.structure.indistinguishable.DECIDING_SHARE`)
whose weight is final is not counted: the data have decided against it, and the output names it
(``not_counted``); one whose weight is not final (``unsure``) is counted. Without
``r``, members whose chains pin them tightly would be called apart for differences no recording
could show (two members of one set, fitting the recorded cycles alike, predict them 0.1-0.5 % apart
with bands narrower than that).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from .cycles import CYCLE, PredictionConfig, cycle_map, predict_cycle

__all__ = ["SetPrediction", "predict_cycle_over_set", "members_agree", "SetMap",
           "cycle_map_over_set", "measurement_resolution", "run_resolution"]

#: The recorded cycle's features that stand for the predicted amplitude and frequency.
_RESOLVED = {"amplitude": "H1", "frequency": "frequency"}
#: Why a pair parts on a quantity.
_DIFFER = {"amplitude": "amplitudes differ", "frequency": "frequencies differ"}
#: Half-width of a 90 % interval in standard deviations.
_Z90 = 1.6448536269514722


def measurement_resolution(recordings, window=10.0, dt=5e-4, seed=0) -> dict:
    """Relative sd with which a recording resolves a cycle's amplitude and frequency.

    For each closed-loop recording, the features likelihood's covariance of its first harmonic
    and frequency over a ``window``-second window (sensor noise by Monte Carlo on the record,
    plus the cycle's own wander between windows:
    :class:`tvcid.discovery.calibration.likelihood.features.FeatureTerm`), over the measured value; the
    median over the recordings. ``{"amplitude": sd, "frequency":
    sd}`` (fractions), or ``None`` without a closed-loop recording. The Monte Carlo of recording
    ``i`` draws from ``numpy.random.default_rng([seed, i])``."""
    from tvcid.discovery.calibration.likelihood.features import FeatureTerm

    features = tuple(_RESOLVED.values())
    rows = []
    for i, rec in enumerate(r for r in recordings if r.kind == "closed"):
        term = FeatureTerm(rec, window, 0.0, dt, features=features,
                           rng=np.random.default_rng([seed, i]))
        sd = dict(zip(features, np.sqrt(np.diag(term.cov_hat)) / np.abs(term.observed)))
        rows.append({q: float(sd[f]) for q, f in _RESOLVED.items()})
    if not rows:
        return None
    return {q: float(np.median([r[q] for r in rows])) for q in _RESOLVED}


def run_resolution(directory, seed=0) -> dict:
    """:func:`measurement_resolution` (with ``seed``) of a ``tvcid discover`` directory's
    closed-loop recordings (read from the paths its ``discovery.json`` names); ``None`` when it
    names none that can be read."""
    import json
    from pathlib import Path

    from tvcid.models.recording import load_recording

    try:
        paths = json.loads((Path(directory) / "discovery.json").read_text())["recordings"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    recordings = [load_recording(p) for p in paths if Path(p).is_file()]
    return measurement_resolution(recordings, seed=seed) if recordings else None


def _weighted_quantiles(values, weights, levels) -> np.ndarray:
    """Quantiles of a discrete distribution: ``values`` with probabilities proportional to
    ``weights``; each the smallest value at which the cumulative distribution reaches the level
    (the inverted CDF: no interpolation across the gap between two members' cycles, which would
    put a quantile where no draw is)."""
    order = np.argsort(values)
    v, w = np.asarray(values, float)[order], np.asarray(weights, float)[order]
    cum = np.cumsum(w) / w.sum()
    idx = np.searchsorted(cum, np.asarray(levels) * (1 - 1e-12), side="left")
    return v[np.minimum(idx, v.size - 1)]


def _mixture_band(predictions, weights, name) -> dict:
    """Quantiles of ``name`` over the members' oscillating draws, member ``n``'s draws together
    of mass ``weights[n]`` times its oscillating fraction (each draw ``weights[n] / n_draws``);
    ``q05`` and ``q95`` moved out by the largest solver error of the members in the band."""
    values, mass, error = [], [], 0.0
    for n, p in predictions.items():
        mask = p.outcomes.outcome == CYCLE
        if not mask.any() or weights[n] <= 0:
            continue
        values.append(np.asarray(getattr(p.outcomes, name))[mask])
        mass.append(np.full(int(mask.sum()), weights[n] / mask.size))
        e = p.solver_error.get(name, 0.0)
        error = max(error, e) if np.isfinite(e) else error
    if not values:
        return {"q05": None, "q50": None, "q95": None}
    q = _weighted_quantiles(np.concatenate(values), np.concatenate(mass), [0.05, 0.5, 0.95])
    return {"q05": float(q[0] - error), "q50": float(q[1]), "q95": float(q[2] + error)}


def _normalised(weights, names) -> dict:
    """``weights`` (name -> weight; ``None``: equal) over ``names``, summing to 1."""
    if weights is None:
        return {n: 1.0 / len(names) for n in names}
    missing = [n for n in names if n not in weights]
    if missing:
        raise ValueError(f"no weight for member {missing[0]}")
    w = {n: float(weights[n]) for n in names}
    if not all(np.isfinite(v) and v >= 0 for v in w.values()) or sum(w.values()) <= 0:
        raise ValueError(f"member weights must be finite, >= 0 and not all 0 (got {w})")
    total = sum(w.values())
    return {n: v / total for n, v in w.items()}


def _apart(a, b, resolution=0.0) -> bool:
    """Bands ``a`` and ``b`` (``q05``, ``q50``, ``q95``) differ by more than two independent
    measurements do: ``|m_a - m_b| > sqrt(h_a^2 + r_a^2 + h_b^2 + r_b^2)`` (the module's rule),
    ``h`` the half-width on the side facing the other, ``r`` the 90 % half-width of a
    measurement with relative sd ``resolution`` at the median."""
    lo, hi = (a, b) if a["q50"] <= b["q50"] else (b, a)
    h_lo, h_hi = lo["q95"] - lo["q50"], hi["q50"] - hi["q05"]
    r_lo, r_hi = (_Z90 * resolution * abs(x["q50"]) for x in (lo, hi))
    return hi["q50"] - lo["q50"] > float(np.sqrt(h_lo**2 + r_lo**2 + h_hi**2 + r_hi**2))


def members_agree(bands: dict, resolution=None, weights=None, unsure=()) -> tuple:
    """Whether the members' predictions agree (the module's rule), and the disagreeing pairs.

    ``bands``: member -> a :meth:`.cycles.CyclePrediction.to_dict`; ``resolution``: relative sd per
    quantity (:func:`measurement_resolution`; ``None``: the bands alone); ``weights``: member ->
    weight, where a member the data decide against
    (:func:`tvcid.discovery.members.set_weights.decided_against`: under the deciding share, not
    in ``unsure``, the members whose weight is not final) is not counted (``None``: every member
    counts). Returns ``(agree, [(a, b, why), ...])``."""
    from tvcid.discovery.members.set_weights import decided_against

    resolution = resolution or {}
    against = set(decided_against(
        None if weights is None else {n: weights.get(n, 1.0) for n in bands}, unsure))
    counted = {n: b for n, b in bands.items() if n not in against}
    pairs = []
    for (na, a), (nb, b) in combinations(counted.items(), 2):
        osc_a, osc_b = a["fraction_oscillating"] > 0.5, b["fraction_oscillating"] > 0.5
        if osc_a != osc_b:
            pairs.append((na, nb, "one oscillates, the other not"))
            continue
        if not osc_a:
            continue
        for q in ("amplitude", "frequency"):
            if (a[q]["q50"] is not None and b[q]["q50"] is not None
                    and _apart(a[q], b[q], resolution.get(q, 0.0))):
                pairs.append((na, nb, _DIFFER[q]))
                break
    return not pairs, pairs


#: How the set's band mixes the members, as the output states it.
MIXTURE_RULE = ("each member's oscillating draws together carry its weight times its "
                "oscillating fraction")


@dataclass(frozen=True)
class SetPrediction:
    """The cycle at one setting, per member of the set and mixed.

    Attributes
    ----------
    members : dict
        Structure name -> :class:`.cycles.CyclePrediction`.
    resolution : dict or None
        What a recording resolves (:func:`measurement_resolution`), for :func:`members_agree`.
    weights : dict or None
        Structure name -> weight of the member in the set (normalised here); ``None``: equal.
    unsure : tuple
        Members whose weight is not final, counted in the verdict whatever their weight
        (:func:`members_agree`).
    """

    members: dict = field(repr=False)
    resolution: dict = None
    weights: dict = None
    unsure: tuple = ()

    def member_weights(self) -> dict:
        """Structure name -> weight, summing to 1."""
        return _normalised(self.weights, list(self.members))

    def to_dict(self) -> dict:
        """The mixture's bands and oscillating fraction (the module's rule), the verdict, and per
        member its :meth:`.cycles.CyclePrediction.to_dict` with its ``weight`` and
        ``share_of_band`` (its part of the mixture's oscillating mass)."""
        from tvcid.discovery.members.set_weights import decided_against

        w = self.member_weights()
        bands = {n: p.to_dict() for n, p in self.members.items()}
        agree, pairs = members_agree(bands, self.resolution,
                                     weights=w if self.weights is not None else None,
                                     unsure=self.unsure)
        mass = {n: w[n] * b["fraction_oscillating"] for n, b in bands.items()}
        total = sum(mass.values())
        for n, b in bands.items():
            b["weight"] = w[n]
            b["share_of_band"] = mass[n] / total if total > 0 else 0.0
        return {
            "amplitude": _mixture_band(self.members, w, "amplitude"),
            "frequency": _mixture_band(self.members, w, "frequency"),
            "fraction_oscillating": float(total),
            "members_agree": agree,
            "disagreeing": [{"members": [a, b], "why": why} for a, b, why in pairs],
            # members the weights decided against: not counted in the verdict
            "not_counted": sorted(decided_against(w if self.weights is not None else None,
                                                  self.unsure)),
            "unsure": list(self.unsure),
            "members": bands,
            "weights": w,
            "weights_stored": self.weights is not None,
            "mixture": MIXTURE_RULE,
            "resolution": self.resolution,
        }


def predict_cycle_over_set(member_draws: dict, setting, config=PredictionConfig(),
                           describing=True, resolution=None, weights=None,
                           unsure=()) -> SetPrediction:
    """:func:`.cycles.predict_cycle` for every member (``member_draws``: structure name ->
    :class:`.draws.PosteriorDraws`, e.g. :func:`.draws.load_set_draws`); ``resolution`` as in
    :func:`members_agree`; ``weights``: structure name -> weight (e.g.
    :func:`.draws.load_set_weights`; ``None``: equal); ``unsure``: members whose weight is not
    final (:func:`.draws.load_unsure_members`)."""
    if not member_draws:
        raise ValueError("predict_cycle_over_set: no member")
    _normalised(weights, list(member_draws))  # refuse bad weights before simulating
    return SetPrediction({n: predict_cycle(d, setting, config, describing=describing)
                          for n, d in member_draws.items()}, resolution, weights, tuple(unsure))


@dataclass(frozen=True)
class SetMap:
    """:class:`.cycles.CycleMap` per member over one grid, and where the members disagree
    (``resolution`` as in :func:`members_agree`; ``weights`` and ``unsure`` as in
    :class:`SetPrediction`)."""

    members: dict = field(repr=False)
    resolution: dict = None
    weights: dict = None
    unsure: tuple = ()

    def disagreement(self) -> np.ndarray:
        """Boolean array over the grid: True where some pair of members disagrees
        (:func:`members_agree` on each grid point's bands)."""
        maps = list(self.members.values())
        shape = maps[0].shape
        out = np.zeros(shape, dtype=bool)
        for idx in np.ndindex(*shape):
            bands = {n: m.point_bands(idx) for n, m in self.members.items()}
            out[idx] = not members_agree(
                bands, self.resolution,
                weights=None if self.weights is None else _normalised(self.weights,
                                                                      list(self.members)),
                unsure=self.unsure)[0]
        return out

    def to_dict(self) -> dict:
        return {"members": {n: m.to_dict() for n, m in self.members.items()},
                "weights": _normalised(self.weights, list(self.members)),
                "disagree": self.disagreement().tolist(), "resolution": self.resolution}

    def plot(self, ax=None):
        """The grid, points where the members disagree marked; returns the axes."""
        import matplotlib.pyplot as plt

        first = next(iter(self.members.values()))
        if ax is None:
            ax = plt.subplots(figsize=(5, 4))[1]
        dis = self.disagreement().astype(float)
        if len(first.keys) == 1:
            ax.plot(first.values[0], dis, "o-")
            ax.set(xlabel=first.keys[0], ylabel="members disagree (1) / agree (0)")
        else:
            ax.pcolormesh(first.values[1], first.values[0], dis, cmap="Reds", vmin=0, vmax=1,
                          shading="nearest")
            ax.set(xlabel=first.keys[1], ylabel=first.keys[0],
                   title="where the choice of structure matters")
        return ax


def cycle_map_over_set(member_draws: dict, base, grid: dict, config=PredictionConfig(),
                       describing=True, progress=False, resolution=None, weights=None,
                       unsure=()) -> SetMap:
    """:func:`.cycles.cycle_map` for every member over the same grid; ``resolution`` as in
    :func:`members_agree`, ``weights`` and ``unsure`` as in :func:`predict_cycle_over_set`."""
    if not member_draws:
        raise ValueError("cycle_map_over_set: no member")
    _normalised(weights, list(member_draws))
    return SetMap({n: cycle_map(d, base, grid, config, describing=describing, progress=progress)
                   for n, d in member_draws.items()}, resolution, weights, tuple(unsure))
