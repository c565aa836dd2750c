"""``StructureDiscovery``: every structure fitted to all recordings by simulation, ranked out of sample.

Pipeline (issue 11):

1. **Structure space** -- :func:`models.structures.structure_space` (36 structures after pruning,
   fewer when the user fixes a structural choice).
2. **Screening and seeds** -- weak-form SINDy (:mod:`discovery.sindy`) proposes parameters for the
   structures its forms describe; they enter the first population of the global search of the
   matching structure. Where the data do not support a form, SINDy says so and the search runs
   unseeded; nothing downstream depends on SINDy being right.
3. **Fit** -- for every (dead-zone position, delay position) class, the largest structure without and
   with the band-pass loop gets a global search (differential evolution over the batch kernel;
   staged, open-loop tests first, when there are both kinds of recording; each stage repeated
   until two independent searches agree, :func:`best_of_restarts`) and least-squares
   refinement from its best distinct candidates, then from the better optima of the
   structures that differ from it only in the delay's position; every nested structure (no
   friction, no backlash) is refined from its parent's optimum with the component removed.
   A structure that fits worse than one of its nested structures (a search failure: it can
   reproduce them) is refined again from that optimum; last, every structure is refined from the
   best optimum of all, carried over (:func:`transferred`).
4. **Rank** -- by two-fold out-of-sample error: each structure within :func:`in_sample_screen` of
   the best in-sample cost is refitted (locally, from its optimum) on one half of every recording
   and scored on the other half, both ways round
   (:meth:`StructureDiscovery._rank` says why not leave-one-recording-out).
5. **Report what the data cannot decide** -- structures whose score is within
   :func:`indistinguishable_margin` of the best (twice the standard error of the score
   difference: each recording's from the disagreement of the two folds, with a floor that a
   wandering cycle raises, :func:`margin_floors`; the recordings' added in quadrature) are
   indistinguishable from it; a structure that only
   adds components to an indistinguishable one without beating it by that margin is merged into
   it (the output says which), and so is every superset of a member whatever its own fit scored
   (at its added components' zero it is that member). The local spread of each coordinate
   (:func:`.search.local_sd`) marks ridges.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq, least_squares

from models.hypotheses import KICK_X0, ActuatorParams, DeadZonePosition, DelayPosition
from models.linear import second_order_response
from models.recording import Recording, load_recording
from models.structures import Structure, shared_choices, structure_space

from ..threads import one_blas_thread
from .coordinates import SearchSpace, UnknownParameterError
from .search import (
    Objective,
    concurrent_map,
    distinct_members,
    global_search,
    local_sd,
    refine,
    refine_all,
)
from .targets import make_target

__all__ = ["StructureDiscovery", "StructureFit", "SearchSizes", "SEARCHES", "validate_recordings",
           "DiscoveryInputError",
           "delay_moved", "transferred", "indistinguishable_margin", "indistinguishable_set",
           "margin_floors",
           "in_sample_screen", "best_of_restarts"]

#: Template of the fields a search does not set (paper 001's linear block, only a placeholder; the
#: papers' kick x0 so that a reported model, simulated in closed loop, leaves the equilibrium).
TEMPLATE = dict(gain=305500.0, damping=202.1, stiffness=14520.0, dead_zone=1e-3,
                dead_zone_position=DeadZonePosition.ERROR, backlash=0.0, delay=2e-3,
                delay_position=DelayPosition.OUTPUT, x0=KICK_X0)
#: Distinct members of a global search's final population refined locally (the best among them).
N_STARTS = 3
#: Independent short searches of one stage (:func:`best_of_restarts`): at least the first number,
#: then more until the best two agree, up to the second; the open-loop stage, and a search of the
#: whole box (recordings of one kind). With open-loop tests the limit cycles are searched once,
#: in the box the open-loop fit narrowed. The band-pass loop's wandering cycles rarely let two
#: searches agree (benchmark draw 1000: every class ran its maximum of 6, its discovery 488 s
#: with three draws sharing 2 cores against 182 s with one search and two sharing), so the
#: whole-box maximum is 4.
OPEN_LOOP_RESTARTS = (3, 8)
WHOLE_BOX_RESTARTS = (2, 4)
#: Half-width of the box kept around the open-loop stage's fit, in local spreads of each coordinate.
OPEN_LOOP_BOX = 6.0
#: Floor of the margin within which a score is indistinguishable from the best, per recording
#: (:func:`indistinguishable_margin`).
TOL_ABS = 0.1
#: The ranking's open-loop simulations take steps this many times finer than the search's
#: (:meth:`StructureDiscovery._rank`).
RANK_OPEN_LOOP_REFINEMENT = 2
#: Most structures given the out-of-sample ranking, and the screen's allowance per recording
#: (:func:`in_sample_screen`).
MAX_RANKED = 24
SCREEN_ABS = 0.5
#: Cost per recording at or above which a fit reproduces nothing: residuals of 100 units rms (a
#: cycle's frequency 10 % or its harmonics 30 % of the fundamental off, on average), far beyond
#: any structure near the data (the benchmark's search failures cost under 40). With the
#: band-pass loop a fixed linear block that cannot move the actuator still rings at 9-10 Hz
#: (cost 8e4, the test's case); a run that diverges or stops oscillating costs 1e8 (``PENALTY**2``).
NO_FIT_COST = 1e4
#: Band over which :func:`delay_moved` matches the moved block's frequency response, in units of
#: the block's natural frequency ``sqrt(K3)``: the limit cycles (2-10 Hz) and the open-loop tests'
#: edges ring below it (M000: 19 Hz).
MATCHED_BAND = (0.05, 1.5)
#: Factor within which each coefficient of the moved block stays of the given one's.
MATCHED_RANGE = 10.0
#: A recording whose output exceeds this (rad) is probably in degrees.
MAX_ANGLE = 0.5


@dataclass(frozen=True)
class SearchSizes:
    """Sizes of every search and refinement of :class:`StructureDiscovery`.

    Attributes
    ----------
    pop, gens : int
        Differential evolution on all recordings: population per coordinate, generations.
    open_pop, open_gens : int
        The same for each of the open-loop stage's searches (:func:`best_of_restarts`).
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


