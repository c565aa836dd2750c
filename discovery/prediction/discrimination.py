"""Which test would tell apart the structures the recordings cannot: model discrimination.

:class:`tvcid.discovery.structure.estimator.StructureDiscovery` reports the structures whose
held-out scores the recordings cannot separate
(:func:`tvcid.discovery.structure.indistinguishable.indistinguishable_set`). This module asks which
further test would separate them. Each candidate test
(:class:`tvcid.discovery.prediction.design.Candidate`: an open-loop square, sine or step, or a
controller setting) is recorded synthetically from the best member with the recordings' sensor noise
and turned into the discovery's own target (:func:`tvcid.discovery.structure.targets.make_target`:
limit-cycle features, or the output error of a simulation from rest). Every member is simulated
through it at its fitted parameters; the cost a member would pay on the new recording if another
member were the truth is the squared distance of their residual vectors, in the target's units (a
cost is a mean of squared residuals, about 1 for the generating model), so it reads on the scale of
the discovery's scores.

That comparison at fixed parameters (the discrimination designs of Box and Hill, 1967) screens
the whole menu, but a refit absorbs most of it. So the ``REFIT_CANDIDATES`` best candidates are
weighed again as T-optimal designs do (Atkinson and Fedorov, 1975): each member's record of the
test is made (one noise realisation for all), every other member is refitted by least squares
from its optimum to the recordings so far and that record together, and what its cost rises,
beyond the recording member's own cost on its record, is the separation. A pair is *decided*
when both ways round (either member the truth) the separation reaches ``DECIDES``, three times
the margin's floor of one recording (``TOL_ABS``). The candidates are ranked by the pairs they
decide, the refitted ones first, then by their closest pair's separation.
"""
from __future__ import annotations

import itertools
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvcid.models.cycle_reading import NoCycleError
from tvcid.models.experiments import CONTROLLER_A, CONTROLLER_B, OpenLoop
from tvcid.models.structures import Structure

from ..calibration.priors import SIGMA
from .design import Candidate, DesignRanking, rank_experiments
from ..structure.indistinguishable import TOL_ABS
from ..structure.targets import make_target

__all__ = ["DiscriminationRanking", "default_candidates", "discriminating_tests", "design_over_set",
           "DECIDES"]

#: Predicted cost difference on the new recording at which a test decides a pair of structures.
DECIDES = 3.0 * TOL_ABS
#: Candidates (the best at fixed parameters) weighed again with every member refitted, and the
#: refits' evaluations (the discovery's standard refinement).
REFIT_CANDIDATES = 3
REFIT_NFEV = 15
#: Open-loop menu of :func:`default_candidates`: amplitudes (rad) and frequencies (Hz) of squares
#: and sines, from the slow tests the papers ran to edges faster than the limit cycles.
OPEN_AMPLITUDES = (5e-3, 10e-3, 20e-3)
OPEN_FREQUENCIES = (0.5, 1.0, 2.0, 4.0, 8.0)
OPEN_DURATION = 10.0
CLOSED_DURATION = 20.0
#: Seconds simulated before a closed-loop candidate's record starts (the cycle settles).
CLOSED_LEAD = 10.0


def default_candidates(sample_rate=1000.0):
    """Open-loop squares and sines (``OPEN_AMPLITUDES`` x ``OPEN_FREQUENCIES``, 10 s) and limit
    cycles at the papers' controller settings A and B (20 s), acquired at ``sample_rate`` Hz."""
    out = []
    for waveform in ("square", "sine"):
        for a, f in itertools.product(OPEN_AMPLITUDES, OPEN_FREQUENCIES):
            out.append(Candidate(f"open-loop {waveform} {a * 1e3:g} mrad {f:g} Hz",
                                 getattr(OpenLoop, waveform)(a, f), OPEN_DURATION, sample_rate))
    for label, exp in (("A", CONTROLLER_A), ("B", CONTROLLER_B)):
        out.append(Candidate(f"closed loop {label} (Kp {exp.kp:g}, Kd {exp.kd:g}, mu {exp.mu:g})",
                             exp, CLOSED_DURATION, sample_rate))
    return out


