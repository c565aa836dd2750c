"""One structure's global search on all recordings (:class:`GlobalFit`).

Differential evolution on the coarse targets, then least squares from the distinct best members
of its final population (:func:`_searched`), repeated until the best two agree
(:func:`best_of_restarts`); with open-loop and closed-loop recordings, staged: the open-loop
recordings alone first (:meth:`GlobalFit.fit_open_loop`), then all of them in the box that fit
narrowed. The structure search (:mod:`.structure_search`) runs one per class, as tasks
(:mod:`.tasks`) or in its own process.
"""
from __future__ import annotations

import math
import time

from .indistinguishable import TOL_ABS
from .search import distinct_members, global_search, local_sd, refine, refine_all

__all__ = ["GlobalFit", "best_of_restarts", "N_STARTS", "OPEN_LOOP_RESTARTS",
           "WHOLE_BOX_RESTARTS", "OPEN_LOOP_BOX"]

#: Distinct members of a global search's final population refined locally (the best among them).
N_STARTS = 3
#: Independent short searches of one stage (:func:`best_of_restarts`): at least the first number,
#: then more until the best two agree, up to the second; the open-loop stage, and a search of the
#: whole box (recordings of one kind). With open-loop tests the limit cycles are searched once,
#: in the box the open-loop fit narrowed. The band-pass loop's wandering cycles rarely let two
#: searches agree, so a whole-box search often runs to its maximum, and that maximum is 4.
OPEN_LOOP_RESTARTS = (3, 8)
WHOLE_BOX_RESTARTS = (2, 4)
#: Half-width of the box kept around the open-loop stage's fit, in local spreads of each coordinate.
OPEN_LOOP_BOX = 6.0


class GlobalFit:
    """The global searches of single structures on one objective.

    Parameters
    ----------
    objective : .search.Objective
        Every recording's target.
    sizes : .structure_search.SearchSizes
    rng : numpy.random.Generator
        The searches' draws, in the order they run.

    Attributes
    ----------
    searches : dict
        Independent searches run per stage (``open_loop``, ``global``; :func:`best_of_restarts`).
    open_loop_seconds : float
        Wall time of the open-loop stages (s).
    """

    def __init__(self, objective, sizes, rng):
        self.objective = objective
        self.sizes = sizes
        self.rng = rng
        self.searches = {"open_loop": 0, "global": 0}
        self.open_loop_seconds = 0.0

    def fit(self, space, seeds, first=None):
        """Global search of one structure on all recordings, then least squares.

        With open-loop and closed-loop recordings together the search is staged: the open-loop
        output error, smooth in the parameters, is fitted first (:meth:`fit_open_loop`); the
        search on all recordings then keeps, for every coordinate the open-loop tests pin, only
        ``OPEN_LOOP_BOX`` local spreads around that fit. The limit cycles' features jump where the
        cycle changes shape, and a cycle at the scale of the dead zone does so within a fraction
        of a percent of the linear block, where a search of the whole box finds no basin. Least
        squares then runs in the whole box.

        On limit cycles alone the whole box is searched, and one short search often ends in
        another basin, so the search is repeated until its best two agree (:func:`best_of_restarts`,
        at most ``WHOLE_BOX_RESTARTS``).

        ``seeds``: parameter objects of the structure (:func:`_valid`) placed in the first
        population; ``first``: the open-loop stage's fit where it has run already (the race,
        :meth:`race_classes`). Returns a :class:`.search.FitResult`.
        """
        objective = self.objective
        pop, gens, nfev = self.sizes.pop, self.sizes.gens, self.sizes.nfev
        starts = [space.coordinates(p) for p in seeds]
        box = space
        open_targets = [t for t in objective.targets if t.kind == "open"]
        restarts = WHOLE_BOX_RESTARTS
        if open_targets and len(open_targets) < len(objective.targets):
            if first is None:
                t0 = time.perf_counter()
                first = self.fit_open_loop(space, open_targets, starts)
                self.open_loop_seconds += time.perf_counter() - t0
            sd = local_sd(space, objective, first.theta, targets=open_targets)
            box = space.narrowed(first.theta, OPEN_LOOP_BOX * sd)
            starts = [first.theta] + starts
            restarts = (1, 1)
        best = best_of_restarts(
            lambda: _searched(box, space, objective, self.rng, starts, pop, gens, nfev),
            len(objective.targets), *restarts)
        self.searches["global"] += best.restarts
        for s in starts[:1]:  # the best seed, refined too
            alt = refine(space, objective, s, max_nfev=nfev)
            if alt.cost < best.cost:
                best = alt
        return best

    def fit_open_loop(self, space, open_targets, starts):
        """Short searches on the open-loop recordings alone, repeated until the best two agree
        (:func:`best_of_restarts`, at most ``OPEN_LOOP_RESTARTS``).

        One search alone often stops in another basin, and short searches from independent
        starts fail independently. The stage is checked by
        ``tests/test_discover.py::test_open_loop_stage_reaches_the_open_loop_optimum``.
        """
        pop, gens = self.sizes.open_pop, self.sizes.open_gens
        best = best_of_restarts(
            lambda: _searched(space, space, self.objective, self.rng, starts, pop, gens, 30,
                              open_targets),
            len(open_targets), *OPEN_LOOP_RESTARTS)
        self.searches["open_loop"] += best.restarts
        return best


def best_of_restarts(search, n_recordings, min_restarts, max_restarts):
    """The best of repeated independent searches (``search()`` returns a fit with ``cost``).

    At least ``min_restarts`` searches, then more until the best two costs agree within
    ``TOL_ABS`` per recording (the floor of what the ranking tells apart: two independent
    searches that reach the same cost make a better basin unlikely) or ``max_restarts`` have run.
    Returns the best fit with its ``restarts`` set to the number of searches run.
    """
    if not 1 <= min_restarts <= max_restarts:
        raise ValueError(f"restarts must satisfy 1 <= min ({min_restarts}) <= max ({max_restarts})")
    fits = []
    while len(fits) < max_restarts:
        fits.append(search())
        if len(fits) >= min_restarts:
            a, b = (sorted(f.cost for f in fits) + [math.inf])[:2]
            if b - a <= TOL_ABS * n_recordings:
                break
    best = min(fits, key=lambda f: f.cost)
    best.restarts = len(fits)
    return best


def _searched(box, space, objective, rng, starts, pop, gens, nfev, targets=None):
    """Differential evolution in ``box`` on the coarse targets (:meth:`.search.Objective.coarse`:
    a third of the simulated seconds), then least squares on the full targets (in the whole
    ``space``) from the best member and from the runners-up in other basins (a short search often
    ends before one basin has won); the best refined fit."""
    de = global_search(box, objective, rng, seeds=starts, popsize=pop, maxiter=gens,
                       targets=objective.coarse(targets))
    fits = refine_all(space, objective,
                      distinct_members(de.population, de.population_costs, box, N_STARTS),
                      max_nfev=nfev, targets=targets)
    return min(fits, key=lambda f: f.cost)
