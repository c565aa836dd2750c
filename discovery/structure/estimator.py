"""``StructureDiscovery``: every structure fitted to all recordings by simulation, ranked out of sample.

Pipeline (:meth:`StructureDiscovery.fit`):

1. **Structure space** -- :func:`tvcid.models.structures.structure_space` (36 structures after pruning,
   fewer when the user fixes a structural choice).
2. **Screening and seeds** -- weak-form SINDy (:mod:`tvcid.discovery.sindy`) proposes parameters for the
   structures its forms describe; they enter the first population of the global search of the
   matching structure. Where the data do not support a form, SINDy says so and the search runs
   unseeded; nothing downstream depends on SINDy being right.
3. **Fit** (:class:`.structure_search.StructureSearch`) -- for every (dead-zone position, delay
   position) class, the largest structure without and with the band-pass loop gets a global
   search (differential evolution over the batch kernel; staged, open-loop tests first, when
   there are both kinds of recording; each stage repeated until two independent searches agree,
   :func:`.global_fit.best_of_restarts`) and least-squares refinement from its best
   distinct candidates, then from the better optima of the structures that differ from it only
   in the delay's position; every nested structure (no friction, no backlash) is refined from its
   parent's optimum with the component removed. A structure that fits worse than one of its
   nested structures (a search failure: it can reproduce them) is refined again from that
   optimum; last, every structure is refined from the best optimum of all, carried over
   (:func:`.transfer.transferred`).
4. **Rank** (:func:`.ranking.rank`) -- by two-fold out-of-sample error: each structure within
   :func:`.ranking.in_sample_screen` of the best in-sample cost is refitted (locally, from its
   optimum) on one half of every recording and scored on the other half, both ways round.
5. **Report what the data cannot decide** (:mod:`.indistinguishable`) -- structures whose score
   is within :func:`.indistinguishable.indistinguishable_margin` of the best (Student's t
   quantile for its degrees of freedom times the standard error of the score difference: each
   recording's from the disagreement of the two folds, with a floor that a wandering cycle raises,
   :func:`.indistinguishable.margin_floors`; the recordings' added in quadrature) are
   indistinguishable from it; a structure that only adds components to
   an indistinguishable one without beating it by that margin is merged into it (the output says
   which), and so is every superset of a member whatever its own fit scored (at its added
   components' zero it is that member). The local spread of each coordinate
   (:func:`.search.local_sd`) marks ridges.

Also here: :func:`validate_recordings`, the checks discovery makes on its input, and
:class:`DiscoveryInputError`.
"""
from __future__ import annotations

import time

import numpy as np

from tvcid.models.hypotheses import ActuatorParams, DeadZonePosition, DelayPosition
from tvcid.models.recording import Recording, load_recording
from tvcid.models.structures import Structure, shared_choices, structure_space

from ..speed import cpu_seconds
from ..threads import one_blas_thread
from .coordinates import SearchSpace, UnknownParameterError
from .ranking import rank
from .search import Objective, local_sd
from .structure_search import SEARCHES, TEMPLATE, StructureSearch, _fixed_for
from .targets import make_target

__all__ = ["StructureDiscovery", "validate_recordings", "DiscoveryInputError", "NO_FIT_COST",
           "MAX_ANGLE"]

#: Cost per recording at or above which a fit reproduces nothing: residuals of 100 units rms (a
#: cycle's frequency 10 % or its harmonics 30 % of the fundamental off, on average), far beyond
#: any structure near the data (the benchmark's search failures cost under 40). With the
#: band-pass loop a fixed linear block that cannot move the actuator still rings at 9-10 Hz
#: (cost 8e4, the test's case); a run that diverges or stops oscillating costs 1e8 (``PENALTY**2``).
NO_FIT_COST = 1e4
#: A recording whose output exceeds this (rad) is probably in degrees.
MAX_ANGLE = 0.5