@dataclass(frozen=True)
class DiscriminationRanking:
    """Candidate tests ranked by how well they separate a set of structures.

    Attributes
    ----------
    members : tuple of str
        The structures to tell apart (names), the best first.
    tests : tuple of dict
        Best first (the refitted candidates, then the others): ``name``, ``refitted``,
        ``pairs_decided`` (of ``n_pairs``), ``closest_pair`` and its ``closest_separation``,
        ``separation`` (members x members, symmetric: the cost a member adds on the new
        recording if the other is the truth), ``undecided`` (the pairs left); the same keys
        ending in ``_fixed`` at the fitted parameters (equal to the plain ones where not
        refitted); or ``skipped`` with the reason (the best member shows no cycle there).
    noise_sd : float
        Sensor-noise sd assumed for the new tests (rad).
    decides : float
        The predicted cost difference that decides a pair (``DECIDES``).
    simulated_seconds, simulated_steps : float
        What the ranking simulated (the synthetic records, the members' runs on them and the
        refits), in seconds and kernel steps; not in :meth:`to_dict`.
    """

    members: tuple
    tests: tuple
    noise_sd: float
    decides: float = DECIDES
    simulated_seconds: float = 0.0
    simulated_steps: float = 0.0

    @property
    def n_pairs(self) -> int:
        return len(self.members) * (len(self.members) - 1) // 2

    @property
    def best(self) -> dict | None:
        """The test that decides the most pairs (``None`` when no candidate ran)."""
        ran = [t for t in self.tests if "skipped" not in t]
        return ran[0] if ran else None

    def to_dict(self) -> dict:
        return {"members": list(self.members), "n_pairs": self.n_pairs, "noise_sd": self.noise_sd,
                "decides": self.decides, "best": self.best, "tests": list(self.tests),
                "criterion": "predicted cost difference on the new recording at the members' "
                             f"fitted parameters; a pair is decided at {self.decides:g} or more"}

    def plot(self, ax=None, n_tests=12):
        """Pairs decided and the closest pair's separation of the best ``n_tests`` candidates."""
        if ax is None:
            import matplotlib.pyplot as plt

            ax = plt.subplots(figsize=(7, 0.35 * n_tests + 1.2))[1]
        ran = [t for t in self.tests if "skipped" not in t][:n_tests][::-1]
        y = np.arange(len(ran))
        ax.barh(y, [t["closest_separation"] for t in ran], color="0.6",
                label="closest pair's predicted cost difference")
        ax.axvline(self.decides, color="k", lw=0.8, ls=":", label="decides a pair")
        ax.set_xscale("symlog", linthresh=0.01)
        ax.set_yticks(y, [f"{t['name']} ({t['pairs_decided']}/{self.n_pairs}"
                          f"{', refitted' if t['refitted'] else ''})" for t in ran], fontsize=7)
        ax.set_xlabel("closest pair's predicted cost difference (pairs decided in brackets)")
        ax.legend(fontsize=7, loc="lower right")
        return ax


