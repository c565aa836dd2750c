"""``StructureDiscovery``: every structure fitted to all recordings by simulation, ranked out of sample.

Pipeline (issue 11):

1. **Structure space** -- :func:`models.structures.structure_space` (36 structures after pruning,
   fewer when the user fixes a structural choice).
2. **Screening and seeds** -- weak-form SINDy (:mod:`discovery.sindy`) proposes parameters for the
   structures its forms describe; they enter the first population of the global search of the
   matching structure. Where the data do not support a form, SINDy says so and the search runs
   unseeded; nothing downstream depends on SINDy being right.
3. **Fit** -- for every (dead-zone position, delay position) class, the largest structure without and
   with the band-pass loop gets a global search (differential evolution over the batch kernel) and
   least-squares refinement from its best distinct candidates; every nested structure (no friction,
   no backlash) is refined from its parent's optimum with the component removed.
4. **Rank** -- by leave-one-recording-out error: each structure is refitted (locally, from its
   optimum) without one recording and scored on it; the score is the sum over recordings. With one
   recording the in-sample cost is the criterion (and the output says so).
5. **Report what the data cannot decide** -- structures whose score is within ``tolerance`` of the
   best are indistinguishable from it; a structure that only adds a component to an
   indistinguishable one without lowering its score is merged into it (the output says which). The
   local spread of each coordinate (:func:`.search.local_sd`) marks ridges.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from models.hypotheses import KICK_X0, ActuatorParams, DeadZonePosition, DelayPosition
from models.recording import Recording, load_recording
from models.structures import Structure, structure_space

from .coordinates import SearchSpace, UnknownParameterError
from .search import Objective, global_search, local_sd, refine
from .targets import make_target

__all__ = ["StructureDiscovery", "StructureFit", "validate_recordings", "DiscoveryInputError"]

#: Template of the fields a search does not set (paper 001's linear block, only a placeholder; the
#: papers' kick x0 so that a reported model, simulated in closed loop, leaves the equilibrium).
TEMPLATE = dict(gain=305500.0, damping=202.1, stiffness=14520.0, dead_zone=1e-3,
                dead_zone_position=DeadZonePosition.ERROR, backlash=0.0, delay=2e-3,
                delay_position=DelayPosition.OUTPUT, x0=KICK_X0)
#: Indistinguishable: held-out score within ``TOL_ABS`` per recording plus ``TOL_REL`` of the best.
TOL_ABS = 0.5
TOL_REL = 0.25
#: A recording whose output exceeds this (rad) is probably in degrees.
MAX_ANGLE = 0.5


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
    quick : bool
        Smaller searches (tests, CI).
    dt : float
        RK4 step of the simulations (s).
    use_sindy : bool
        Seed the searches with weak-form SINDy's proposals.
    progress : bool
        Progress bars (tqdm).
    max_ranked : int
        Structures (best in-sample first) that get the leave-one-recording-out ranking.

    Attributes
    ----------
    ranking_ : list of StructureFit
        Best first.
    best_ : StructureFit
    indistinguishable_ : list of StructureFit
        The best and every structure the data cannot tell from it (merged ones included).
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
    targets_ : list
    """

    def __init__(self, fixed=None, seed=0, quick=False, dt=5e-4, use_sindy=True, progress=False,
                 max_ranked=8):
        self.fixed = fixed
        self.seed = seed
        self.quick = quick
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
        pop, gens = (5, 15) if self.quick else (8, 45)
        starts = [space.coordinates(p) for p in seeds]
        de = global_search(space, objective, rng, seeds=starts, popsize=pop, maxiter=gens)
        best = refine(space, objective, de.theta, max_nfev=15 if self.quick else 30)
        # a second start from the best SINDy seed guards against a population that missed it
        for s in starts[:1]:
            alt = refine(space, objective, s, max_nfev=15 if self.quick else 30)
            if alt.cost < best.cost:
                best = alt
        return best

    def fit(self, recordings):
        t_start = time.perf_counter()
        timings = {}
        recs = validate_recordings(recordings)
        fixed = dict(self.fixed or {})
        known = set(ActuatorParams.parameter_names())
        unknown = sorted(set(fixed) - known)
        if unknown:
            raise UnknownParameterError(
                f"unknown parameter(s) {', '.join(unknown)} in --fix; known: {', '.join(sorted(known))}")
        structural = {k: fixed.pop(k) for k in ("dead_zone_position", "delay_position") if k in fixed}
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
        bar = _progress(tops, "global search", self.progress)
        for s in bar:
            seeds = list(sindy.get(s.name, []))
            for other, plist in sindy.items():  # nested proposals seed their parents too
                o = Structure.parse(other)
                if (o.dead_zone_position, o.delay_position) == (s.dead_zone_position, s.delay_position):
                    seeds += [s.to_params(p, **_widen(p, s)) for p in plist if p not in seeds]
            if s.bandpass:
                parent = fits.get(s.without("bandpass"))
                if parent is not None:
                    seeds += [parent.params.replace(bandpass_gain=g, bandpass_saturation=k * parent.params.gain
                                                    / parent.params.stiffness)
                              for g, k in ((40.0, 5e-4), (80.0, 3e-4))]
            fr = self._fit_global(spaces[s], objective, rng, _valid(seeds, s))
            fits[s] = self._fit_record(s, spaces[s], fr, "global search (differential evolution, "
                                       "then least squares)", sindy.get(s.name, []))
        timings["global"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        rest = [s for s in kept if s not in fits]
        rest.sort(key=lambda s: -len(s.components))
        for s in _progress(rest, "nested structures", self.progress):
            parent = min((f for f in fits.values() if _is_nested(s, f.structure)),
                         key=lambda f: f.cost, default=None)
            if parent is None:
                fr = self._fit_global(spaces[s], objective, rng, [])
                origin = "global search"
            else:
                start = s.to_params(parent.params, **_reduced_values(parent.params, s))
                fr = refine(spaces[s], objective, spaces[s].coordinates(start),
                            max_nfev=15 if self.quick else 30)
                origin = f"least squares from {parent.structure.name} with the component removed"
            fits[s] = self._fit_record(s, spaces[s], fr, origin, sindy.get(s.name, []))
        timings["nested"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        ranked = self._rank(fits, spaces, objective)
        timings["ranking"] = time.perf_counter() - t0
        best = ranked[0]
        for f in [g for g in ranked if g.indistinguishable_from_best]:
            sd = local_sd(spaces[f.structure], objective, f.theta)
            f.coordinate_sd = dict(zip(spaces[f.structure].names, map(float, sd)))
        self.ranking_ = ranked
        self.best_ = best
        self.indistinguishable_ = [f for f in ranked if f.indistinguishable_from_best]
        self.pruned_ = {s.name: why for s, why in pruned.items()}
        self.offsets_ = objective.offsets(best.params)
        self.noise_ = {t.name: (t.noise(best.params) if t.kind == "open" else self._noise_of(t.recording))
                       for t in targets}
        self.fixed_ = dict(self.fixed or {})
        self.n_simulations_ = objective.n_evaluations
        timings["total"] = time.perf_counter() - t_start
        self.timings_ = timings
        return self

    def _fit_record(self, s, space, fr, origin, seeds):
        names = [t.name for t in self.targets_]
        return StructureFit(structure=s, params=space.params(fr.theta), theta=fr.theta,
                            cost=fr.cost, cost_by_recording=dict(zip(names, map(float, fr.cost_by_target))),
                            origin=origin, sindy_seeds=[p.to_dict() for p in seeds])

    def _rank(self, fits, spaces, objective):
        """Leave-one-recording-out scores for the best in-sample fits; sets and merges."""
        order = sorted(fits.values(), key=lambda f: f.cost)
        targets = self.targets_
        n = len(targets)
        candidates = order[: self.max_ranked]
        if n == 1:
            for f in order:
                f.score, f.criterion = f.cost, "in-sample cost (one recording: nothing to hold out)"
        else:
            for f in order[self.max_ranked:]:
                f.score, f.criterion = math.inf, "not ranked (in-sample cost far from the best)"
            for f in _progress(candidates, "leave-one-recording-out", self.progress):
                held = {}
                for i, t in enumerate(targets):
                    rest = targets[:i] + targets[i + 1:]
                    fr = refine(spaces[f.structure], objective, f.theta,
                                max_nfev=6 if self.quick else 12, targets=rest)
                    held[t.name] = float(objective.costs([spaces[f.structure].params(fr.theta)],
                                                         [t])[0, 0])
                f.held_out = held
                f.score = float(sum(held.values()))
                f.criterion = "leave-one-recording-out cost (sum over recordings)"
        ranked = sorted(order, key=lambda f: (f.score, f.cost))
        best_score = ranked[0].score
        tol = TOL_ABS * n + TOL_REL * best_score
        inside = [f for f in ranked if f.score <= best_score + tol]
        names = {f.structure: f for f in inside}
        for f in inside:
            f.indistinguishable_from_best = True
            # a superset that does not beat its nested structure is that structure
            for comp in f.structure.components:
                sub = names.get(f.structure.without(comp))
                if sub is not None and f.score >= sub.score - TOL_REL * sub.score:
                    f.merged_into = sub.structure.name
                    break
        # the winner: the best-scoring structure that is not merged into a simpler one
        winner = next(f for f in ranked if f.merged_into is None)
        ranked.remove(winner)
        ranked.insert(0, winner)
        return ranked


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
    return (s.dead_zone_position == parent.dead_zone_position
            and s.delay_position == parent.delay_position and s.bandpass == parent.bandpass
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
    out = []
    for p in seeds:
        try:
            out.append(s.to_params(p))
        except ValueError:
            continue
    return out


def _progress(items, desc, enabled):
    if not enabled:
        return items
    from tqdm.auto import tqdm

    return tqdm(items, desc=desc, leave=False)