#: ``standard`` is what the discovery benchmark measures (``studies.benchmarks.discovery``) and what
#: ``tvcid discover`` runs by default; ``thorough`` searches about 1.8x as many parameter sets
#: (M000's four records: 123,000 against 69,000 simulations, 816 s against 507 s on 2 idle cores)
#: and is not covered by the benchmark.
SEARCHES = {
    "standard": SearchSizes(pop=5, gens=15, open_pop=5, open_gens=15, nfev=15, rank_nfev=6),
    "thorough": SearchSizes(pop=8, gens=45, open_pop=6, open_gens=25, nfev=30, rank_nfev=12),
}


class DiscoveryInputError(ValueError):
    """Input that discovery cannot work with; the message names the file or parameter."""


@dataclass
class StructureFit:
    """One structure fitted to the recordings.

    Attributes
    ----------
    structure : models.structures.Structure
    params : ActuatorParams
        Every field, the structure's enums set, absent components zeroed.
    cost : float
        In-sample cost (sum over recordings; about 1 per recording for the generating model).
    cost_by_recording : dict
    score : float
        The ranking criterion's value (lower is better).
    criterion : str
    coordinate_sd : dict
        Local spread of each search coordinate (:func:`.search.local_sd`).
    origin : str
        How the fit was reached.
    sindy_seeds : list of dict
        SINDy's proposals for this structure (natural parameters).
    indistinguishable_from_best : bool
    merged_into : str or None
        Name of the nested structure this one was merged into.
    held_out : dict
        Held-out cost per recording.
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
            "indistinguishable_from_best": self.indistinguishable_from_best,
            "merged_into": self.merged_into,
            "coordinate_sd": self.coordinate_sd,
            "origin": self.origin,
            "sindy_seeds": self.sindy_seeds,
        }


def validate_recordings(recordings):
    """Paths or Recordings -> list of Recording, with the checks discovery needs.

    Raises
    ------
    DiscoveryInputError
        No recording; units other than rad/s; an output above 0.5 rad (degrees?); a constant
        output.
    """
    if isinstance(recordings, (str, Recording)) or hasattr(recordings, "__fspath__"):
        recordings = [recordings]
    recs = [r if isinstance(r, Recording) else load_recording(r) for r in recordings]
    if not recs:
        raise DiscoveryInputError("no recording given")
    units = {}
    for r in recs:
        name = r.path or "recording"
        u = r.meta.get("units", {})
        for col, expected in (("t", "s"), ("u", "rad"), ("delta", "rad")):
            got = u.get(col, expected)
            if got != expected:
                raise DiscoveryInputError(f"{name}: column '{col}' is in {got!r}; tvcid expects {expected}")
            units.setdefault(col, set()).add(got)
        peak = float(np.max(np.abs(r.delta - np.median(r.delta))))
        if peak > MAX_ANGLE:
            raise DiscoveryInputError(
                f"{name}: column 'delta' reaches {peak:.3g} rad from its median; values in degrees? "
                f"(tvcid expects rad, actuator angles below {MAX_ANGLE} rad)")
        if not np.ptp(r.delta) > 0:
            raise DiscoveryInputError(f"{name}: column 'delta' is constant (no motion to fit)")
    return recs


class StructureDiscovery:
    """Discover the actuator's structure and every parameter from recordings.

    Parameters
    ----------
    fixed : dict, optional
        Known parts, field -> value (e.g. the linear block, a known delay, a structural choice);
        used in every structure.
    seed : int
        Seed of every random draw (global searches).
    search : {"standard", "thorough"}
        Sizes of the searches (:data:`SEARCHES`).
    dt : float
        RK4 step of the simulations (s).
    use_sindy : bool
        Seed the searches with weak-form SINDy's proposals.
    progress : bool
        Progress bars (tqdm).
    max_ranked : int
        Structures (best in-sample first) that always get the out-of-sample ranking; any further
        structure whose in-sample cost is within :func:`in_sample_screen` of the best's is ranked
        too (up to ``MAX_RANKED``), so that the reported set is not cut at a fixed size.

    Attributes
    ----------
    ranking_ : list of StructureFit
        Best first.
    best_ : StructureFit
    indistinguishable_ : list of StructureFit
        The best and every structure the data cannot tell from it (merged ones included).
    decided_ : dict
        Structural choice -> the value every structure of ``indistinguishable_`` shares, ``None``
        where they differ (the recordings leave it open; :func:`models.structures.shared_choices`).
    pruned_ : dict
        Structure name -> why it was not fitted.
    offsets_ : dict
        Sensor offset per recording at the best fit (rad).
    noise_ : dict
        Sensor-noise sd per recording (rad): open loop, the rms output error at the best fit;
        closed loop, from second differences.
    sindy_ : dict
        SINDy's proposals by structure, or the reason it gave none.
    timings_ : dict
        Wall time per stage (s).
    searches_ : dict
        Independent searches run per stage (``open_loop``, ``global``; :func:`best_of_restarts`).
    targets_ : list
    sizes_ : SearchSizes
        The search sizes used.
    """

    def __init__(self, fixed=None, seed=0, search="standard", dt=5e-4, use_sindy=True,
                 progress=False, max_ranked=8):
        self.fixed = fixed
        self.seed = seed
        self.search = search
        self.dt = dt
        self.use_sindy = use_sindy
        self.progress = progress
        self.max_ranked = max_ranked

    # -- stages --------------------------------------------------------------------------------
    def _sindy_seeds(self, recs):
        """SINDy's proposals as parameter objects, by structure name."""
        from discovery.sindy import WeakSINDyActuator

        noise = float(np.median([self._noise_of(r) for r in recs]))
        try:
            est = WeakSINDyActuator(noise=noise, seed=self.seed, n_bootstrap=0).fit(recs)
        except (ValueError, RuntimeError, ArithmeticError, np.linalg.LinAlgError) as exc:
            return {}, f"SINDy proposed nothing: {exc}"
        seeds = {}
        for cand in est.candidates_:
            try:
                p = cand.to_params()
            except ValueError:
                continue
            seeds.setdefault(Structure.of_params(p).name, []).append(p)
        return seeds, None

    @staticmethod
    def _noise_of(rec):
        from discovery.calibration.likelihood import estimate_noise

        return estimate_noise(rec.delta)

    def _fit_global(self, space, objective, rng, seeds):
        """Global search of one structure on all recordings, then least squares.

        With open-loop and closed-loop recordings together the search is staged: the open-loop
        output error, smooth in the parameters, is fitted first (:meth:`_fit_open_loop`); the
        search on all recordings then keeps, for every coordinate the open-loop tests pin, only
        ``OPEN_LOOP_BOX`` local spreads around that fit. The limit cycles' features jump where the
        cycle changes shape, and a cycle at the scale of the dead zone does so within a fraction
        of a percent of the linear block (benchmark draw 1002: costs 100-50,000 within 1 % of the
        true static gain), so an unstaged search of the whole box found no basin (costs >= 9,180
        against 2.09 at the truth). Least squares then runs in the whole box.

        On limit cycles alone the whole box is searched, and one short search often ends in
        another basin (benchmark draw 1023, the true structure: eight searches from independent
        starts ended at 0.17-113 against the truth's 0.35, three of them below it), so the search
        is repeated until its best two agree (:func:`best_of_restarts`, at most
        ``WHOLE_BOX_RESTARTS``).
        """
        pop, gens, nfev = self.sizes_.pop, self.sizes_.gens, self.sizes_.nfev
        starts = [space.coordinates(p) for p in seeds]
        box = space
        open_targets = [t for t in objective.targets if t.kind == "open"]
        restarts = WHOLE_BOX_RESTARTS
        if open_targets and len(open_targets) < len(objective.targets):
            t0 = time.perf_counter()
            first = self._fit_open_loop(space, objective, rng, open_targets, starts)
            self._open_loop_seconds += time.perf_counter() - t0
            sd = local_sd(space, objective, first.theta, targets=open_targets)
            box = space.narrowed(first.theta, OPEN_LOOP_BOX * sd)
            starts = [first.theta] + starts
            restarts = (1, 1)
        best = best_of_restarts(
            lambda: _searched(box, space, objective, rng, starts, pop, gens, nfev),
            len(objective.targets), *restarts)
        self._count_searches("global", best.restarts)
        for s in starts[:1]:  # the best seed, refined too
            alt = refine(space, objective, s, max_nfev=nfev)
            if alt.cost < best.cost:
                best = alt
        return best

    def _count_searches(self, stage, n):
        counts = self.__dict__.setdefault("_searches", {"open_loop": 0, "global": 0})
        counts[stage] += n

    def _fit_open_loop(self, space, objective, rng, open_targets, starts):
        """Short searches on the open-loop recordings alone, repeated until the best two agree
        (:func:`best_of_restarts`, at most ``OPEN_LOOP_RESTARTS``).

        One search alone often stops in another basin: on 12 benchmark draws with open-loop tests
        (the true structure), one search of 5 x 15 generations reached the open-loop optimum in 8,
        one of 8 x 30 in 9. Short searches from independent starts fail independently; with three
        of them the staged search (box of 4 spreads) reached the truth's cost in 14 of 15 draws;
        draw 1002 needed a box of 8 spreads (hence ``OPEN_LOOP_BOX`` = 6). Draw 1019 (a dead zone
        with a backlash, two squares at 200 Hz) needs more: of eight searches, six ended at
        27-42 and two at 0.76 and 1.16 against the truth's 0.72, so a fixed three found it one
        time in three. These counts come from session scripts, not from a command in the
        repository; what a command reproduces is
        ``tests/test_discover.py::test_open_loop_stage_reaches_the_open_loop_optimum`` and the
        benchmark.
        """
        pop, gens = self.sizes_.open_pop, self.sizes_.open_gens
        best = best_of_restarts(
            lambda: _searched(space, space, objective, rng, starts, pop, gens, 30, open_targets),
            len(open_targets), *OPEN_LOOP_RESTARTS)
        self._count_searches("open_loop", best.restarts)
        return best

    def fit(self, recordings):
        """Screen, search, refine and rank every structure on ``recordings``; returns ``self``."""
        with one_blas_thread():  # the kernels own the cores (:mod:`discovery.threads`)
            return self._fit(recordings)

    def _fit(self, recordings):
        t_start = time.perf_counter()
        timings = {}
        if self.search not in SEARCHES:
            raise ValueError(f"unknown search size {self.search!r}; choose one of "
                             f"{', '.join(SEARCHES)}")
        self.sizes_ = SEARCHES[self.search]
        recs = validate_recordings(recordings)
        fixed = dict(self.fixed or {})
        known = set(ActuatorParams.parameter_names())
        unknown = sorted(set(fixed) - known)
        if unknown:
            raise UnknownParameterError(
                f"unknown parameter(s) {', '.join(unknown)} in --fix; known: {', '.join(sorted(known))}")
        structural = {k: fixed.pop(k) for k in ("dead_zone_position", "delay_position") if k in fixed}
        for key, enum in (("dead_zone_position", DeadZonePosition), ("delay_position", DelayPosition)):
            if key in structural and structural[key] not in {e.value for e in enum} | set(enum):
                raise ValueError(f"--fix {key}={structural[key]!r}: choose one of "
                                 f"{', '.join(e.value for e in enum)}")
        kept, pruned = structure_space({**fixed, **structural})
        base = ActuatorParams(**{**TEMPLATE, **{k: v for k, v in fixed.items()
                                                if k not in ("friction_offset", "backlash",
                                                             "bandpass_gain")}})
        targets = [make_target(r, self.dt) for r in recs]
        self.targets_ = targets
        objective = Objective(targets)
        rng = np.random.default_rng(self.seed)
        t0 = time.perf_counter()
        sindy, sindy_error = ({}, "not run") if not self.use_sindy else self._sindy_seeds(recs)
        self.sindy_ = {"proposals": {k: [p.to_dict() for p in v] for k, v in sindy.items()},
                       "error": sindy_error}
        timings["sindy"] = time.perf_counter() - t0

        self._open_loop_seconds = 0.0
        self._searches = {"open_loop": 0, "global": 0}
        spaces = {s: SearchSpace(s, base, _fixed_for(s, fixed), self.dt) for s in kept}
        fits = {}
        t0 = time.perf_counter()
        classes = sorted({(s.dead_zone_position, s.delay_position) for s in kept},
                         key=lambda c: (c[0].value, c[1].value))
        tops = []
        for cls in classes:
            members = [s for s in kept if (s.dead_zone_position, s.delay_position) == cls]
            for bandpass in (False, True):
                group = [s for s in members if s.bandpass == bandpass]
                if group:
                    tops.append(max(group, key=lambda s: len(s.components)))
        bar = _progress_bar(tops, "global search", self.progress)
        for s in bar:
            seeds = list(sindy.get(s.name, []))
            for other, plist in sindy.items():  # nested proposals seed their parents too
                o = Structure.parse(other)
                if (o.dead_zone_position, o.delay_position) == (s.dead_zone_position, s.delay_position):
                    seeds += [p for p in plist if p not in seeds]
            if s.bandpass:
                parent = fits.get(s.without("bandpass"))
                if parent is not None:
                    seeds += [parent.params.replace(bandpass_gain=g, bandpass_saturation=k * parent.params.gain
                                                    / parent.params.stiffness)
                              for g, k in ((40.0, 5e-4), (80.0, 3e-4))]
            fr = self._fit_global(spaces[s], objective, rng, _valid(seeds, s))
            fits[s] = self._fit_record(s, spaces[s], fr, "global search (differential evolution, "
                                       "then least squares)", sindy.get(s.name, []))
        self._cross_seed(fits, spaces, objective)
        timings["global"] = time.perf_counter() - t0
        timings["global_open_loop_stage"] = self._open_loop_seconds

        t0 = time.perf_counter()
        rest = [s for s in kept if s not in fits]
        bar = _progress_bar(len(rest), "nested structures", self.progress)
        # level by level, largest first: a parent has more components, so the structures of one
        # level are refined concurrently from parents already fitted (the loop's result)
        for size in sorted({len(s.components) for s in rest}, reverse=True):
            level = [s for s in rest if len(s.components) == size]
            parents = {s: min((f for f in fits.values() if _is_nested(s, f.structure)),
                              key=lambda f: f.cost, default=None) for s in level}
            done = {}
            for s in (s for s in level if parents[s] is None):  # in order: the rng's draws
                done[s] = (self._fit_global(spaces[s], objective, rng, []), "global search")
                bar.update()

            def from_parent(s):
                parent = parents[s]
                start = s.to_params(parent.params, **_reduced_values(parent.params, s))
                fr = refine(spaces[s], objective, spaces[s].coordinates(start),
                            max_nfev=self.sizes_.nfev)
                bar.update()
                return fr, f"least squares from {parent.structure.name} with the component removed"

            adopted = [s for s in level if parents[s] is not None]
            done.update(zip(adopted, concurrent_map(from_parent, adopted)))
            for s in level:
                fr, origin = done[s]
                fits[s] = self._fit_record(s, spaces[s], fr, origin, sindy.get(s.name, []))
        bar.close()
        self.repaired_ = self._repair_supersets(fits, spaces, objective)
        self.repaired_ += self._seed_from_best(fits, spaces, objective)
        timings["nested"] = time.perf_counter() - t0

        best_fit = min(fits.values(), key=lambda f: f.cost)
        if best_fit.cost >= NO_FIT_COST * len(targets):
            raise DiscoveryInputError(
                f"no structure reproduces the recordings: every candidate diverged, stopped "
                f"oscillating or missed them by over 100 units rms (best {best_fit.structure.name}, "
                f"cost {best_fit.cost:.3g}); check the "
                "fixed parameters and the sidecars' controller settings")
        t0 = time.perf_counter()
        ranked, rank_evaluations = self._rank(fits, spaces)
        timings["ranking"] = time.perf_counter() - t0
        best = ranked[0]
        for f in [g for g in ranked if g.indistinguishable_from_best]:
            sd = local_sd(spaces[f.structure], objective, f.theta)
            f.coordinate_sd = dict(zip(spaces[f.structure].names, map(float, sd)))
        self.ranking_ = ranked
        self.best_ = best
        self.indistinguishable_ = [f for f in ranked if f.indistinguishable_from_best]
        self.decided_ = shared_choices([f.structure for f in self.indistinguishable_])
        self.pruned_ = {s.name: why for s, why in pruned.items()}
        self.offsets_ = objective.offsets(best.params)
        self.noise_ = {t.name: (t.noise(best.params) if t.kind == "open" else self._noise_of(t.recording))
                       for t in targets}
        self.fixed_ = dict(self.fixed or {})
        self.n_simulations_ = objective.n_evaluations + rank_evaluations
        timings["total"] = time.perf_counter() - t_start
        self.timings_ = timings
        self.searches_ = dict(self._searches)
        return self

    def _fit_record(self, s, space, fr, origin, seeds):
        names = [t.name for t in self.targets_]
        return StructureFit(structure=s, params=space.params(fr.theta), theta=fr.theta,
                            cost=fr.cost, cost_by_recording=dict(zip(names, map(float, fr.cost_by_target))),
                            origin=origin, sindy_seeds=[p.to_dict() for p in seeds])

    def _rank(self, fits, spaces):
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
        and the ranking must not read it as evidence. Benchmark draw 1017 (delay before the first
        integrator, two squares at 1 kHz): at 5e-4 s the true structure refitted at 0.724 against
        0.637 for the delay before the integrator, its squares' residual 1.4e-5 rad rms at the
        truth against a noise of 1.2e-5; at 2.5e-4 s the three delay positions fit at
        0.638-0.647, as indistinguishable as they are.

        Returns the ranked fits (:func:`indistinguishable_set`) and the simulations the refits ran.
        """
        order = sorted(fits.values(), key=lambda f: f.cost)
        targets = [make_target(t.recording, self.dt / RANK_OPEN_LOOP_REFINEMENT)
                   if t.kind == "open" else t for t in self.targets_]
        objective = Objective(targets)
        folds = [t.halves() for t in targets]
        fit_on = [[h[k] for h in folds] for k in (0, 1)]
        limit = in_sample_screen(order[0].cost, len(targets))
        candidates = [f for i, f in enumerate(order)
                      if i < self.max_ranked or (f.cost <= limit and i < MAX_RANKED)]
        for f in order[len(candidates):]:
            f.score, f.criterion = math.inf, "not ranked (in-sample cost far from the best)"
        bar = _progress_bar(2 * len(candidates), "two-fold out-of-sample ranking", self.progress)

        def held_out(task):  # one structure's refit on one fold, scored on the other
            f, k = task
            fr = refine(spaces[f.structure], objective, f.theta,
                        max_nfev=self.sizes_.rank_nfev, targets=fit_on[k])
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
        return ranked, objective.n_evaluations

    def _cross_seed(self, fits, spaces, objective, n_sources=2):
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
                start = s.to_params(moved, **_widen(moved, s))
                self._keep_better(fits, spaces, objective, s, start,
                                  f"least squares from the optimum of {other.structure.name}")

    def _seed_from_best(self, fits, spaces, objective):
        """Refine every structure from the best fit of all, carried over (:func:`transferred`).

        The global searches run per (dead-zone position, delay position, band-pass loop) class and
        the cross-seeding within a class; a class whose search missed its basin (benchmark draw
        1019: the generating structure fitted at 2.2 while its band-pass superset reached 1.44
        and the true parameters give 1.56) is reached here from the others' best optimum.
        Returns the structures the superset repair that follows refitted.
        """
        best = min(fits.values(), key=lambda f: f.cost)
        chosen = [s for s in sorted(fits, key=lambda s: s.name)
                  if s != best.structure and fits[s].cost > best.cost]
        refined = concurrent_map(  # independent refinements from one start each
            lambda s: refine(spaces[s], objective, spaces[s].coordinates(transferred(best.params, s)),
                             max_nfev=self.sizes_.nfev), chosen)
        for s, fr in zip(chosen, refined):
            self._keep_better(fits, spaces, objective, s, None,
                              f"least squares from the optimum of {best.structure.name}", fr)
        return self._repair_supersets(fits, spaces, objective)

    def _repair_supersets(self, fits, spaces, objective):
        """Refit a structure that fits worse than one of its nested structures.

        A superset can always reproduce its nested structure (the added component at zero), so
        a higher cost is a search failure (the friction offset's discontinuity makes the
        landscape rugged); the superset is refined from the nested optimum with the component
        switched on small.
        """
        def repair(s):
            fixed = False
            for comp in s.components:
                sub = fits.get(s.without(comp))
                if sub is None or fits[s].cost <= sub.cost * (1 + 1e-3):
                    continue
                start = s.to_params(sub.params, **_widen(sub.params, s))
                fixed |= self._keep_better(fits, spaces, objective, s, start,
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

    def _keep_better(self, fits, spaces, objective, s, start, origin, fr=None):
        """Refine ``s`` from ``start`` (or take the refined ``fr``); replace its fit (keeping
        SINDy's seeds) if the cost drops."""
        if fr is None:
            fr = refine(spaces[s], objective, spaces[s].coordinates(start),
                        max_nfev=self.sizes_.nfev)
        if fr.cost >= fits[s].cost:
            return False
        seeds = fits[s].sindy_seeds
        fits[s] = self._fit_record(s, spaces[s], fr, origin, [])
        fits[s].sindy_seeds = seeds
        return True


def indistinguishable_set(ranked, n_recordings, floors=None):
    """Mark the structures the recordings cannot tell from the best; the winner first.

    ``ranked``: :class:`StructureFit` objects with ``score`` and ``fold_costs``, best score first.
    Members: every score within :func:`indistinguishable_margin` of the best. Merged
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
        if f.score - best.score <= indistinguishable_margin(best.fold_costs, f.fold_costs, n,
                                                            floors):
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
    """Differential evolution in ``box``, then least squares (in the whole ``space``) from the best
    member and from the runners-up in other basins (a short search often ends before one basin has
    won); the best refined fit."""
    de = global_search(box, objective, rng, seeds=starts, popsize=pop, maxiter=gens, targets=targets)
    fits = refine_all(space, objective,
                      distinct_members(de.population, de.population_costs, box, N_STARTS),
                      max_nfev=nfev, targets=targets)
    return min(fits, key=lambda f: f.cost)


def in_sample_screen(best_cost, n_recordings):
    """In-sample cost above which a structure cannot be indistinguishable from the best.

    A score is a held-out cost, which is at least about the in-sample cost (the overfit of a few
    parameters to hundreds of residuals is a small fraction of a unit per recording), so a structure
    whose in-sample cost exceeds the best's by far more than :func:`indistinguishable_margin` can
    allow is left unranked. The screen is twice the best's cost plus ``SCREEN_ABS`` per recording:
    generous, since two folds that disagree widen the margin beyond its floor.
    """
    return 2.0 * best_cost + SCREEN_ABS * n_recordings


def margin_floors(targets):
    """Floor of :func:`indistinguishable_margin` per recording: ``TOL_ABS``, or a limit cycle's
    :attr:`.targets.CycleTarget.window_cost` where that is larger.

    A wandering cycle (the band-pass loop's) costs even the generating model about its window
    cost, from where the simulated window falls in the wander, and that cost scatters by about
    as much from one fit to the next; a score difference below it is no evidence. Benchmark draw
    1000 (two band-pass cycles at 200 Hz, window costs 0.24 and 0.22; the truth's own cost 0.93)
    ranked a wrong delay position 0.225 better than the truth's structure, 0.025 past the floor
    of 0.2, once the delay's move between positions was matched in frequency (696f4e1).
    Re-evaluated on the 22 benchmark rows that keep their ranking, this floor changes two
    verdicts: 1000 (truth back in a set of 2) and 1023 (a set of 3 becomes 4).
    """
    return np.array([max(TOL_ABS, t.window_cost) for t in targets])


def indistinguishable_margin(best_units, other_units, n_recordings, floors=None):
    """How much worse than the best a score may be and still not be told apart from it.

    ``*_units`` are held-out costs ``(2 folds, n recordings)``. A recording's difference between
    the structures is measured twice, once per fold; the disagreement of the two measures its
    noise (the sd of their mean is ``|d0 - d1| / 2``), never taken below half that recording's
    floor (``TOL_ABS``, or ``floors`` per recording when given: :func:`margin_floors`). The
    margin is twice the standard error of the score difference summed over recordings, the
    recordings' errors independent: ``2 sqrt(sum_i max(|d0_i - d1_i| / 2, floor_i / 2)^2)``.
    One recording's margin is ``max(|d0 - d1|, floor)``.

    The floors add in quadrature like the folds' noise, not linearly: a linear sum (the rule
    before 2026-11-27) let recordings that do not discriminate widen the margin in proportion to
    their number, so that a structure worse on every one of five recordings (benchmark draw
    1017, dead zone on the error: +0.02 to +0.14 on each, 0.35 in all, the folds agreeing) stayed
    inside a margin of 0.5. Recordings are not exchangeable (a square wave can decide what a
    sine cannot), so their spread is not taken as noise.
    """
    d = np.asarray(other_units, dtype=float) - np.asarray(best_units, dtype=float)
    floor = (np.full(n_recordings, TOL_ABS) if floors is None
             else np.asarray(floors, dtype=float))
    sd = np.maximum(np.abs(d[0] - d[1]) / 2.0, floor / 2.0)
    return 2.0 * math.sqrt(float(np.sum(sd**2)))


def delay_moved(params, position):
    """``params`` with the delay moved to ``position`` and the linear block changed to match.

    Inside the second-order block's loop (``before_first_integrator``,
    ``y'' = [K1 e - K2 y' - K3 y](t - Td)``) the block is ``K1 / (s^2 e^{s Td} + K2 s + K3)``;
    after it, ``K1 e^{-s Td} / (s^2 + K2 s + K3)`` (:func:`models.linear.second_order_response`).
    The moved block is the one whose frequency response matches the given one over
    ``MATCHED_BAND`` of the given block's natural frequency ``sqrt(K3)`` (log gain and phase, least
    squares), started from the first-order match (:func:`_first_order_moved`). The first-order
    match alone fails where ``K2 Td`` is not small: benchmark draw 1019's delay-inside fit (K2 Td =
    0.4) moved outside came out 29 % off in gain and 0.27 rad in phase within the band, Td 7.8 ms
    for the truth's 3.7 ms, and least squares from there stopped at cost 133 against 0.72; matched
    over the band it is within 0.1 % and 0.005 rad, and lands at the truth's block within 2 %
    (Td 3.9 ms). M000's 1.7 ms inside reads as 2.1 ms outside. The two outer positions (before
    the integrator, at the output) share the block.
    """
    inner = DelayPosition.BEFORE_FIRST_INTEGRATOR
    if (params.delay_position is inner) == (position is inner):
        return params.replace(delay_position=position)
    start = _first_order_moved(params, position)
    if not params.delay > 0:
        return start
    omega = np.geomspace(MATCHED_BAND[0], MATCHED_BAND[1], 48) * math.sqrt(params.stiffness)
    target = second_order_response(params.gain, params.damping, params.stiffness, params.delay,
                                   params.delay_position is inner, omega)

    def mismatch(x):
        k1, k2, k3, td = np.exp(x)
        ratio = second_order_response(k1, k2, k3, td, position is inner, omega) / target
        return np.concatenate([np.log(np.abs(ratio)), np.angle(ratio)])

    # within MATCHED_RANGE of the given block: a resonant inner block (long delay) has no outer
    # match, and the fit would drift off with every coefficient growing together
    source = np.log([params.gain, params.damping, params.stiffness, params.delay])
    lo, hi = source - math.log(MATCHED_RANGE), source + math.log(MATCHED_RANGE)
    x0 = np.clip(np.log([start.gain, start.damping, start.stiffness, start.delay]), lo, hi)
    fit = least_squares(mismatch, x0, bounds=(lo, hi), xtol=1e-10, ftol=1e-12)
    if not (np.all(np.isfinite(fit.x)) and fit.cost < 0.5 * float(np.sum(mismatch(x0) ** 2))):
        return start
    k1, k2, k3, td = map(float, np.exp(fit.x))
    return start.replace(gain=k1, damping=k2, stiffness=k3, delay=td)


def _first_order_moved(params, position):
    """:func:`delay_moved` to first order in ``s Td``.

    With ``D = 1 + K2 Td`` of the outer form, ``K1, K3`` inside are the outer ones over ``D``,
    ``K2`` inside is ``(K2 + K3 Td) / D`` and the delay inside is ``Td / D``.
    """
    inner = DelayPosition.BEFORE_FIRST_INTEGRATOR
    k1, k2, k3, td = params.gain, params.damping, params.stiffness, params.delay
    if position is inner:  # outer -> inner
        d = 1.0 + k2 * td
        return params.replace(gain=k1 / d, damping=(k2 + k3 * td) / d, stiffness=k3 / d,
                              delay=td / d, delay_position=position)
    # inner -> outer: the D whose outer block maps onto this inner one (K2 outer = (D - 1) / Td)
    def mismatch(d):
        return k2 * d - (d - 1.0) / (td * d) - k3 * td * d * d

    if td <= 0 or mismatch(1.0) <= 0 or mismatch(20.0) >= 0:
        return params.replace(delay_position=position)
    d = brentq(mismatch, 1.0, 20.0)
    return params.replace(gain=k1 * d, damping=(d - 1.0) / (td * d), stiffness=k3 * d,
                          delay=td * d, delay_position=position)


def transferred(params, structure):
    """Another structure's ``params`` as a start for ``structure``.

    The delay is moved with :func:`delay_moved`; a dead zone moved between the error and the
    velocity signal keeps its threshold in rad of error (``z_error = (z - off) / g0``, ``g0 = K1/K3``
    the second-order block's static gain, the search coordinate ``log_c_e``); a component removed
    leaves the moving threshold as it was (:func:`_reduced_values`), one added starts small
    (:func:`_widen`; the band-pass loop at gain 40 and a saturation of 5e-4 rad of error).
    """
    p = delay_moved(params, structure.delay_position)
    g0 = p.gain / p.stiffness
    values = _reduced_values(p, structure)
    moving = values.get("dead_zone", p.dead_zone - p.friction_offset)
    if p.dead_zone_position is not structure.dead_zone_position:
        if structure.dead_zone_position is DeadZonePosition.VELOCITY:
            values["dead_zone"] = moving * g0
        else:
            values["dead_zone"] = moving / g0
        values["friction_offset"] = 0.0
    elif not structure.friction:
        values["friction_offset"] = 0.0
    if structure.bandpass and p.bandpass_gain == 0.0:
        values.update(bandpass_gain=40.0, bandpass_saturation=5e-4 * g0)
    start = structure.to_params(p, **values)
    return structure.to_params(start, **_widen(start, structure))


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


def _contains(parent, s):
    """``parent`` is ``s`` with components added (the band-pass loop among them): at those
    components' zero it is ``s``."""
    return (s.dead_zone_position == parent.dead_zone_position
            and s.delay_position == parent.delay_position
            and set(s.components) < set(parent.components))


def _reduced_values(params, s):
    """Start values for nested ``s`` from its parent's ``params``: the moving threshold kept."""
    values = {}
    if not s.friction and params.friction_offset != 0.0:
        values["dead_zone"] = params.dead_zone - params.friction_offset
    return values


def _widen(p, s):
    """A nested proposal as a start for a larger structure: small values for its absent parts."""
    extra = {}
    if s.backlash and p.backlash == 0.0:
        extra["backlash"] = 1e-5
    if s.friction and p.friction_offset == 0.0:
        extra["friction_offset"] = -0.1 * p.dead_zone
    return extra


def _valid(seeds, s):
    """The seeds as starts of ``s`` (its absent parts widened, :func:`_widen`); a seed ``s`` cannot
    take (a value its parameters refuse) is dropped, never raised."""
    out = []
    for p in seeds:
        try:
            out.append(s.to_params(p, **_widen(p, s)))
        except ValueError:
            continue
    return out


def _progress_bar(work, desc, enabled):
    """A tqdm bar, silent unless ``enabled``: over ``work`` when it is a sequence, else of
    ``work`` steps that concurrent tasks advance (tqdm's ``update`` holds a lock)."""
    from tqdm.auto import tqdm

    if isinstance(work, int):
        return tqdm(total=work, desc=desc, leave=False, disable=not enabled)
    return tqdm(work, desc=desc, leave=False, disable=not enabled)