def discriminating_tests(members, candidates=None, noise_sd=1e-5, dt=5e-4, seed=0,
                         recorded=None, n_refit=REFIT_CANDIDATES):
    """Rank ``candidates`` by the pairs of ``members`` they would tell apart.

    Parameters
    ----------
    members : sequence of tvcid.models.ActuatorParams
        Fitted parameters of the structures to tell apart, the best first (each a different
        structure: :meth:`tvcid.models.structures.Structure.of_params`).
    candidates : sequence of Candidate, optional
        Tests to weigh (default :func:`default_candidates`).
    noise_sd : float
        Sensor-noise sd (rad) of the new recordings.
    dt : float
        Simulation step (s) of the targets (the discovery's).
    seed : int
        Seed of the synthetic records' noise.
    recorded : sequence of targets, optional
        The recordings the members were fitted to
        (:attr:`tvcid.discovery.structure.estimator.StructureDiscovery.targets_` or
        :func:`tvcid.discovery.structure.targets.make_target` of each): with them the ``n_refit``
        best candidates at fixed parameters are weighed again with the members refitted; without
        them only the comparison at fixed parameters is made (a refit to the new test alone would
        bend every structure to it).
    n_refit : int
        Candidates weighed again with the members refitted.

    Returns
    -------
    DiscriminationRanking

    Raises
    ------
    ValueError
        Fewer than two members, two members of one structure, or a noise sd that is not > 0.
    """
    members = list(members)
    if len(members) < 2:
        raise ValueError(f"discrimination needs at least two structures (got {len(members)})")
    names = [Structure.of_params(p).name for p in members]
    if len(set(names)) != len(names):
        raise ValueError(f"two members share a structure: {names}")
    if not (noise_sd > 0 and math.isfinite(noise_sd)):
        raise ValueError(f"noise_sd must be > 0 (got {noise_sd})")
    candidates = default_candidates() if candidates is None else list(candidates)
    rng = np.random.default_rng(seed)
    seeds = rng.integers(2**31, size=len(candidates))
    spent = _Spent()
    with tempfile.TemporaryDirectory() as tmp:
        tests = [_weighed(cand, members, names, noise_sd, dt, int(seeds[i]),
                          Path(tmp) / f"candidate{i:03d}.csv", spent)
                 for i, cand in enumerate(candidates)]
    screened = sorted((t for t in tests if "skipped" not in t),
                      key=lambda t: (-t["pairs_decided"], -t["closest_separation"]))
    if recorded:
        by_name = {c.name: (c, int(seeds[i])) for i, c in enumerate(candidates)}
        with tempfile.TemporaryDirectory() as tmp:
            for t in screened[:n_refit]:
                cand, s = by_name[t["name"]]
                _refitted(t, cand, members, names, list(recorded), noise_sd, dt, s, Path(tmp),
                          spent)
    refit = [t for t in screened if t["refitted"]]
    ranked = sorted(refit, key=lambda t: (-t["pairs_decided"], -t["closest_separation"]))
    ranked += [t for t in screened if not t["refitted"]]
    return DiscriminationRanking(tuple(names), tuple(ranked + [t for t in tests if "skipped" in t]),
                                 float(noise_sd), simulated_seconds=spent.seconds,
                                 simulated_steps=spent.steps)


class _Spent:
    """Seconds and kernel steps simulated, summed over runs and objectives."""

    def __init__(self):
        self.seconds = 0.0
        self.steps = 0.0

    def run(self, seconds, dt):
        self.seconds += float(seconds)
        self.steps += float(seconds) / float(dt)

    def objective(self, objective):
        """Count what ``objective`` has simulated."""
        self.seconds += objective.simulated_seconds
        self.steps += objective.simulated_steps


def _target_of(params, cand, noise_sd, dt, seed, path, spent=None):
    """The discovery's target of ``params``' synthetic record of ``cand`` (a closed-loop record
    after ``CLOSED_LEAD`` s), or the reason there is none (no cycle, a diverging run); the
    record's simulation is counted in ``spent``."""
    from tvcid.models.simulate import SimulationDiverged, step_for_rate
    from tvcid.models.synthetic import synthetic_recording

    closed = cand.kind == "closed"
    if spent is not None:  # at the step synthetic_recording takes; a diverging run at its length
        spent.run(cand.duration + (CLOSED_LEAD if closed else 0.0),
                  step_for_rate(cand.sample_rate,
                                controller_rate=getattr(cand.experiment, "sample_rate", None)))
    try:
        rec = synthetic_recording(params, cand.experiment,
                                  cand.duration + (CLOSED_LEAD if closed else 0.0), noise_sd, seed,
                                  path, keep_last=cand.duration if closed else None,
                                  rate=cand.sample_rate)
        return make_target(rec, dt)
    except (NoCycleError, SimulationDiverged, ValueError) as exc:
        return str(exc)


