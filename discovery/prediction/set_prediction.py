"""Predictions over the set of structures the recordings cannot tell apart: does the ambiguity
matter at this controller?

Each member of a discover directory's set predicts the cycle with its own posterior
(:func:`.cycles.predict_cycle`); the set's band is the equal-weight mixture of the members' draws
(the weights of :mod:`discovery.structure.set_posterior`). The members *agree* at a setting when
every pair of them agrees on whether the loop oscillates (both oscillate in most draws, or both do
not) and, where both oscillate, their 90 % bands of amplitude and of frequency overlap once each is
widened by what a recording of the cycle can resolve (:func:`measurement_resolution`); otherwise
the choice of structure changes the answer there, and the output says so. Without the widening,
members whose chains pin them tightly would be called apart for differences no recording could
show (two members of one set, fitting the recorded cycles alike, predict them 0.1-0.5 % apart
with bands narrower than that).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from .cycles import CYCLE, PredictionConfig, cycle_map, predict_cycle

__all__ = ["SetPrediction", "predict_cycle_over_set", "members_agree", "SetMap", "cycle_map_over_set",
           "measurement_resolution", "run_resolution"]

#: The recorded cycle's features that stand for the predicted amplitude and frequency.
_RESOLVED = {"amplitude": "H1", "frequency": "frequency"}
#: Half-width of a 90 % interval in standard deviations.
_Z90 = 1.6448536269514722


def measurement_resolution(recordings, window=10.0, dt=5e-4) -> dict:
    """Relative sd with which a recording resolves a cycle's amplitude and frequency.

    For each closed-loop recording, the features likelihood's covariance of its first harmonic
    and frequency over a ``window``-second window (sensor noise by Monte Carlo on the record,
    plus the cycle's own wander between windows:
    :class:`discovery.calibration.likelihood.features.FeatureTerm`), over the measured value; the
    median over the recordings. ``{"amplitude": sd, "frequency":
    sd}`` (fractions), or ``None`` without a closed-loop recording."""
    from discovery.calibration.likelihood.features import FeatureTerm

    features = tuple(_RESOLVED.values())
    rows = []
    for i, rec in enumerate(r for r in recordings if r.kind == "closed"):
        term = FeatureTerm(rec, window, 0.0, dt, features=features, rng=np.random.default_rng(i))
        sd = dict(zip(features, np.sqrt(np.diag(term.cov_hat)) / np.abs(term.observed)))
        rows.append({q: float(sd[f]) for q, f in _RESOLVED.items()})
    if not rows:
        return None
    return {q: float(np.median([r[q] for r in rows])) for q in _RESOLVED}


def run_resolution(directory) -> dict:
    """:func:`measurement_resolution` of a ``tvcid discover`` directory's closed-loop recordings
    (read from the paths its ``discovery.json`` names); ``None`` when it names none that can be
    read."""
    import json
    from pathlib import Path

    from models.recording import load_recording

    try:
        paths = json.loads((Path(directory) / "discovery.json").read_text())["recordings"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    recordings = [load_recording(p) for p in paths if Path(p).is_file()]
    return measurement_resolution(recordings) if recordings else None


def _mixture_quantiles(predictions, name) -> dict:
    """Quantiles of ``name`` over the oscillating draws of every member, equally weighted (each
    member's oscillating draws resampled to the same count by a seeded generator)."""
    rng = np.random.default_rng(0)
    pools = []
    for p in predictions:
        mask = p.outcomes.outcome == CYCLE
        values = np.asarray(getattr(p.outcomes, name))[mask]
        if values.size:
            pools.append(rng.choice(values, size=mask.size, replace=True))
    if not pools:
        return {"q05": None, "q50": None, "q95": None}
    q = np.quantile(np.concatenate(pools), [0.05, 0.5, 0.95])
    return {"q05": float(q[0]), "q50": float(q[1]), "q95": float(q[2])}


def _overlap(a, b, resolution=0.0) -> bool:
    """90 % bands ``a`` and ``b`` overlap, each widened by the 90 % interval of a measurement
    with relative sd ``resolution`` at its median."""
    wa, wb = (_Z90 * resolution * abs(x["q50"]) for x in (a, b))
    return a["q05"] - wa <= b["q95"] + wb and b["q05"] - wb <= a["q95"] + wa


def members_agree(bands: dict, resolution=None) -> tuple:
    """Whether the members' predictions agree (the module's rule), and the disagreeing pairs.

    ``bands``: member -> a :meth:`.cycles.CyclePrediction.to_dict`; ``resolution``: relative sd
    per quantity (:func:`measurement_resolution`; ``None``: the bands alone). Returns
    ``(agree, [(a, b, why), ...])``."""
    resolution = resolution or {}
    pairs = []
    for (na, a), (nb, b) in combinations(bands.items(), 2):
        osc_a, osc_b = a["fraction_oscillating"] > 0.5, b["fraction_oscillating"] > 0.5
        if osc_a != osc_b:
            pairs.append((na, nb, "one oscillates, the other not"))
            continue
        if not osc_a:
            continue
        for q in ("amplitude", "frequency"):
            if (a[q]["q50"] is not None and b[q]["q50"] is not None
                    and not _overlap(a[q], b[q], resolution.get(q, 0.0))):
                pairs.append((na, nb, f"{q} bands apart"))
                break
    return not pairs, pairs


@dataclass(frozen=True)
class SetPrediction:
    """The cycle at one setting, per member of the set and mixed.

    Attributes
    ----------
    members : dict
        Structure name -> :class:`.cycles.CyclePrediction`.
    resolution : dict or None
        What a recording resolves (:func:`measurement_resolution`), for :func:`members_agree`.
    """

    members: dict = field(repr=False)
    resolution: dict = None

    def to_dict(self) -> dict:
        bands = {n: p.to_dict() for n, p in self.members.items()}
        agree, pairs = members_agree(bands, self.resolution)
        preds = list(self.members.values())
        return {
            "amplitude": _mixture_quantiles(preds, "amplitude"),
            "frequency": _mixture_quantiles(preds, "frequency"),
            "fraction_oscillating": float(np.mean([p.fraction_oscillating for p in preds])),
            "members_agree": agree,
            "disagreeing": [{"members": [a, b], "why": why} for a, b, why in pairs],
            "members": bands,
            "weights": "equal",
            "resolution": self.resolution,
        }


def predict_cycle_over_set(member_draws: dict, setting, config=PredictionConfig(),
                           describing=True, resolution=None) -> SetPrediction:
    """:func:`.cycles.predict_cycle` for every member (``member_draws``: structure name ->
    :class:`.draws.PosteriorDraws`, e.g. :func:`.draws.load_set_draws`); ``resolution`` as in
    :func:`members_agree`."""
    if not member_draws:
        raise ValueError("predict_cycle_over_set: no member")
    return SetPrediction({n: predict_cycle(d, setting, config, describing=describing)
                          for n, d in member_draws.items()}, resolution)


@dataclass(frozen=True)
class SetMap:
    """:class:`.cycles.CycleMap` per member over one grid, and where the members disagree
    (``resolution`` as in :func:`members_agree`)."""

    members: dict = field(repr=False)
    resolution: dict = None

    def disagreement(self) -> np.ndarray:
        """Boolean array over the grid: True where some pair of members disagrees
        (:func:`members_agree` on each grid point's bands)."""
        maps = list(self.members.values())
        shape = maps[0].shape
        out = np.zeros(shape, dtype=bool)
        for idx in np.ndindex(*shape):
            bands = {n: m.point_bands(idx) for n, m in self.members.items()}
            out[idx] = not members_agree(bands, self.resolution)[0]
        return out

    def to_dict(self) -> dict:
        return {"members": {n: m.to_dict() for n, m in self.members.items()},
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
                       describing=True, progress=False, resolution=None) -> SetMap:
    """:func:`.cycles.cycle_map` for every member over the same grid; ``resolution`` as in
    :func:`members_agree`."""
    if not member_draws:
        raise ValueError("cycle_map_over_set: no member")
    return SetMap({n: cycle_map(d, base, grid, config, describing=describing, progress=progress)
                   for n, d in member_draws.items()}, resolution)
