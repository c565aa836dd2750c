"""The out-of-sample ranking: held-out folds, scores, and the fitted structures they rank.

* :class:`StructureFit` -- one structure fitted to the recordings, with its score and verdict;
* :func:`in_sample_screen` -- the in-sample cost beyond which a structure is left unranked;
* :func:`rank` -- two-fold out-of-sample scores for the best in-sample fits, then the set rule
  (:func:`.indistinguishable.indistinguishable_set`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tvcid.models.hypotheses import ActuatorParams
from tvcid.models.structures import Structure

from .indistinguishable import indistinguishable_set, margin_floors
from .search import Objective, concurrent_map, progress_bar, refine
from .targets import make_target

__all__ = ["StructureFit", "rank", "in_sample_screen", "ranked_candidates",
           "RANK_OPEN_LOOP_REFINEMENT", "SCREEN_ABS"]

#: The ranking's open-loop simulations take steps this many times finer than the search's
#: (:func:`rank`).
RANK_OPEN_LOOP_REFINEMENT = 2
#: The screen's allowance per recording (:func:`in_sample_screen`).
SCREEN_ABS = 0.5


@dataclass
class StructureFit:
    """One structure fitted to the recordings.

    Attributes
    ----------
    structure : tvcid.models.structures.Structure
    params : ActuatorParams
        Every field, the structure's enums set, absent components zeroed.
    theta : ndarray
        Search coordinates of ``params`` (:class:`.coordinates.SearchSpace`).
    cost : float
        In-sample cost (sum over recordings; about 1 per recording for the generating model).
    cost_by_recording : dict
    origin : str
        How the fit was reached.
    score : float
        The ranking criterion's value (lower is better).
    criterion : str
    coordinate_sd : dict
        Local spread of each search coordinate (:func:`.search.local_sd`).
    sindy_seeds : list of dict
        SINDy's proposals for this structure (natural parameters).
    indistinguishable_from_best : bool
    merged_into : str or None
        Name of the nested structure this one is merged into.
    held_out : dict
        Held-out cost per recording.
    fold_costs : ndarray or None
        Held-out costs ``(2 folds, n recordings)``; ``None`` when not ranked.
    margin : float or None
        How much worse than the best score this one's may be and still be indistinguishable
        from it (:func:`.indistinguishable.indistinguishable_margin`); ``None`` when not weighed.
    margin_se : float or None
        The standard error of its score's difference from the best's, behind ``margin``.
    """

    structure: Structure
    params: ActuatorParams
    theta: np.ndarray
    cost: float
    cost_by_recording: dict
    origin: str
    score: float = math.nan
    criterion: str = ""
    coordinate_sd: dict = field(default_factory=dict)
    sindy_seeds: list = field(default_factory=list)
    indistinguishable_from_best: bool = False
    merged_into: str | None = None
    held_out: dict = field(default_factory=dict)
    fold_costs: np.ndarray | None = None
    margin: float | None = None
    margin_se: float | None = None

    def to_dict(self) -> dict:
        return {
            "structure": self.structure.name,
            "components": self.structure.to_dict(),
            "params": self.params.to_dict(),
            "score": self.score,
            "criterion": self.criterion,
            "cost": self.cost,
            "cost_by_recording": self.cost_by_recording,
            "held_out": self.held_out,
            "fold_costs": None if self.fold_costs is None else np.asarray(self.fold_costs).tolist(),
            "margin": self.margin,
            "margin_se": self.margin_se,
            "indistinguishable_from_best": self.indistinguishable_from_best,
            "merged_into": self.merged_into,
            "coordinate_sd": self.coordinate_sd,
            "origin": self.origin,
            "sindy_seeds": self.sindy_seeds,
        }


def rank(fits, spaces, targets, dt, rank_nfev, max_ranked, progress=False):
    """Two-fold out-of-sample scores for the best in-sample fits; sets and merges.

    Every recording is cut into two halves (:meth:`.targets.CycleTarget.halves`: the first and
    second half of the cycle's periods; open loop: interleaved blocks). Each structure is
    refitted (locally, from its optimum) on one half of every recording and scored on the
    other, both ways round; the score is the mean of the two held-out costs. Unlike leaving a
    whole recording out, every fold still sees every experiment, so a parameter that only one
    experiment informs (a friction offset seen by a square wave alone) is not left free to
    wander when that experiment is held out.

    Open-loop recordings are simulated here at a step ``RANK_OPEN_LOOP_REFINEMENT`` times
    finer than the search's: the search step's own error is not the same in every structure,
    and the ranking must not read it as evidence (``tests/test_discover_ranking_step.py``).

    Parameters
    ----------
    fits : dict
        Structure -> :class:`StructureFit`, every structure searched; each gets its ``score``,
        ``criterion``, ``held_out``, ``fold_costs`` and verdict here.
    spaces : dict
        Structure -> :class:`.coordinates.SearchSpace`.
    targets : list
        The search's targets, one per recording (:func:`.targets.make_target`).
    dt : float
        The search's simulation step (s).
    rank_nfev : int
        Least-squares evaluations of each fold's refit.
    max_ranked : int
        Structures (best in-sample first) that always get the ranking; every further structure
        within :func:`in_sample_screen` of the best is ranked too (:func:`ranked_candidates`).
    progress : bool
        A progress bar (tqdm).

    Returns
    -------
    ranked : list of StructureFit
        Winner first, the set marked (:func:`.indistinguishable.indistinguishable_set`).
    n_evaluations : int
        Parameter sets the refits simulated.
    simulated_seconds : float
        Seconds those runs simulated (:class:`.search.Objective`).
    simulated_steps : float
        Kernel steps of those runs.
    """
    order = sorted(fits.values(), key=lambda f: f.cost)
    targets = [make_target(t.recording, dt / RANK_OPEN_LOOP_REFINEMENT)
               if t.kind == "open" else t for t in targets]
    objective = Objective(targets)
    folds = [t.halves() for t in targets]
    fit_on = [[h[k] for h in folds] for k in (0, 1)]
    candidates = ranked_candidates(order, max_ranked, len(targets))
    for f in order[len(candidates):]:
        f.score, f.criterion = math.inf, "not ranked (in-sample cost far from the best)"
    bar = progress_bar(2 * len(candidates), "two-fold out-of-sample ranking", progress)

    def held_out(task):  # one structure's refit on one fold, scored on the other
        f, k = task
        fr = refine(spaces[f.structure], objective, f.theta, max_nfev=rank_nfev, targets=fit_on[k])
        bar.update()
        return objective.costs([spaces[f.structure].params(fr.theta)], fit_on[1 - k])[0]

    scored = iter(concurrent_map(held_out, [(f, k) for f in candidates for k in (0, 1)]))
    bar.close()
    for f in candidates:
        per_unit = np.array([next(scored), next(scored)])
        f.fold_costs = per_unit
        f.held_out = {t.name: float(per_unit[:, i].mean()) for i, t in enumerate(targets)}
        f.score = float(per_unit.sum(axis=1).mean())
        f.criterion = ("two-fold out-of-sample cost (fit on one half of every recording, "
                       "scored on the other; mean of both ways)")
    ranked = indistinguishable_set(sorted(order, key=lambda f: (f.score, f.cost)), len(targets),
                                   floors=margin_floors(targets))
    return ranked, objective.n_evaluations, objective.simulated_seconds, objective.simulated_steps


def ranked_candidates(order, max_ranked, n_recordings):
    """The fits given the out-of-sample ranking: the first ``max_ranked`` of ``order`` (best
    in-sample cost first) and every further one within :func:`in_sample_screen` of the best.

    No count caps the second group: a structure the screen keeps may be indistinguishable from
    the best, and one left unranked would be missing from the set. Where one cycle fits every
    structure of the grammar about equally (costs of a few thousandths), the truth's in-sample
    cost falls anywhere in that order.
    """
    limit = in_sample_screen(order[0].cost, n_recordings)
    return [f for i, f in enumerate(order) if i < max_ranked or f.cost <= limit]


def in_sample_screen(best_cost, n_recordings):
    """In-sample cost above which a structure cannot be indistinguishable from the best.

    A score is a held-out cost, which is at least about the in-sample cost (the overfit of a few
    parameters to hundreds of residuals is a small fraction of a unit per recording), so a
    structure whose in-sample cost exceeds the best's by far more than
    :func:`.indistinguishable.indistinguishable_margin` can allow is left unranked. The screen is
    twice the best's cost plus ``SCREEN_ABS`` per recording: generous, since two folds that
    disagree widen the margin beyond its floor.
    """
    return 2.0 * best_cost + SCREEN_ABS * n_recordings
