"""Fit one structure to all recordings at once: global search over the batch kernel, then refinement.

* :class:`Objective` -- the residuals of every recording's target (:mod:`.targets`) for a batch of
  parameter sets; one batch kernel call per recording simulates the whole batch on all cores.
* :func:`global_search` -- differential evolution (``scipy.optimize.differential_evolution``,
  vectorised: a whole population is one batch), its first population a Latin hypercube plus any
  seeds (SINDy's proposals, a nested structure's fit).
* :func:`refine` -- trust-region least squares (``scipy.optimize.least_squares``) with the
  finite-difference Jacobian computed as one batch.
* :func:`local_sd` -- Gauss-Newton spread of each coordinate at a fit: the change that raises the
  cost by one unit (a 1 % error); large values mark what the recordings do not decide.

Threads: the batch kernel releases the GIL, so the recordings of one evaluation are simulated
concurrently (a refinement's one-set batches otherwise keep one core busy), and so are the
refinements of a search's distinct candidates (:func:`refine_all`) and other independent tasks
(:func:`concurrent_map`), all through :func:`tvcid.discovery.threads.thread_map`.
:func:`progress_bar` is a bar such tasks may advance.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution, least_squares
from scipy.stats import qmc

from tvcid.discovery.threads import thread_map

__all__ = ["Objective", "FitResult", "global_search", "refine", "refine_all", "concurrent_map",
           "local_sd", "distinct_members", "progress_bar"]

#: Finite-difference step of the Jacobian in internal coordinates (0.2 % in the logs).
FD_STEP = 2e-3
#: Threads simulating recordings concurrently, and refinements (or tasks) run concurrently
#: (separate pools: a task waits on its refinements, a refinement on its recordings).
TARGET_THREADS = 4
REFINE_THREADS = 3


class Objective:
    """Residuals of a batch of parameter sets on a set of targets (one per recording).

    Parameters
    ----------
    targets : list
        :class:`.targets.CycleTarget` / :class:`.targets.OutputTarget` objects.

    Attributes
    ----------
    n_evaluations : int
        Parameter sets evaluated so far.
    simulated_seconds : float
        Seconds simulated so far: each valid set runs each target asked for over that target's
        run length (settling and window of a limit cycle, the whole record in open loop), and
        again where a limit cycle is simulated from its second start.
    simulated_steps : float
        Kernel steps of the same runs, each run's ``t_end / dt`` of the simulator it used (as
        :attr:`tvcid.discovery.calibration.log_posterior.LogPosterior.simulated_steps` counts them).
    """

    def __init__(self, targets):
        self.targets = list(targets)
        self.n_evaluations = 0
        self.simulated_seconds = 0.0
        self.simulated_steps = 0.0
        self._lock = threading.Lock()
        self._coarse = None

    def coarse(self, targets=None):
        """The coarse counterparts (:meth:`.targets.CycleTarget.coarse`) of ``targets`` (all by
        default), each made once: what a differential evolution screens its population on."""
        with self._lock:
            if self._coarse is None:
                self._coarse = {id(t): t.coarse() for t in self.targets}
        return [self._coarse[id(t)] for t in (targets or self.targets)]

    def _sets_for(self, target, param_sets):
        if target.initial_conditions() is None:
            return param_sets
        return [None if p is None else p.replace(**target.initial_conditions(p)) for p in param_sets]

    def blocks(self, param_sets, targets=None):
        """Residual blocks ``[(n, m_i)]``, one per target; invalid sets get penalty rows."""
        from .targets import PENALTY

        targets = targets or self.targets
        n_valid = sum(p is not None for p in param_sets)
        with self._lock:
            self.n_evaluations += n_valid
            for t in targets:
                self._count(t, n_valid)

        def block(target):
            sets = self._sets_for(target, param_sets)
            r, again = target.residuals_counted(sets)
            if again:
                with self._lock:
                    self._count(target, again)
            bad = np.array([p is None for p in sets])
            if bad.any():
                r[bad] = PENALTY / math.sqrt(r.shape[1])
            return r

        return thread_map("targets", TARGET_THREADS, block, targets)

    def _count(self, target, n_runs):
        """Count ``n_runs`` runs of ``target``'s simulator (the caller holds the lock)."""
        t_end, dt = float(target.simulator.t_end), float(target.simulator.dt)
        self.simulated_seconds += n_runs * t_end
        self.simulated_steps += n_runs * t_end / dt

    def costs(self, param_sets, targets=None):
        """Cost per target, ``(n, n_targets)``: sum of squared residuals (one unit ~ 1 % error)."""
        return np.column_stack([np.sum(b * b, axis=1) for b in self.blocks(param_sets, targets)])

    def residuals(self, param_sets, targets=None):
        return np.concatenate(self.blocks(param_sets, targets), axis=1)

    def offsets(self, params):
        """Profiled sensor offset of every recording at ``params`` (rad)."""
        return {t.name: float(t.offset(self._sets_for(t, [params]))[0]) for t in self.targets}


@dataclass
class FitResult:
    """A structure fitted to recordings.

    Attributes
    ----------
    theta : ndarray
        Search coordinates at the optimum.
    cost : float
        Sum over recordings of the squared residuals.
    cost_by_target : ndarray
    evaluations : int
        Parameter sets simulated.
    restarts : int
        Independent searches this fit is the best of
        (:func:`.global_fit.best_of_restarts`).
    start_cost_by_target : ndarray or None
        A refinement's cost per target at its start (:func:`refine`).
    """

    theta: np.ndarray
    cost: float
    cost_by_target: np.ndarray
    evaluations: int
    restarts: int = 1
    start_cost_by_target: np.ndarray | None = None


