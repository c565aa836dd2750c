"""The structure search: every structure of the space fitted to all recordings, in-sample.

* :data:`SEARCHES` -- the search sizes (:class:`SearchSizes`) by name;
* :class:`StructureSearch` -- the stages: a global search (staged, open-loop tests first, when
  there are both kinds of recording) for the largest structure of every (dead-zone position,
  delay position, band-pass loop) class, cross-seeded between delay positions; every nested
  structure refined from its parent's optimum; the repairs (a superset refitted from a nested
  structure that fits better; every structure refitted from the best optimum of all);
* the seeds a structure can take (:func:`_valid`); the starts carried from one structure to
  another are :mod:`.transfer`'s.

One structure's global search is :mod:`.global_fit`'s, its refinement :mod:`.search`'s; the
ranking of the fits is :mod:`.ranking`'s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvcid.models.hypotheses import KICK_X0, DeadZonePosition, DelayPosition
from tvcid.models.structures import Structure

from .global_fit import GlobalFit
from .indistinguishable import TOL_ABS, _contains
from .ranking import SCREEN_ABS, StructureFit
from .search import concurrent_map, progress_bar, refine
from .tasks import fit_tops
from .transfer import delay_moved, reduced_values, transferred, widened_values

__all__ = ["StructureSearch", "SearchSizes", "SEARCHES", "TEMPLATE"]

#: Template of the fields a search does not set (paper 001's linear block, only a placeholder; the
#: papers' kick x0 so that a reported model, simulated in closed loop, leaves the equilibrium).
TEMPLATE = dict(gain=305500.0, damping=202.1, stiffness=14520.0, dead_zone=1e-3,
                dead_zone_position=DeadZonePosition.ERROR, backlash=0.0, delay=2e-3,
                delay_position=DelayPosition.OUTPUT, x0=KICK_X0)
#: How :meth:`StructureSearch.search_classes` may race the classes (:meth:`StructureSearch.race_classes`).
RACE_MODES = ("off", "measure", "on")
#: Tops searched on all recordings before the race drops any: those of lowest open-loop bound.
RACE_LEADERS = 2


@dataclass(frozen=True)
class SearchSizes:
    """Sizes of every search and refinement of :class:`.estimator.StructureDiscovery`.

    Attributes
    ----------
    pop, gens : int
        Differential evolution on all recordings: population per coordinate, generations.
    open_pop, open_gens : int
        The same for each of the open-loop stage's searches (:func:`.global_fit.best_of_restarts`).
    nfev : int
        Least-squares evaluations of a refinement (global searches, nested structures, repairs).
    rank_nfev : int
        Least-squares evaluations of each fold's refit in the out-of-sample ranking.
    """

    pop: int
    gens: int
    open_pop: int
    open_gens: int
    nfev: int
    rank_nfev: int


#: ``standard`` is what the discovery benchmark measures (``tvcid.studies.benchmarks.discovery``) and what
#: ``tvcid discover`` runs by default; ``thorough`` searches about 1.8x as many parameter sets
#: (M000's four records: 123,000 against 69,000 simulations, 816 s against 507 s on 2 idle cores)
#: and is not covered by the benchmark.
SEARCHES = {
    "standard": SearchSizes(pop=5, gens=15, open_pop=5, open_gens=15, nfev=15, rank_nfev=6),
    "thorough": SearchSizes(pop=8, gens=45, open_pop=6, open_gens=25, nfev=30, rank_nfev=12),
}


class StructureSearch:
    """The searches and refinements that fit the structures of a space to one objective.

    Parameters
    ----------
    objective : .search.Objective
        Every recording's target.
    sizes : SearchSizes
    rng : numpy.random.Generator
        The global searches' draws, taken in the order the searches run (the searches of
        :meth:`search_classes` each draw from a generator of their own, seeded from it).
    spaces : dict, optional
        Structure -> :class:`.coordinates.SearchSpace` of every structure to fit.
    progress : bool
        Progress bars (tqdm).
    executor : tvcid.discovery.executors.Executor, optional
        Runs :meth:`search_classes`' searches (:mod:`.tasks`); default: one after the other in
        this process.
    race : {"off", "measure", "on"}
        Whether :meth:`search_classes` races the classes (:meth:`race_classes`) where there are
        open-loop and closed-loop recordings: ``on`` drops the classes the race rules out,
        ``measure`` runs the race's order and records what it would drop, dropping nothing.

    Attributes
    ----------
    global_fit : .global_fit.GlobalFit
        The single structures' global searches run here, and the counts of all of them
        (``searches``, ``open_loop_seconds``), those of :mod:`.tasks` added.
    worker_cpu_seconds : float
        CPU seconds of the searches run in other processes (:func:`.tasks.fit_tops`).
    race_record : dict or None
        What the race decided (:meth:`race_classes`), None where it did not run.
    dropped : dict
        Structure -> why the race dropped it (``race="on"`` only).
    """

    def __init__(self, objective, sizes, rng, spaces=None, progress=False, executor=None,
                 race="off"):
        if race not in RACE_MODES:
            raise ValueError(f"race={race!r}: choose one of {', '.join(RACE_MODES)}")
        self.objective = objective
        self.sizes = sizes
        self.rng = rng
        self.spaces = dict(spaces or {})
        self.progress = progress
        self.executor = executor
        self.global_fit = GlobalFit(objective, sizes, rng)
        self.worker_cpu_seconds = 0.0
        self.race = race
        self.race_record = None
        self.dropped = {}

    # -- the stages ----------------------------------------------------------------------------
    def search_classes(self, structures, sindy):
        """Global search of the largest structure of every class, then cross-seeding.

        A class is a (dead-zone position, delay position) pair, without and with the band-pass
        loop. Each search is seeded with SINDy's proposals (``sindy``: structure name -> list of
        ActuatorParams) for the structure and for the structures nested in it; a band-pass
        structure also with its class's fit without the loop, the loop switched on small.
        The searches are independent tasks (:func:`.tasks.fit_top`, through ``executor``), each
        drawing from a generator seeded from ``rng`` before any runs: those without the loop
        first, then those with it, which read their class's fit. Returns the fits, structure ->
        :class:`.ranking.StructureFit`.
        """
        tops = _class_tops(structures)
        kinds = {t.kind for t in self.objective.targets}
        if self.race != "off" and kinds == {"open", "closed"}:
            return self.race_classes(tops, structures, sindy)
        child = dict(zip(tops, map(int, self.rng.integers(2**63, size=len(tops)))))
        found = {}
        bar = progress_bar(len(tops), "global search", self.progress)
        for wave in ([s for s in tops if not s.bandpass], [s for s in tops if s.bandpass]):
            starts = [_valid(_top_seeds(s, sindy, found), s) for s in wave]
            for s, fr in zip(wave, fit_tops(self, wave, starts, [child[s] for s in wave])):
                found[s] = self._record(s, fr, "global search (differential evolution, then "
                                        "least squares)", sindy.get(s.name, []))
                bar.update()
        bar.close()
        fits = {s: found[s] for s in tops}  # the cross-seeding refines in the classes' order
        self.cross_seed(fits)
        return fits

    def race_classes(self, tops, structures, sindy):
        """:meth:`search_classes` as a race: every class's open-loop stage first, then the
        searches on all recordings, most promising first, and the classes that cannot reach the
        ranking dropped.

        1. Every top's open-loop stage (:meth:`.global_fit.GlobalFit.fit_open_loop`; a band-pass top seeded with its
           class's open-loop fit, the loop switched on small). Its cost is a lower bound of the
           top's in-sample cost on all recordings (the open-loop recordings' share of it cannot
           be smaller than their own optimum), and of every structure nested in it.
        2. The searches on all recordings (:meth:`.global_fit.GlobalFit.fit` from that stage) of the
           ``RACE_LEADERS`` tops of lowest bound.
        3. A top whose bound exceeds :func:`.ranking.in_sample_screen` of the best cost so far
           cannot be ranked, nor can any structure nested in it: it is dropped, unless it is
           nested in a top that stays (a class's structures without the band-pass loop stay
           with its band-pass top). The other tops are searched.

        With ``race="measure"`` nothing is dropped and :attr:`race_record` says what would have
        been. Returns the fits, structure -> :class:`.ranking.StructureFit`, of the tops
        searched; :attr:`dropped` names every structure of ``structures`` left out, with why.
        """
        from .ranking import in_sample_screen

        seeds = dict(zip(tops, map(int, self.rng.integers(2**63, size=len(tops)))))
        opened, first = {}, {}
        bar = progress_bar(2 * len(tops), "global search (raced)", self.progress)
        for wave in ([s for s in tops if not s.bandpass], [s for s in tops if s.bandpass]):
            starts = [_valid(_top_seeds(s, sindy, opened), s) for s in wave]
            for s, fr in zip(wave, fit_tops(self, wave, starts, [seeds[s] for s in wave],
                                            open_loop_only=True)):
                first[s] = fr
                opened[s] = self._record(s, fr, "open-loop stage", [])
                bar.update()
        bound = {s: float(first[s].cost) for s in tops}
        order = sorted(tops, key=lambda s: (bound[s], s.name))
        found = {}

        def search(wave):
            starts = [_valid(_top_seeds(s, sindy, {**opened, **found}), s) for s in wave]
            for s, fr in zip(wave, fit_tops(self, wave, starts, [seeds[s] + 1 for s in wave],
                                            firsts=[first[s] for s in wave])):
                found[s] = self._record(s, fr, "global search (differential evolution, then "
                                        "least squares)", sindy.get(s.name, []))
                bar.update()

        search(order[:RACE_LEADERS])
        best = min(f.cost for f in found.values())
        screen = in_sample_screen(best, len(self.objective.targets))
        # a leader stays whatever its cost: a search can miss its basin, so a cost is no bound
        staying = {s for s in tops if bound[s] <= screen or s in found}
        staying |= {s for s in tops if _within(s, staying)}
        out = [s for s in tops if s not in staying]
        dropped = [s for s in structures if _within(s, out) and not _within(s, staying)]
        self.race_record = {
            "bounds": {s.name: bound[s] for s in order},
            "leaders": [s.name for s in order[:RACE_LEADERS]],
            "best_cost": best, "screen": screen, "dropped_tops": [s.name for s in out],
            "dropped": sorted(s.name for s in dropped), "applied": self.race == "on"}
        rest = [s for s in order[RACE_LEADERS:] if s in staying or self.race == "measure"]
        search(rest)
        bar.close()
        open_names = [t.name for t in self.objective.targets if t.kind == "open"]
        # the bound's check: the open-loop recordings' share of each searched top's fit
        self.race_record["open_loop_share"] = {
            s.name: float(sum(found[s].cost_by_recording[n] for n in open_names))
            for s in order if s in found}
        if self.race == "on":
            self.dropped.update((s, _raced_out(screen)) for s in dropped)
        fits = {s: found[s] for s in tops if s in found}
        self.cross_seed(fits)
        return fits

    def fit_nested(self, structures, fits, sindy):
        """Fit every structure of ``structures`` not in ``fits`` (adding it there), then repair.

        Level by level, largest first: each structure is refined from the best fit of the
        structures it is nested in (same positions, same band-pass flag) with the component
        removed, or searched globally where there is none. Then the superset repair
        (:meth:`repair_supersets`) and the refits from the best optimum of all
        (:meth:`seed_from_best`). Returns the names of the structures the repairs refitted.
        """
        rest = [s for s in structures if s not in fits]
        bar = progress_bar(len(rest), "nested structures", self.progress)
        # level by level, largest first: a parent has more components, so the structures of one
        # level are refined concurrently from parents already fitted (the loop's result)
        for size in sorted({len(s.components) for s in rest}, reverse=True):
            level = [s for s in rest if len(s.components) == size]
            parents = {s: min((f for f in fits.values() if _is_nested(s, f.structure)),
                              key=lambda f: f.cost, default=None) for s in level}
            done = {}
            for s in (s for s in level if parents[s] is None):  # in order: the rng's draws
                done[s] = (self.global_fit.fit(self.spaces[s], []), "global search")
                bar.update()

            def from_parent(s):
                parent = parents[s]
                start = s.to_params(parent.params, **reduced_values(parent.params, s))
                fr = refine(self.spaces[s], self.objective, self.spaces[s].coordinates(start),
                            max_nfev=self.sizes.nfev)
                bar.update()
                return fr, f"least squares from {parent.structure.name} with the component removed"

            adopted = [s for s in level if parents[s] is not None]
            done.update(zip(adopted, concurrent_map(from_parent, adopted)))
            for s in level:
                fr, origin = done[s]
                fits[s] = self._record(s, fr, origin, sindy.get(s.name, []))
        bar.close()
        repaired = self.repair_supersets(fits)
        repaired += self.seed_from_best(fits)
        return repaired

    def refit_from(self, structures, previous, race=None):
        """The experiment loop's search: every structure refined by least squares from its
        optimum of an earlier run (``previous``: structure name -> ActuatorParams) on the
        objective's recordings, the new ones included; a structure without one is searched
        globally, and so is one whose refit fits any recording worse than the earlier optimum
        did by more than ``TOL_ABS`` (the added recordings pull it out of the earlier basin:
        M000's cycle A alone can be fitted on a gain-delay ridge at twice the gain and half the
        delay of the optimum of cycles A and B, and the refit from there stops at a cost of 1.03
        against a fresh search's 0.035). Then the cross-seeding, the superset repair and the
        refits from the best optimum, as after a fresh search. Returns ``(fits, repaired)``.

        ``race``: the earlier run's :attr:`race_record`. A structure the earlier race dropped
        (no optimum to start from) stays dropped while its class's open-loop bound, still a
        lower bound of its cost (the earlier recordings are all here), exceeds the ranking's
        screen of the refits' best cost (:meth:`_dropped_again`); otherwise it is searched."""
        warm = [s for s in structures if s.name in previous]
        bar = progress_bar(len(warm), "refits from the earlier run", self.progress)

        def from_previous(s):
            start = self.spaces[s].coordinates(s.to_params(previous[s.name]))
            fr = refine(self.spaces[s], self.objective, start, max_nfev=self.sizes.nfev)
            bar.update()
            return fr, bool(np.any(fr.cost_by_target - fr.start_cost_by_target > TOL_ABS))

        fits, moved = {}, {}
        for s, (fr, worse) in zip(warm, concurrent_map(from_previous, warm)):
            fits[s] = self._record(s, fr, "least squares from the earlier run's optimum", [])
            if worse:
                moved[s] = fr
        bar.close()
        self._dropped_again(structures, previous, fits, race)
        for s in structures:  # in order: the rng's draws
            if s in self.dropped:
                continue
            if s in moved:  # the refit's optimum seeds the search, which keeps the better
                found = self.global_fit.fit(self.spaces[s], [self.spaces[s].params(moved[s].theta)])
                if found.cost < moved[s].cost:
                    fits[s] = self._record(s, found, "global search (the added recordings fit "
                                           "worse near the earlier run's optimum)", [])
            elif s not in fits:
                fits[s] = self._record(s, self.global_fit.fit(self.spaces[s], []), "global search", [])
        self.cross_seed(fits)
        repaired = self.repair_supersets(fits)
        repaired += self.seed_from_best(fits)
        return fits, repaired

    def _dropped_again(self, structures, previous, fits, race):
        """:meth:`refit_from`'s race: the structures of ``structures`` without an optimum in
        ``previous`` that the earlier race (``race``, applied) dropped, still ruled out by the
        screen of the best of ``fits``, into :attr:`dropped`; :attr:`race_record` carried."""
        from .ranking import in_sample_screen

        if not race or not race.get("applied") or not fits:
            return
        best = min(f.cost for f in fits.values())
        screen = in_sample_screen(best, len(self.objective.targets))
        bounds = race["bounds"]
        tops = [Structure.parse(n) for n in race["dropped_tops"]]
        back = [t for t in tops if bounds[t.name] <= screen]
        out = [t for t in tops if not _within(t, back)]
        for s in structures:
            if s.name in previous:
                continue
            if _within(s, out):
                self.dropped[s] = _raced_out(screen)
        self.race_record = {**race, "best_cost": best, "screen": screen,
                            "dropped_tops": [t.name for t in out],
                            "dropped": sorted(s.name for s in self.dropped)}

    # -- refits from other structures' optima --------------------------------------------------
    def cross_seed(self, fits, n_sources=2):
        """Refine each searched structure from the better optima of its delay-position siblings.

        Structures that differ only in where the delay sits describe nearly the same loop (a delay
        inside the second-order block's own feedback reads, at low frequency, as a changed K2 and
        K3 plus a delay after it), so one's optimum is a good start for another; a search that
        missed its basin is caught here rather than ranked as if the structure were wrong.
        """
        for s in list(fits):
            siblings = sorted((f for o, f in fits.items()
                               if o != s and o.dead_zone_position == s.dead_zone_position
                               and o.bandpass == s.bandpass and f.cost < fits[s].cost),
                              key=lambda f: f.cost)[:n_sources]
            for other in siblings:
                moved = delay_moved(other.params, s.delay_position)
                start = s.to_params(moved, **widened_values(moved, s))
                self.keep_better(fits, s, start,
                                 f"least squares from the optimum of {other.structure.name}")

    def seed_from_best(self, fits):
        """Refine every structure from the best fit of all, carried over (:func:`transferred`).

        The global searches run per (dead-zone position, delay position, band-pass loop) class and
        the cross-seeding within a class; a class whose search misses its basin is reached here
        from the others' best optimum. Returns the structures the superset repair that follows refits.
        """
        best = min(fits.values(), key=lambda f: f.cost)
        chosen = [s for s in sorted(fits, key=lambda s: s.name)
                  if s != best.structure and fits[s].cost > best.cost]
        refined = concurrent_map(  # independent refinements from one start each
            lambda s: refine(self.spaces[s], self.objective,
                             self.spaces[s].coordinates(transferred(best.params, s)),
                             max_nfev=self.sizes.nfev), chosen)
        for s, fr in zip(chosen, refined):
            self.keep_better(fits, s, None,
                             f"least squares from the optimum of {best.structure.name}", fr)
        return self.repair_supersets(fits)

    def repair_supersets(self, fits):
        """Refit a structure that fits worse than one of its nested structures.

        A superset can always reproduce its nested structure (the added component at zero), so
        a higher cost is a search failure (the friction offset's discontinuity makes the
        landscape rugged); the superset is refined from the nested optimum with the component
        switched on small. Returns the names of the structures refitted.
        """
        def repair(s):
            fixed = False
            for comp in s.components:
                sub = fits.get(s.without(comp))
                if sub is None or fits[s].cost <= sub.cost * (1 + 1e-3):
                    continue
                start = s.to_params(sub.params, **widened_values(sub.params, s))
                fixed |= self.keep_better(fits, s, start,
                                          f"least squares from {sub.structure.name} with {comp} added")
            return fixed

        repaired = []
        order = sorted(fits, key=lambda s: len(s.components))
        # level by level, smallest first: a structure's nested ones have fewer components, so
        # one level's repairs read only fits already final (the loop's result, concurrently)
        for size in sorted({len(s.components) for s in order}):
            level = [s for s in order if len(s.components) == size]
            repaired += [s.name for s, fixed in zip(level, concurrent_map(repair, level)) if fixed]
        return repaired

    def keep_better(self, fits, s, start, origin, fr=None):
        """Refine ``s`` from ``start`` (or take the refined ``fr``); replace its fit (keeping
        SINDy's seeds) if the cost drops. Returns whether it did."""
        if fr is None:
            fr = refine(self.spaces[s], self.objective, self.spaces[s].coordinates(start),
                        max_nfev=self.sizes.nfev)
        if fr.cost >= fits[s].cost:
            return False
        seeds = fits[s].sindy_seeds
        fits[s] = self._record(s, fr, origin, [])
        fits[s].sindy_seeds = seeds
        return True

    def _record(self, s, fr, origin, seeds):
        names = [t.name for t in self.objective.targets]
        return StructureFit(structure=s, params=self.spaces[s].params(fr.theta), theta=fr.theta,
                            cost=fr.cost, cost_by_recording=dict(zip(names, map(float, fr.cost_by_target))),
                            origin=origin, sindy_seeds=[p.to_dict() for p in seeds])


def _within(s, tops):
    """``s`` is one of ``tops`` or nested in one of them."""
    return any(s == t or _contains(t, s) for t in tops)


def _raced_out(screen):
    """Why the race dropped a structure (one reason for all, so that the report lists them
    together; each class's bound is in :attr:`StructureSearch.race_record`)."""
    return (f"raced out: the open-loop recordings alone cost more in its class than the "
            f"ranking's screen {screen:.3g} allows (twice the best in-sample cost plus "
            f"{SCREEN_ABS} per recording; each class's bound is in discovery.json's `race`)")


def _class_tops(structures):
    """The largest structure of every (dead-zone position, delay position, band-pass loop)
    class, in the classes' order."""
    classes = sorted({(s.dead_zone_position, s.delay_position) for s in structures},
                     key=lambda c: (c[0].value, c[1].value))
    tops = []
    for cls in classes:
        members = [s for s in structures if (s.dead_zone_position, s.delay_position) == cls]
        for bandpass in (False, True):
            group = [s for s in members if s.bandpass == bandpass]
            if group:
                tops.append(max(group, key=lambda s: len(s.components)))
    return tops


def _fixed_for(structure, fixed):
    """Fixed values that apply to ``structure`` (a component's value only where it is present)."""
    out = dict(fixed)
    for key, comp in (("friction_offset", "friction"), ("backlash", "backlash"),
                      ("bandpass_gain", "bandpass"), ("bandpass_saturation", "bandpass")):
        if key in out and not getattr(structure, comp):
            out.pop(key)
    return out


def _is_nested(s, parent):
    """``s`` is ``parent`` with components removed (same positions, same band-pass flag)."""
    return s.bandpass == parent.bandpass and _contains(parent, s)


def _top_seeds(s, sindy, fits):
    """The starts of ``s``'s global search: SINDy's proposals for ``s`` and for the structures of
    its class nested in it; for a band-pass ``s``, also its class's fit without the loop in
    ``fits``, the loop switched on small."""
    seeds = list(sindy.get(s.name, []))
    for other, plist in sindy.items():  # nested proposals seed their parents too
        o = Structure.parse(other)
        if (o.dead_zone_position, o.delay_position) == (s.dead_zone_position, s.delay_position):
            seeds += [p for p in plist if p not in seeds]
    parent = fits.get(s.without("bandpass")) if s.bandpass else None
    if parent is not None:
        p = parent.params
        seeds += [p.replace(bandpass_gain=g, bandpass_saturation=k * p.gain / p.stiffness)
                  for g, k in ((40.0, 5e-4), (80.0, 3e-4))]
    return seeds


def _valid(seeds, s):
    """The seeds as starts of ``s`` (its absent parts widened, :func:`widened_values`); a seed
    ``s`` cannot take (a value its parameters refuse) is dropped, never raised."""
    out = []
    for p in seeds:
        try:
            out.append(s.to_params(p, **widened_values(p, s)))
        except ValueError:
            continue
    return out