class DiscoveryInputError(ValueError):
    """Input that discovery cannot work with; the message names the file or parameter."""


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
        Sizes of the searches (:data:`.structure_search.SEARCHES`).
    dt : float
        RK4 step of the simulations (s).
    use_sindy : bool
        Seed the searches with weak-form SINDy's proposals.
    progress : bool
        Progress bars (tqdm).
    max_ranked : int
        Structures (best in-sample first) that always get the out-of-sample ranking; any further
        structure whose in-sample cost is within :func:`.ranking.in_sample_screen` of the best's
        is ranked too, so that the reported set is not cut at a fixed size.
    executor : tvcid.discovery.executors.Executor, optional
        Runs the global searches of the classes' largest structures
        (:meth:`.structure_search.StructureSearch.search_classes`), e.g. on a Dask cluster;
        default: one after the other in this process. The result is the same wherever they run.
    race : {"off", "measure", "on"}
        Race the classes' searches where there are open-loop and closed-loop recordings
        (:meth:`.structure_search.StructureSearch.race_classes`): ``on`` drops the classes
        whose open-loop misfit alone rules them out of the in-sample screen (they join
        ``pruned_``), ``measure`` searches them all and records what the race would drop, ``off``
        (default) searches every class in the classes' order. Not the default: the set's margin
        is not bounded by the screen, and on the drop rule's measured draws the race would drop
        members of the reported set (docs/limits.md).

    Attributes
    ----------
    ranking_ : list of StructureFit
        Best first.
    best_ : StructureFit
    indistinguishable_ : list of StructureFit
        The best and every structure the data cannot tell from it (merged ones included).
    decided_ : dict
        Structural choice -> the value every structure of ``indistinguishable_`` shares, ``None``
        where they differ (the recordings leave it open; :func:`tvcid.models.structures.shared_choices`).
    pruned_ : dict
        Structure name -> why it was not fitted (the fixed parts, or the race).
    race_ : dict or None
        What the race decided: each top's open-loop bound, the screen, the tops and structures
        dropped, and whether they were (:attr:`.structure_search.StructureSearch.race_record`);
        None where it did not run.
    repaired_ : list of str
        Structures the repairs refitted (:meth:`.structure_search.StructureSearch.fit_nested`).
    offsets_ : dict
        Sensor offset per recording at the best fit (rad).
    noise_ : dict
        Sensor-noise sd per recording (rad): open loop, the rms output error at the best fit;
        closed loop, from second differences.
    sindy_ : dict
        SINDy's proposals by structure, or the reason it gave none.
    fixed_ : dict
        The fixed parts used.
    n_simulations_ : int
        Parameter sets simulated (searches, refinements and the ranking's refits).
    timings_ : dict
        Wall time per stage (s).
    cpu_seconds_ : dict
        CPU seconds per stage (``sindy``, ``global`` and ``nested``, or ``refit``; ``ranking``,
        ``total``): this process's and its ended children's
        (:func:`tvcid.discovery.speed.cpu_seconds`), with those of the global searches that ran in
        other processes.
    simulated_seconds_ : dict
        Seconds simulated per stage (``global`` and ``nested``, or ``refit``; ``ranking``), each
        parameter set's run over every recording it was scored on; stages only, so that the
        values add up to the search's.
    simulated_steps_ : dict
        Kernel steps of the same runs per stage (each run's ``t_end / dt``).
    searches_ : dict
        Independent searches run per stage (``open_loop``, ``global``;
        :func:`.global_fit.best_of_restarts`).
    targets_ : list
    sizes_ : SearchSizes
        The search sizes used.
    """

    def __init__(self, fixed=None, seed=0, search="standard", dt=5e-4, use_sindy=True,
                 progress=False, max_ranked=8, executor=None, race="off"):
        self.fixed = fixed
        self.seed = seed
        self.search = search
        self.dt = dt
        self.use_sindy = use_sindy
        self.progress = progress
        self.max_ranked = max_ranked
        self.executor = executor
        self.race = race

    def fit(self, recordings, previous=None, previous_race=None):
        """Screen, search, refine and rank every structure on ``recordings``; returns ``self``.

        ``previous`` (structure name -> ActuatorParams, an earlier run's optima on part of these
        recordings) replaces SINDy's screening and the global searches by least squares from
        those optima (:meth:`.structure_search.StructureSearch.refit_from`): the experiment
        loop's update after new recordings; ``previous_race`` (the earlier run's ``race_``) keeps
        the structures its race dropped out while they stay ruled out."""
        with one_blas_thread():  # the kernels own the cores (:mod:`tvcid.discovery.threads`)
            return self._fit(recordings, previous, previous_race)

    def _fit(self, recordings, previous=None, previous_race=None):
        t_start, c_start = time.perf_counter(), cpu_seconds()
        timings, cpu = {}, {}
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
        t0, c0 = time.perf_counter(), cpu_seconds()
        if previous:
            sindy, sindy_error = {}, "not run: the earlier run's optima seed the searches"
        elif not self.use_sindy:
            sindy, sindy_error = {}, "not run"
        else:
            sindy, sindy_error = self._sindy_seeds(recs)
        self.sindy_ = {"proposals": {k: [p.to_dict() for p in v] for k, v in sindy.items()},
                       "error": sindy_error}
        timings["sindy"], cpu["sindy"] = time.perf_counter() - t0, cpu_seconds() - c0

        spaces = {s: SearchSpace(s, base, _fixed_for(s, fixed), self.dt) for s in kept}
        search = StructureSearch(objective, self.sizes_, rng, spaces, self.progress, self.executor,
                                 race=self.race)
        simulated, steps = {}, {}
        clock = [0.0, 0.0, 0.0, 0.0, 0.0]

        def start():
            clock[:] = (time.perf_counter(), cpu_seconds(), search.worker_cpu_seconds,
                        objective.simulated_seconds, objective.simulated_steps)

        def stop(stage):
            timings[stage] = time.perf_counter() - clock[0]
            cpu[stage] = cpu_seconds() - clock[1] + search.worker_cpu_seconds - clock[2]
            simulated[stage] = objective.simulated_seconds - clock[3]
            steps[stage] = objective.simulated_steps - clock[4]

        start()
        if previous:
            fits, self.repaired_ = search.refit_from(kept, previous, race=previous_race)
            stop("refit")
        else:
            fits = search.search_classes(kept, sindy)
            stop("global")
            timings["global_open_loop_stage"] = search.global_fit.open_loop_seconds
            start()
            self.repaired_ = search.fit_nested([s for s in kept if s not in search.dropped],
                                               fits, sindy)
            stop("nested")

        best_fit = min(fits.values(), key=lambda f: f.cost)
        if best_fit.cost >= NO_FIT_COST * len(targets):
            raise DiscoveryInputError(
                f"no structure reproduces the recordings: every candidate diverged, stopped "
                f"oscillating or missed them by over 100 units rms (best {best_fit.structure.name}, "
                f"cost {best_fit.cost:.3g}); check the "
                "fixed parameters and the sidecars' controller settings")
        t0, c0 = time.perf_counter(), cpu_seconds()
        ranked, rank_evaluations, simulated["ranking"], steps["ranking"] = rank(
            fits, spaces, targets, self.dt, self.sizes_.rank_nfev, self.max_ranked, self.progress)
        timings["ranking"], cpu["ranking"] = time.perf_counter() - t0, cpu_seconds() - c0
        best = ranked[0]
        for f in [g for g in ranked if g.indistinguishable_from_best]:
            sd = local_sd(spaces[f.structure], objective, f.theta)
            f.coordinate_sd = dict(zip(spaces[f.structure].names, map(float, sd)))
        self.ranking_ = ranked
        self.best_ = best
        self.indistinguishable_ = [f for f in ranked if f.indistinguishable_from_best]
        self.decided_ = shared_choices([f.structure for f in self.indistinguishable_])
        self.pruned_ = {s.name: why for s, why in {**pruned, **search.dropped}.items()}
        self.race_ = search.race_record
        self.offsets_ = objective.offsets(best.params)
        self.noise_ = {t.name: (t.noise(best.params) if t.kind == "open" else self._noise_of(t.recording))
                       for t in targets}
        self.fixed_ = dict(self.fixed or {})
        self.n_simulations_ = objective.n_evaluations + rank_evaluations
        timings["total"] = time.perf_counter() - t_start
        cpu["total"] = cpu_seconds() - c_start + search.worker_cpu_seconds
        self.timings_ = timings
        self.cpu_seconds_ = cpu
        self.simulated_seconds_ = simulated
        self.simulated_steps_ = steps
        self.searches_ = dict(search.global_fit.searches)
        return self

    def _sindy_seeds(self, recs):
        """SINDy's proposals as parameter objects, by structure name, and the reason for none."""
        from tvcid.discovery.sindy import WeakSINDyActuator

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
        from tvcid.models.cycle_reading import white_noise_sd

        return white_noise_sd(rec.delta)
