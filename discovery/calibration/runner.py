"""The sampling core: an emcee ensemble run to convergence, checkpointed and resumable.

Small on purpose, following emcee's design: any log-probability (vectorised or not), any emcee
moves, any backend, any pool (an object with ``.map``). :func:`run_ensemble` adds four things to
``EnsembleSampler.run_mcmc``:

* reproducibility from one seed: the initial positions and the sampler's ``RandomState`` are drawn
  from one ``numpy.random.Generator(seed)``; on resume emcee restores the ``RandomState`` the
  backend saved with the last step, so a run killed and resumed gives the same chain as one run
  straight through;
* checkpoints: with an ``HDFBackend`` every step is written as it is taken;
* a stopping rule: the run stops once ``N > tau_factor * tau`` for every parameter (integrated
  autocorrelation time, checked every ``check_every`` steps at absolute step counts, so an
  interrupted run checks at the same steps as an uninterrupted one), on the whole chain or on its
  second half alone (:func:`convergence_report`), or at ``max_steps`` with a
  :class:`ConvergenceWarning`;
* a pool that maps *batches*: with ``vectorize=True`` and a pool, the walkers are split into one
  batch per pool worker and each batch goes through the vectorised log-probability (the batch
  kernel) on its worker.
"""
from __future__ import annotations

import contextlib
import math
import signal
import threading
import warnings
from dataclasses import asdict, dataclass

import emcee
import numpy as np

__all__ = [
    "ConvergenceWarning",
    "ConvergenceReport",
    "default_moves",
    "run_ensemble",
    "convergence_report",
    "PooledLogProb",
]


class ConvergenceWarning(UserWarning):
    """The chain stopped at the step cap before ``N > tau_factor * tau``."""


@dataclass(frozen=True)
class ConvergenceReport:
    """Convergence diagnostics of an ensemble run.

    Attributes
    ----------
    iterations : int
        Steps in the chain (all of them, resumed ones included).
    tau : tuple of float
        Integrated autocorrelation time per parameter (steps), of the steps the test kept.
    n_over_tau : float
        Steps kept over ``max(tau)``.
    tau_factor : float
        The ``N > tau_factor * tau`` criterion.
    converged : bool
    acceptance : float
        Mean acceptance fraction over the walkers.
    new_steps : int
        Steps taken by this call (0 when a finished run is reopened).
    wall_time : float
        Seconds spent sampling in this call.
    burn : int
        Steps the test left out: 0, or the first half of the chain when only the second half
        passes (the posterior's samples then start after it).
    """

    iterations: int
    tau: tuple
    n_over_tau: float
    tau_factor: float
    converged: bool
    acceptance: float
    new_steps: int = 0
    wall_time: float = 0.0
    burn: int = 0

    def to_dict(self):
        d = asdict(self)
        d["tau"] = [float(t) for t in self.tau]
        return d


def default_moves():
    """Differential-evolution moves (80 % DEMove, 20 % DESnookerMove): they follow the narrow,
    strongly correlated valleys of a limit-cycle fit far better than the stretch move."""
    return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]


class PooledLogProb:
    """A vectorised log-probability whose batch is split over ``pool.map``.

    Picklable as long as ``log_prob`` is; ``pool`` is any object with ``.map`` (multiprocessing,
    ``concurrent.futures`` executors, mpi4py / schwimmbad / Dask pools).
    """

    def __init__(self, log_prob, pool, n_chunks=None):
        self.log_prob = log_prob
        self.pool = pool
        self.n_chunks = n_chunks

    def __call__(self, coords):
        coords = np.atleast_2d(coords)
        n_chunks = self.n_chunks or getattr(self.pool, "_processes", None) or 2
        chunks = [c for c in np.array_split(coords, min(n_chunks, len(coords))) if len(c)]
        parts = list(self.pool.map(self.log_prob, chunks))
        return np.concatenate([np.atleast_1d(p) for p in parts])