def _weighed(cand, members, names, noise_sd, dt, seed, path, spent):
    """One candidate's separation matrix and verdict (or the reason it was skipped); what it
    simulates is counted in ``spent``."""
    from ..structure.search import Objective

    target = _target_of(members[0], cand, noise_sd, dt, seed, path, spent)
    if isinstance(target, str):
        return {"name": cand.name, "skipped": f"the best structure: {target}"}
    # the objective starts each member at the target's initial conditions and counts the runs
    objective = Objective([target])
    res = objective.residuals(members)
    spent.objective(objective)
    sep = np.sum((res[:, None, :] - res[None, :, :]) ** 2, axis=2)
    return {"name": cand.name, "kind": cand.kind, "refitted": False,
            **_verdict(sep, names, "_fixed"), **_verdict(sep, names)}


def _verdict(sep, names, suffix=""):
    """Pairs decided, the closest pair and the undecided ones of a symmetric separation matrix."""
    pairs = list(itertools.combinations(range(len(names)), 2))
    closest = min(pairs, key=lambda ij: sep[ij])
    return {f"pairs_decided{suffix}": int(sum(sep[ij] >= DECIDES for ij in pairs)),
            f"closest_pair{suffix}": [names[closest[0]], names[closest[1]]],
            f"closest_separation{suffix}": float(sep[closest]),
            f"undecided{suffix}": [[names[i], names[j]] for i, j in pairs if sep[i, j] < DECIDES],
            f"separation{suffix}": np.round(sep, 6).tolist()}


def _refitted(test, cand, members, names, recorded, noise_sd, dt, seed, tmp, spent):
    """``test``'s verdict again with the members refitted to every other member's record of it.

    Member ``j``'s record of the test is made (one noise realisation for every ``j``); member
    ``i`` is refitted by least squares, from its optimum, to the recordings so far
    (``recorded``: their targets) and that record together. ``sep[i, j]`` is what ``i``'s
    refitted cost rose above its cost on the recordings so far, less ``j``'s own cost on its
    record: the evidence the test would add against ``i`` were ``j`` the truth. A pair's
    separation is the smaller of its two ways round; a pair undecided at fixed parameters is
    not refitted (a refit only lowers the separation). A member whose record of a closed-loop
    test shows no cycle is told from every member that shows one. What it simulates is counted
    in ``spent``.
    """
    from ..structure.coordinates import SearchSpace
    from ..structure.search import Objective, refine

    k = len(members)
    targets = [_target_of(p, cand, noise_sd, dt, seed, tmp / f"refit{j:02d}.csv", spent)
               for j, p in enumerate(members)]
    targets = [None if isinstance(t, str) else t for t in targets]
    old = Objective(recorded)
    old_cost = old.costs(members).sum(axis=1)
    spent.objective(old)
    own = []
    for t, p in zip(targets, members):
        if t is None:
            own.append(None)
            continue
        objective = Objective([t])
        own.append(float(objective.costs([p])[0].sum()))
        spent.objective(objective)
    fixed = np.asarray(test["separation_fixed"])
    sep = np.zeros((k, k))
    for i, j in itertools.permutations(range(k), 2):
        if targets[j] is None:
            sep[i, j] = np.inf if targets[i] is not None else 0.0
            continue
        if min(fixed[i, j], fixed[j, i]) < DECIDES:
            sep[i, j] = fixed[i, j]
            continue
        space = SearchSpace(Structure.of_params(members[i]), members[i], {}, dt)
        objective = Objective(list(recorded) + [targets[j]])
        fit = refine(space, objective, space.coordinates(members[i]), max_nfev=REFIT_NFEV)
        spent.objective(objective)
        sep[i, j] = max(fit.cost - old_cost[i] - own[j], 0.0)
    test.update(refitted=True, **_verdict(np.minimum(sep, sep.T), names))