def _batch_cost(space, objective, thetas, targets=None):
    sets = [space.params(th) for th in thetas]
    return objective.costs(sets, targets)


def global_search(space, objective, rng, seeds=(), popsize=8, maxiter=40, targets=None):
    """Differential evolution over the structure's box; returns a :class:`FitResult`.

    Parameters
    ----------
    space : .coordinates.SearchSpace
    objective : Objective
    rng : numpy.random.Generator
    seeds : sequence of ndarray
        Coordinate vectors placed in the first population.
    popsize : int
        Population per coordinate (scipy's convention).
    maxiter : int
        Generations.
    """
    n0 = objective.n_evaluations
    lo, hi = space.low, space.high
    n_pop = max(popsize * space.ndim, 12)
    sampler = qmc.LatinHypercube(d=space.ndim, seed=rng)
    init = lo + sampler.random(n_pop) * (hi - lo)
    for i, s in enumerate(list(seeds)[: n_pop // 3]):
        init[i] = np.clip(s, lo, hi)

    def fun(x):  # x: (ndim, S)
        return _batch_cost(space, objective, x.T, targets).sum(axis=1)

    res = differential_evolution(
        fun, space.bounds(), init=init, maxiter=maxiter, vectorized=True, updating="deferred",
        polish=False, tol=1e-3, mutation=(0.5, 1.0), recombination=0.8,
        seed=np.random.default_rng(rng.integers(2**32)),
    )
    cbt = _batch_cost(space, objective, [res.x], targets)[0]
    out = FitResult(np.asarray(res.x), float(cbt.sum()), cbt, objective.n_evaluations - n0)
    out.population = np.asarray(res.population)
    out.population_costs = np.asarray(res.population_energies)
    return out


def distinct_members(population, costs, space, n, min_distance=0.1):
    """The ``n`` best members of a final population that lie apart from each other.

    Distance in coordinates scaled by the box (``min_distance`` of its width): a population that
    has not collapsed onto one basin keeps its runners-up, which local refinement may turn into
    a better optimum than the best member's.
    """
    width = np.where(space.high > space.low, space.high - space.low, 1.0)
    chosen = []
    for i in np.argsort(costs):
        x = (population[i] - space.low) / width
        if all(np.max(np.abs(x - (c - space.low) / width)) >= min_distance for c in chosen):
            chosen.append(population[i])
        if len(chosen) == n:
            break
    return chosen


def refine(space, objective, theta0, max_nfev=40, targets=None):
    """Trust-region least squares from ``theta0`` (batched finite-difference Jacobian)."""
    lo, hi = space.low, space.high
    theta0 = np.clip(np.asarray(theta0, dtype=float), lo, hi)
    cache = {}
    count = [2]  # the two costs below; not read off the objective, which refinements share

    def fun(th):
        key = th.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = objective.residuals([space.params(th)], targets)[0]
            count[0] += 1
        return cache[key]

    def jac(th):
        # asked only at accepted points: a rejected trial step costs one simulation, not ndim + 1
        r0 = fun(th)
        steps = np.where(th + FD_STEP <= hi, FD_STEP, -FD_STEP)
        r = objective.residuals([space.params(p) for p in th + np.diag(steps)], targets)
        count[0] += len(steps)
        return (r - r0).T / steps

    res = least_squares(fun, theta0, jac=jac, bounds=(lo, hi), method="trf", x_scale=1.0,
                        max_nfev=max_nfev, xtol=1e-6, ftol=1e-6)
    theta = np.clip(res.x, lo, hi)
    cbt = _batch_cost(space, objective, [theta], targets)[0]
    start = _batch_cost(space, objective, [theta0], targets)[0]
    if start.sum() < cbt.sum():  # least_squares never worsens, but the penalty plateaus can
        theta, cbt = theta0, start
    return FitResult(theta, float(cbt.sum()), cbt, count[0], start_cost_by_target=start)


def refine_all(space, objective, starts, max_nfev=40, targets=None):
    """:func:`refine` from each of ``starts`` (run concurrently); the fits in the same order."""
    return thread_map("refine", REFINE_THREADS,
                      lambda s: refine(space, objective, s, max_nfev=max_nfev, targets=targets),
                      starts)


def concurrent_map(fn, items):
    """``[fn(x) for x in items]`` with the calls run concurrently, results in order.

    For independent, deterministic tasks (a refinement per structure): the result is the loop's.
    ``fn`` may call :func:`refine_all` and the objective (their own threads), not this function.
    """
    return thread_map("tasks", REFINE_THREADS, fn, items)


def progress_bar(work, desc, enabled):
    """A tqdm bar, silent unless ``enabled``: over ``work`` when it is a sequence, else of
    ``work`` steps that concurrent tasks advance (tqdm's ``update`` holds a lock)."""
    from tqdm.auto import tqdm

    if isinstance(work, int):
        return tqdm(total=work, desc=desc, leave=False, disable=not enabled)
    return tqdm(work, desc=desc, leave=False, disable=not enabled)


def local_sd(space, objective, theta, targets=None):
    """Gauss-Newton spread of each coordinate at ``theta`` (change raising the cost by one unit).

    ``inf`` along directions the recordings do not determine at all.
    """
    hi = space.high
    steps = np.where(theta + FD_STEP <= hi, FD_STEP, -FD_STEP)
    pts = np.vstack([theta, theta + np.diag(steps)])
    r = objective.residuals([space.params(p) for p in pts], targets)
    jac = (r[1:] - r[0]).T / steps
    info = jac.T @ jac
    try:
        cov = np.linalg.pinv(info, rcond=1e-12)
    except np.linalg.LinAlgError:
        return np.full(space.ndim, math.inf)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sd[np.diag(info) <= 0] = math.inf
    return sd