def convergence_report(sampler, tau_factor=50.0, new_steps=0, wall_time=0.0) -> ConvergenceReport:
    """``N > tau_factor * tau`` on the whole chain, or else on its second half alone, with tau
    at least one step.

    The walkers' way in from their start (a maximum a posteriori a few sd off the bulk, a spread
    along a ridge) is a trend that the autocorrelation estimate reads as slow mixing for the whole
    run. The second half alone is the chain with the first half taken as burn-in (emcee's advice:
    estimate tau after discarding it); a stationary chain passes on the whole first.
    """
    it = int(sampler.iteration)
    ndim = sampler.ndim
    burn = 0
    if it < 2:
        tau = np.full(ndim, np.inf)
    else:
        tau = _autocorr_time(sampler, 0)
    ok = _passes(tau, it, tau_factor)
    if not ok and it >= 4:
        half = _autocorr_time(sampler, it // 2)
        if _passes(half, it - it // 2, tau_factor):
            ok, tau, burn = True, half, it // 2
    tmax = float(np.max(tau)) if tau.size else math.inf
    acc = float(np.mean(sampler.acceptance_fraction)) if it > 0 else 0.0
    kept = it - burn
    return ConvergenceReport(
        iterations=it,
        tau=tuple(float(t) for t in tau),
        n_over_tau=float(kept / tmax) if tmax > 0 and math.isfinite(tmax) else 0.0,
        tau_factor=float(tau_factor),
        converged=ok,
        acceptance=acc,
        new_steps=int(new_steps),
        wall_time=float(wall_time),
        burn=int(burn),
    )


def _autocorr_time(sampler, discard):
    # a parameter no walker has moved yet has a zero autocovariance: NaN (not passed), no warning
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(sampler.get_autocorr_time(discard=discard, tol=0, quiet=True), dtype=float)


def _passes(tau, steps, tau_factor) -> bool:
    # tau is floored at one step: independent draws have tau 1, and a short chain's estimate
    # below it would call 10 steps converged
    return bool(tau.size and np.all(np.isfinite(tau))
                and steps > tau_factor * max(float(np.max(tau)), 1.0))


@contextlib.contextmanager
def deferred_interrupts():
    """SIGINT (Ctrl-C) and SIGTERM set ``flag["signal"]`` instead of interrupting at once.

    emcee's likelihood wrapper prints a traceback for any exception raised inside the likelihood,
    an interruption included; deferred, the sampling loop stops between steps, after the step's
    checkpoint. A second signal interrupts at once. Only in the main thread (elsewhere a no-op).
    """
    flag = {"signal": None}
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def defer(signum, frame):
        if flag["signal"] is not None:
            raise KeyboardInterrupt("interrupted twice")
        flag["signal"] = signum

    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s in previous:
        signal.signal(s, defer)
    try:
        yield flag
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)


def run_ensemble(
    log_prob,
    initial,
    n_walkers,
    ndim,
    max_steps,
    seed=0,
    backend=None,
    moves=None,
    pool=None,
    vectorize=True,
    check_every=100,
    tau_factor=50.0,
    progress=False,
    stop_when_converged=True,
    warn=True,
    after_chunk=None,
):
    """Run (or resume) an ensemble until ``N > tau_factor * tau`` or ``max_steps``.

    Parameters
    ----------
    log_prob : callable
        ``log_prob(coords)``: with ``vectorize=True`` coords is ``(n, ndim)`` and the result
        ``(n,)``; otherwise one point at a time.
    initial : callable or array
        ``initial(rng) -> (n_walkers, ndim)`` or the positions themselves; used only when the
        backend holds no step yet.
    n_walkers, ndim : int
    max_steps : int
        Step cap of the whole chain (resumed steps count).
    seed : int
        Seed of the ``numpy.random.Generator`` behind the initial positions and emcee's
        ``RandomState``.
    backend : emcee.backends.Backend or None
        ``emcee.backends.HDFBackend(path)`` to checkpoint and resume.
    moves : emcee moves or None
        :func:`default_moves` when ``None``.
    pool : object with ``.map`` or None
    vectorize : bool
    check_every : int
        Steps between convergence checks.
    tau_factor : float
    progress : bool
        emcee's tqdm progress bar.
    stop_when_converged : bool
        False runs to ``max_steps`` whatever the diagnostics (e.g. to map a ridge).
    after_chunk : callable or None
        ``after_chunk(sampler)`` after every chunk of ``check_every`` steps (at absolute step
        counts, so a resumed run calls it where an uninterrupted one would), before the
        convergence check: e.g. a one-off adaptation of a move's proposal.

    Returns
    -------
    sampler : emcee.EnsembleSampler
    report : ConvergenceReport
    """
    import time

    n_walkers, ndim, max_steps = int(n_walkers), int(ndim), int(max_steps)
    check_every = max(1, int(check_every))
    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1 (got {max_steps})")
    fn = log_prob
    emcee_pool = None
    if pool is not None:
        if not hasattr(pool, "map"):
            raise TypeError(f"pool must have a .map method (got {type(pool).__name__})")
        if vectorize:
            fn = PooledLogProb(log_prob, pool)
        else:
            emcee_pool = pool
    sampler = emcee.EnsembleSampler(
        n_walkers, ndim, fn, moves=moves if moves is not None else default_moves(),
        backend=backend, vectorize=vectorize, pool=emcee_pool,
    )
    rng = np.random.default_rng(seed)
    state = None
    if sampler.iteration == 0:
        p0 = initial(rng) if callable(initial) else np.asarray(initial, dtype=float)
        if p0.shape != (n_walkers, ndim):
            raise ValueError(f"initial positions have shape {p0.shape}, expected {(n_walkers, ndim)}")
        state = emcee.State(p0, random_state=np.random.RandomState(
            int(rng.integers(0, 2**32 - 1))).get_state())
        sampler.random_state = state.random_state
    start_it = sampler.iteration
    t0 = time.perf_counter()
    report = convergence_report(sampler, tau_factor)
    # one deferred scope over all chunks: a signal during a chunk's last step (or between
    # chunks) is not lost when the chunk ends
    with deferred_interrupts() as interrupt:
        while sampler.iteration < max_steps:
            if stop_when_converged and report.converged:
                break
            it = sampler.iteration
            n = min(check_every - it % check_every, max_steps - it)
            # emcee's run_mcmc, step by step: an interruption waits for the step's checkpoint
            last = state if state is not None else sampler._previous_state
            for last in sampler.sample(last, iterations=n, progress=progress, progress_kwargs={
                    "desc": f"steps {it}-{it + n} of <= {max_steps}"}):
                if interrupt["signal"] is not None:
                    sampler._previous_state = last
                    raise KeyboardInterrupt(f"interrupted after step {sampler.iteration}")
            sampler._previous_state = last
            state = None  # continue from the sampler's (or backend's) last state
            if after_chunk is not None:
                after_chunk(sampler)
            report = convergence_report(sampler, tau_factor)
        if interrupt["signal"] is not None:
            raise KeyboardInterrupt(f"interrupted after step {sampler.iteration}")
    report = convergence_report(
        sampler, tau_factor, new_steps=sampler.iteration - start_it,
        wall_time=time.perf_counter() - t0,
    )
    if warn and not report.converged:
        warnings.warn(
            f"NOT CONVERGED: {report.iterations} steps = {report.n_over_tau:.1f} tau "
            f"(needs > {tau_factor:g} tau; tau = {', '.join(f'{t:.0f}' for t in report.tau)}); "
            "raise max_steps and run again on the same backend to continue",
            ConvergenceWarning,
            stacklevel=2,
        )
    return sampler, report
