"""The set rule: which structures the recordings cannot tell from the best, and which are merged.

* :func:`indistinguishable_margin` -- how much worse than the best a held-out score may be and
  still not be told apart from it (Student's t quantile for the degrees of freedom the standard
  error has, times the standard error of the score difference, each recording's from the
  disagreement of the two folds, with a floor per recording);
* :func:`margin_floors` -- that floor per recording: ``TOL_ABS``, raised by a wandering cycle;
* :func:`indistinguishable_set` -- the members of the set, the structures merged into a simpler
  member, and the winner;
* :func:`_contains` -- one structure is another with components added (at those components' zero
  it is the other).

What every member shares is :func:`tvcid.models.structures.shared_choices` of the set's structures.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

__all__ = ["TOL_ABS", "DECIDING_SHARE", "MARGIN_QUANTILE", "indistinguishable_margin",
           "margin_degrees", "margin_floors", "indistinguishable_set"]

#: Floor of the margin within which a score is indistinguishable from the best, per recording
#: (:func:`indistinguishable_margin`).
TOL_ABS = 0.1
#: A member of the set, or a side of a structural choice, holding less than this share of the
#: set's weight is decided against: its component is "decided" and its chain is not run to its
#: cap.
DECIDING_SHARE = 0.05
#: One-sided quantile of the margin: a structure is left out when its score exceeds the best's by
#: more than this quantile of the difference's t distribution (2 standard errors where the
#: error is known: the normal's quantile at 2).
MARGIN_QUANTILE = float(stats.norm.cdf(2.0))


def indistinguishable_set(ranked, n_recordings, floors=None):
    """Mark the structures the recordings cannot tell from the best; the winner first.

    ``ranked``: :class:`.ranking.StructureFit` objects with ``score`` and ``fold_costs``, best
    score first. Members: every score within :func:`indistinguishable_margin` of the best. Merged
    (``merged_into``): a member that only adds a component to another member without beating it
    by the margin, and every superset of a member whatever its own fit scored (at its added
    components' zero it is that member, so a worse score is a search failure and the data cannot
    exclude it). The winner is the best-scoring structure not merged into another. ``floors``:
    the margin's floor per recording (:func:`margin_floors`; default ``TOL_ABS`` each).
    """
    ranked = list(ranked)
    best, n = ranked[0], n_recordings
    inside = [best]
    for f in ranked[1:]:
        if not math.isfinite(f.score):
            break
        f.margin = indistinguishable_margin(best.fold_costs, f.fold_costs, n, floors)
        sd, _ = _recording_sd(best.fold_costs, f.fold_costs, n, floors)
        f.margin_se = math.sqrt(float(np.sum(sd**2)))
        if f.score - best.score <= f.margin:
            inside.append(f)
    names = {f.structure: f for f in inside}
    for f in inside:
        f.indistinguishable_from_best = True
        # a superset that does not beat its nested structure is that structure
        for comp in f.structure.components:
            sub = names.get(f.structure.without(comp))
            if sub is not None and f.score >= sub.score - indistinguishable_margin(
                    sub.fold_costs, f.fold_costs, n, floors):
                f.merged_into = sub.structure.name
                break
    # a superset of a member reproduces it exactly (its added components at zero): whatever
    # its own fit scored (a worse score is a search failure), the data cannot exclude it
    members = sorted(inside, key=lambda f: f.score)
    for f in ranked:
        if f.indistinguishable_from_best:
            continue
        sub = next((m for m in members if _contains(f.structure, m.structure)), None)
        if sub is not None:
            f.indistinguishable_from_best = True
            f.merged_into = sub.merged_into or sub.structure.name
    # the winner: the best-scoring structure that is not merged into a simpler one
    winner = next(f for f in ranked if f.merged_into is None)
    ranked.remove(winner)
    ranked.insert(0, winner)
    return ranked


def margin_floors(targets):
    """Floor of :func:`indistinguishable_margin` per recording: ``TOL_ABS``, or a limit cycle's
    :attr:`.targets.CycleTarget.window_cost` where that is larger.

    A wandering cycle (the band-pass loop's) costs even the generating model about its window
    cost, from where the simulated window falls in the wander, and that cost scatters by about
    as much from one fit to the next; a score difference below it is no evidence
    (``tests/test_discover.py::test_wandering_cycles_raise_the_margin_floor``).
    """
    return np.array([max(TOL_ABS, t.window_cost) for t in targets])


def indistinguishable_margin(best_units, other_units, n_recordings, floors=None):
    """How much worse than the best a score may be and still not be told apart from it.

    ``*_units`` are held-out costs ``(2 folds, n recordings)``. A recording's difference between
    the structures is measured twice, once per fold; the disagreement of the two measures its
    noise (the sd of their mean is ``|d0 - d1| / 2``), never taken below half that recording's
    floor (``TOL_ABS``, or ``floors`` per recording when given: :func:`margin_floors`). The
    standard error of the score difference sums the recordings' variances, their errors
    independent: ``se = sqrt(sum_i max(|d0_i - d1_i| / 2, floor_i / 2)^2)``. The margin is
    ``t_q(nu) se``, Student's t quantile :data:`MARGIN_QUANTILE` at the degrees of freedom ``nu``
    the standard error has (:func:`margin_degrees`): two standard errors where the floors set it,
    more where two folds' disagreement, one degree of freedom a recording, does.

    Two folds estimate a recording's noise from one difference: where that estimate sets the
    margin, it is as often far below the noise as far above it, and twice it is too small a
    margin exactly when the records are short; the t quantile carries that uncertainty (for one
    recording, ``t_q(1) = 13.97``: 7 times the two standard errors). On the discovery
    benchmark's draws the margin's miss rate and the set's size are measured by
    ``python -m tvcid.studies.benchmarks.discovery --rederive`` (docs/results.md).

    The floors add in quadrature like the folds' noise, not linearly: a linear sum lets
    recordings that do not discriminate widen the margin in proportion to their number
    (``tests/test_discover.py::test_recordings_that_do_not_discriminate_widen_the_margin_in_quadrature``).
    Recordings are not exchangeable (a square wave can decide what a sine cannot), so their
    spread is not taken as noise.
    """
    sd, estimated = _recording_sd(best_units, other_units, n_recordings, floors)
    se = math.sqrt(float(np.sum(sd**2)))
    nu = margin_degrees(sd, estimated)
    return float(stats.t.ppf(MARGIN_QUANTILE, nu) if math.isfinite(nu) else 2.0) * se


def margin_degrees(sd, estimated) -> float:
    """Welch-Satterthwaite degrees of freedom of ``sqrt(sum sd_i^2)``: each recording whose sd
    the folds estimate (``estimated``) has one, a floor is known (infinitely many):
    ``(sum sd_i^2)^2 / sum_estimated sd_i^4``; infinite where no recording's is estimated."""
    sd = np.asarray(sd, dtype=float)
    est = np.asarray(estimated, dtype=bool)
    fourth = float(np.sum(sd[est] ** 4))
    return float(np.sum(sd**2)) ** 2 / fourth if fourth > 0 else math.inf


def _recording_sd(best_units, other_units, n_recordings, floors):
    """Each recording's sd of the mean fold difference, floored, and whether the folds set it."""
    d = np.asarray(other_units, dtype=float) - np.asarray(best_units, dtype=float)
    floor = (np.full(n_recordings, TOL_ABS) if floors is None
             else np.asarray(floors, dtype=float))
    folds = np.abs(d[0] - d[1]) / 2.0
    return np.maximum(folds, floor / 2.0), folds > floor / 2.0


def _contains(parent, s):
    """``parent`` is ``s`` with components added (the band-pass loop among them): at those
    components' zero it is ``s``."""
    return (s.dead_zone_position == parent.dead_zone_position
            and s.delay_position == parent.delay_position
            and set(s.components) < set(parent.components))
