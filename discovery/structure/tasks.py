"""The structure search's independent global searches as self-contained tasks of an executor.

:meth:`.structure_search.StructureSearch.search_classes` searches the largest structure of every
class; each search (:func:`fit_top`) draws from its own generator, seeded up front, and gets all
it needs as arguments: the targets, the search sizes, the structure's search space, its starts
and its seed. So it runs the same in this process (the default) or on a Dask worker
(:class:`tvcid.discovery.executors.DaskExecutor`), where its arguments and result travel pickled.

The targets pickle (their simulators hold arrays); an :class:`.search.Objective` does not (it
holds a lock), so each task builds its own around copies of the targets and hands back what it
spent (:class:`TopFit`), which :func:`fit_tops` adds to the search's objective and targets.
"""
from __future__ import annotations

import copy
import os
import time
from dataclasses import dataclass

import numpy as np

from ..threads import one_blas_thread
from .global_fit import GlobalFit
from .search import FitResult, Objective

__all__ = ["TopFit", "fit_top", "fit_tops"]


@dataclass
class TopFit:
    """What one global search found and spent.

    Attributes
    ----------
    fit : .search.FitResult
    evaluations : int
        Parameter sets simulated.
    simulated_seconds : float
        Seconds simulated (:attr:`.search.Objective.simulated_seconds`).
    simulated_steps : float
        Kernel steps of the same runs (:attr:`.search.Objective.simulated_steps`).
    cpu_seconds : float
        CPU seconds of the process that ran the search, while it ran.
    pid : int
        That process's id: a search run in another process adds its CPU seconds to the stage's.
    second_starts : list of int
        Runs each target simulated again from its second start (0 for an open-loop target).
    searches : dict
        Independent searches run per stage (``open_loop``, ``global``).
    open_loop_seconds : float
        Wall time of the open-loop stage (s).
    """

    fit: FitResult
    evaluations: int
    simulated_seconds: float
    second_starts: list
    searches: dict
    open_loop_seconds: float
    simulated_steps: float = 0.0
    cpu_seconds: float = 0.0
    pid: int = 0


def fit_top(targets, sizes, space, starts, seed, first=None, open_loop_only=False):
    """:meth:`.global_fit.GlobalFit.fit` of one structure, alone (or only its open-loop stage,
    :meth:`.global_fit.GlobalFit.fit_open_loop`).

    Parameters
    ----------
    targets : list
        Every recording's target (:mod:`.targets`); copied, so that the caller's counters move
        only by what :func:`fit_tops` adds.
    sizes : .structure_search.SearchSizes
    space : .coordinates.SearchSpace
        The structure's box.
    starts : list of ActuatorParams
        Starts placed in the first population.
    seed : int
        Seed of the search's generator.
    first : .search.FitResult, optional
        The open-loop stage's fit, where it has run already (the stage is not run again).
    open_loop_only : bool
        Run the open-loop stage alone: the fit is the open-loop recordings' optimum, its cost
        theirs alone.

    Returns
    -------
    TopFit
    """
    cpu0 = time.process_time()
    own = [copy.copy(t) for t in targets]
    for t in own:
        if hasattr(t, "second_starts"):
            t.second_starts = 0
    objective = Objective(own)
    search = GlobalFit(objective, sizes, np.random.default_rng(seed))
    with one_blas_thread():  # also on a worker: the kernels own its cores
        if open_loop_only:
            t0 = time.perf_counter()
            fit = search.fit_open_loop(space, [t for t in own if t.kind == "open"],
                                       [space.coordinates(p) for p in starts])
            search.open_loop_seconds += time.perf_counter() - t0
        else:
            fit = search.fit(space, starts, first=first)
    return TopFit(fit=fit, evaluations=objective.n_evaluations,
                  simulated_seconds=objective.simulated_seconds,
                  second_starts=[getattr(t, "second_starts", 0) for t in own],
                  searches=dict(search.searches), open_loop_seconds=search.open_loop_seconds,
                  simulated_steps=objective.simulated_steps,
                  cpu_seconds=time.process_time() - cpu0, pid=os.getpid())


def fit_tops(search, structures, starts, seeds, firsts=None, open_loop_only=False):
    """:func:`fit_top` of each of ``structures`` through ``search.executor``; yields each
    structure's :class:`.search.FitResult` in order, once its spending is added to ``search``
    (its objective's evaluations, simulated seconds and steps, its targets' second starts, its
    ``searches`` and ``open_loop_seconds``, and, where it ran in another process, its CPU
    seconds to ``worker_cpu_seconds``).

    Parameters
    ----------
    search : .structure_search.StructureSearch
    structures : list of Structure
    starts : list of list of ActuatorParams
        Each structure's starts.
    seeds : list of int
        Each structure's seed.
    firsts : list of .search.FitResult, optional
        Each structure's open-loop stage already run (:func:`fit_top`'s ``first``).
    open_loop_only : bool
        Each structure's open-loop stage alone.
    """
    from ..executors import LocalProcesses

    executor = search.executor if search.executor is not None else LocalProcesses(1)
    n = len(structures)
    targets = search.objective.targets
    done = executor.map(fit_top, [targets] * n, [search.sizes] * n,
                        [search.spaces[s] for s in structures], starts, seeds,
                        firsts if firsts is not None else [None] * n, [open_loop_only] * n)
    for result in done:
        objective = search.objective
        objective.n_evaluations += result.evaluations
        objective.simulated_seconds += result.simulated_seconds
        objective.simulated_steps += result.simulated_steps
        if result.pid != os.getpid():  # this process's clock did not see it
            search.worker_cpu_seconds += result.cpu_seconds
        for t, k in zip(targets, result.second_starts):
            if k:
                t.second_starts += k
        for stage, k in result.searches.items():
            counts = search.global_fit.searches
            counts[stage] = counts.get(stage, 0) + k
        search.global_fit.open_loop_seconds += result.open_loop_seconds
        yield result.fit