def design_over_set(member_draws: dict, candidates, params=None, noise=None, seed=0,
                    n_truths=24, progress=False) -> DesignRanking:
    """Rank ``candidates`` for a set of structures the recordings could not tell apart.

    Each member (``member_draws``: structure name ->
    :class:`tvcid.discovery.prediction.draws.PosteriorDraws`, e.g.
    :func:`tvcid.discovery.prediction.draws.load_set_draws`) ranks the candidates by
    :func:`tvcid.discovery.prediction.design.rank_experiments` on the parameters every member samples
    (or ``params``); a candidate's information gain and expected width ratios are the members'
    means (equal weights, as in the set's posterior), and each member's gain is kept. Beside it,
    the pairs of members the candidate would tell apart at their median models
    (:func:`discriminating_tests`, at the noise of the new test). A candidate that tells more
    pairs apart ranks first, then the larger gain: while the structure is open each member's
    intervals hold only under that member, so a test that decides between them teaches more than
    one that narrows them all.

    Returns
    -------
    tvcid.discovery.prediction.design.DesignRanking
        Rows with ``pairs_decided`` (of ``n_pairs``) and each member's gain and width ratios
        (``members``) beside the means.

    Raises
    ------
    ValueError
        Fewer than two members, or ``params`` not sampled by every member.
    """
    names = list(member_draws)
    if len(names) < 2:
        raise ValueError(f"a set needs at least two members (got {len(names)})")
    shared = [n for n in member_draws[names[0]].names
              if n != SIGMA and all(n in d.names for d in member_draws.values())]
    chosen = list(params) if params else shared
    missing = [p for p in chosen if p not in shared]
    if missing:
        raise ValueError(f"--params {', '.join(missing)}: not sampled by every member of the set "
                         f"(shared: {', '.join(shared)})")
    sigma = noise if noise is not None else next(
        (d.sigma() for d in member_draws.values() if d.sigma() is not None), None)
    rankings = {n: rank_experiments(d, candidates, params=chosen, noise=sigma, seed=seed,
                                    n_truths=n_truths, progress=progress)
                for n, d in member_draws.items()}
    by_name = {n: {r["name"]: r for r in rk.rows} for n, rk in rankings.items()}
    told = discriminating_tests([member_draws[n].median_params() for n in names], candidates,
                                noise_sd=float(sigma), seed=seed)
    decided = {r["name"]: r for r in told.tests}
    rows = []
    for cand in candidates:
        per = [by_name[n][cand.name] for n in names]
        rows.append({
            "name": cand.name,
            "kind": cand.kind,
            "duration": cand.duration,
            "pairs_decided": int(decided[cand.name]["pairs_decided"]),
            "n_pairs": told.n_pairs,
            "information_gain": float(np.mean([r["information_gain"] for r in per])),
            "shrinkage": {p: float(np.mean([r["shrinkage"][p] for r in per])) for p in chosen},
            "members": {n: {"information_gain": r["information_gain"], "shrinkage": r["shrinkage"]}
                        for n, r in zip(names, per)},
        })
    return DesignRanking(rows=set_design_order(rows), params=tuple(chosen),
                         criterion=SET_DESIGN_CRITERION)


#: How :func:`design_over_set` orders the candidates.
SET_DESIGN_CRITERION = ("pairs of the set's members told apart (at their median models), then the "
                        "members' mean expected information gain (nats)")


def set_design_order(rows) -> list:
    """Rows of :func:`design_over_set` in its order: more pairs told apart first, then the larger
    mean gain."""
    return sorted(rows, key=lambda r: (-r["pairs_decided"], -r["information_gain"]))
