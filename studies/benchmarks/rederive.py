"""The set rule weighed again on the discovery benchmark's finished rows, without a search.

Every row stores its ranking (each ranked structure's held-out fold costs), so a change of the
rule for the indistinguishable set reaches finished draws (:func:`rederived`), and the rule's
margin floors can be scaled over a range to show its trade-off between holding the truth and a
small set (:func:`floor_scan`, :class:`FloorScan`). ``python -m
tvcid.studies.benchmarks.discovery --rederive`` and ``--floor-scan`` run them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvcid.discovery.structure import StructureDiscovery
from tvcid.models.structures import Structure

from ..common import code_commit
from .scenarios import draw_scenario, write_recordings
from .verdicts import fit_ceiling, set_verdict, undecided_marked

#: The commit of the code this process imported.
CODE_COMMIT = code_commit()


def draw_floors(seed, out_dir, ranges="wide"):
    """The margin floors (:func:`tvcid.discovery.structure.indistinguishable.margin_floors`) of draw
    ``seed``'s recordings (drawn within ``ranges``), regenerated into ``out_dir/drawNNN`` unless
    they are there."""
    from tvcid.discovery.structure.estimator import validate_recordings
    from tvcid.discovery.structure.indistinguishable import margin_floors
    from tvcid.discovery.structure.targets import make_target

    paths = write_recordings(draw_scenario(seed, ranges=ranges), Path(out_dir) / f"draw{seed:03d}",
                             reuse=True)
    dt = StructureDiscovery().dt
    return margin_floors([make_target(r, dt) for r in validate_recordings(paths)])


def rederived(row, floors, commit=CODE_COMMIT):
    """``row`` with its indistinguishable set, winner and verdict derived again from its stored
    ranking (every ranked structure's held-out fold costs) by the current set rule
    (:func:`tvcid.discovery.structure.indistinguishable.indistinguishable_set`), with ``floors`` per
    recording.

    No search runs: the fits and scores are the row's own. Structures the row did not rank join
    the set where they contain a member (as in the discovery). A changed verdict keeps the old one
    under ``previous``; ``set_rule_check`` says which commit's rule and what changed.
    """
    from tvcid.discovery.structure.indistinguishable import indistinguishable_set
    from tvcid.discovery.structure.ranking import StructureFit
    from tvcid.models.structures import structure_space

    def fit(structure, score, cost, folds=None):
        return StructureFit(structure=structure, params=None, theta=np.zeros(1), cost=cost,
                            cost_by_recording={}, origin=row.get("commit", ""), score=score,
                            fold_costs=None if folds is None else np.asarray(folds, dtype=float))

    fits = [fit(Structure.parse(x["structure"]), x["score"], x["cost"], x["fold_costs"])
            for x in row["ranking"]]
    named = {f.structure for f in fits}
    fits += [fit(s, math.inf, math.inf) for s in structure_space({})[0] if s not in named]
    fits.sort(key=lambda f: (f.score, f.cost))
    ranked = indistinguishable_set(fits, len(floors), floors=np.asarray(floors, dtype=float))
    verdict = set_verdict(ranked, Structure.parse(row["structure"]))
    for key in ("members", "truth_member"):
        del verdict[key]
    keys = ("winner", "set_size", "truth_in_set", "right_or_in_small_set")
    changed = [k for k in keys if verdict[k] != row[k]]
    out = dict(row)
    if changed:
        out["previous"] = {k: row.get(k) for k in ("commit", "winner", "right_winner",
                                                   "truth_in_set", "set_size",
                                                   "right_or_in_small_set")}
    out.update(verdict)
    merged = {f.structure.name: f.merged_into for f in ranked}
    out["ranking"] = [{**x, "merged_into": merged[x["structure"]]} for x in row["ranking"]]
    floors_text = ", ".join(f"{v:.3g}" for v in floors)
    out["set_rule_check"] = (
        f"the indistinguishable set re-derived from this row's ranking with {commit}'s rule "
        f"(floors {floors_text}): " + ("unchanged" if not changed else "; ".join(
            f"{k} {row[k]} -> {verdict[k]}" for k in changed)))
    return undecided_marked(out)


#: Scales of the margin floors weighed by ``--floor-scan`` (1 is the rule in use).
FLOOR_SCALES = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)


@dataclass(frozen=True)
class FloorScan:
    """The set rule's trade-off on finished rows: each scale of the margin floors against the
    fraction of draws whose truth is the winner or in a set of at most 3, the fraction whose
    set holds the truth, and the mean set size (:func:`floor_scan`).

    Attributes
    ----------
    scales : tuple of float
        Factors on every recording's floor
        (:func:`tvcid.discovery.structure.indistinguishable.margin_floors`).
    right_or_in_set_le3, truth_in_set, mean_set_size : tuple of float
        Per scale, over the draws.
    misses : tuple of tuple of int
        Per scale, the seeds neither the winner nor in a set of at most 3.
    ceiling : float
        Fraction of the draws where at most 3 minimal structures fit the recordings as well as
        the truth itself (:func:`.verdicts.as_well_as_truth`): what a set of at most 3 can reach without
        excluding a structure the data favour as much as the truth.
    """

    scales: tuple
    right_or_in_set_le3: tuple
    truth_in_set: tuple
    mean_set_size: tuple
    misses: tuple
    ceiling: float = math.nan

    @property
    def missed_at_every_scale(self) -> tuple:
        """Seeds that no floor turns into a hit: the set rule is not what holds them."""
        common = set(self.misses[0])
        for m in self.misses[1:]:
            common &= set(m)
        return tuple(sorted(common))

    def to_dict(self) -> dict:
        return {"scales": list(self.scales), "right_or_in_set_le3": list(self.right_or_in_set_le3),
                "truth_in_set": list(self.truth_in_set), "mean_set_size": list(self.mean_set_size),
                "misses": [list(m) for m in self.misses], "ceiling": self.ceiling,
                "missed_at_every_scale": list(self.missed_at_every_scale)}

    def plot(self, ax=None):
        """Both rates and the goal (90 %) against the floors' scale; the rule's scale 1 marked."""
        if ax is None:
            from tvcid.figures import pyplot

            ax = pyplot().subplots(figsize=(6, 3.6))[1]
        ax.plot(self.scales, self.right_or_in_set_le3, "o-", label="winner, or in a set of at most 3")
        ax.plot(self.scales, self.truth_in_set, "s--", label="truth in the reported set")
        ax.axhline(0.9, color="0.5", lw=0.8, ls=":", label="goal")
        ax.axhline(self.ceiling, color="C3", lw=0.8, ls="-.",
                   label="at most 3 structures fit as well as the truth")
        ax.axvline(1.0, color="0.7", lw=0.8)
        ax.set_xlabel("scale on every recording's margin floor (1: the rule in use)")
        ax.set_ylabel("fraction of draws")
        ax.set_ylim(0.0, 1.02)
        ax.legend(loc="lower right", fontsize=8)
        return ax


def floor_scan(rows, floors, scales=FLOOR_SCALES):
    """Re-derive every finished row's set (:func:`rederived`) with its margin floors scaled.

    ``floors``: seed -> the draw's floors per recording (:func:`draw_floors`). No search runs. A
    draw missed at every scale (:attr:`FloorScan.missed_at_every_scale`) is not held by the
    margin's floor: its structures' held-out scores do not tell the truth from more than two
    others, or, with no floor, exclude it.
    """
    rows = [r for r in rows if "error" not in r]
    hits, truth_in, sizes, misses = [], [], [], []
    for scale in scales:
        again = [rederived(r, np.asarray(floors[r["seed"]], dtype=float) * scale) for r in rows]
        hits.append(float(np.mean([r["right_or_in_small_set"] for r in again])))
        truth_in.append(float(np.mean([r["truth_in_set"] for r in again])))
        sizes.append(float(np.mean([r["set_size"] for r in again])))
        misses.append(tuple(r["seed"] for r in again if not r["right_or_in_small_set"]))
    return FloorScan(tuple(float(s) for s in scales), tuple(hits), tuple(truth_in), tuple(sizes),
                     tuple(misses), fit_ceiling(rows))
