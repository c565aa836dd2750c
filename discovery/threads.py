"""Thread budget of the fitting stages: the simulation kernels own the cores, BLAS gets one thread,
and independent simulations run in Python threads on top (:func:`thread_map`).

The batch kernel (:func:`tvcid.models.kernel.simulate_batch_kernel`) runs on every core through numba's
OpenMP layer, and the searches (:mod:`tvcid.discovery.structure.search`) run recordings and refinements
in Python threads on top. The linear algebra between simulations is small (least squares on a
Jacobian of a few columns, 2 x 2 edge-timing systems), yet a multi-threaded OpenBLAS wakes its own
threads for it, and they spin against the kernel's: one structure's staged search on the speed
benchmark's four recordings took 69-70 s with OpenBLAS on 2 threads and 47 s on one (an A/B of
``/usr/bin/time``: 148 against 86 CPU seconds for the same work).

The kernel releases the GIL and numba's OpenMP layer accepts calls from several threads, so
simulations of different recordings can run at once: the search's recordings and refinements
(:mod:`tvcid.discovery.structure.search`) and the calibration's likelihood terms
(:class:`tvcid.discovery.calibration.log_posterior.LogPosterior`). Every evaluation is deterministic and
the results are combined in order, so they do not depend on the threads' order
(``tests/test_threads.py``).

Interruptions: Ctrl-C reaches the main thread alone, and a pool's thread runs its task to its end
whatever happens to the caller (the interpreter waits for it at exit), so a stage whose tasks
last minutes would ignore Ctrl-C. The tasks of one :func:`thread_map` call, and those they start
in turn, share a stop event: a thread interrupted while it waits for them (KeyboardInterrupt,
SIGTERM raised as one, a cancelled Dask task) sets it, cancels the tasks not started and waits
for the running ones, which raise :class:`Stopped` at their next :func:`thread_map` (every batch
of simulations starts one: :meth:`tvcid.discovery.structure.search.Objective.blocks`,
:class:`tvcid.discovery.calibration.log_posterior.LogPosterior`). The event is that call's alone:
a later call, in the same process, starts afresh.
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import contextmanager

__all__ = ["one_blas_thread", "thread_map", "check_stop", "Stopped", "THREADED"]

#: ``False`` runs every :func:`thread_map` as a plain loop (the tests compare both).
THREADED = True
_pools = {}
_pools_lock = threading.Lock()
#: ``stop``: the stop event of the :func:`thread_map` call whose task this thread runs.
_task_state = threading.local()


class Stopped(KeyboardInterrupt):
    """Raised in a pool's task whose caller was interrupted: the task ends at its next
    :func:`thread_map` instead of running to its end. A KeyboardInterrupt, so that no
    ``except Exception`` takes it for the task's failure."""


def check_stop():
    """Raise :class:`Stopped` if the :func:`thread_map` call whose task this thread runs was
    interrupted; a no-op elsewhere (the main thread gets Ctrl-C itself)."""
    stop = getattr(_task_state, "stop", None)
    if stop is not None and stop.is_set():
        raise Stopped("the caller was interrupted")


def _task(stop, fn, x):
    """``fn(x)`` in a pool's thread, under ``stop``: the tasks it starts share it."""
    outer = getattr(_task_state, "stop", None)
    _task_state.stop = stop
    try:
        check_stop()  # taken from the queue after the interruption
        return fn(x)
    finally:
        _task_state.stop = outer


def thread_map(name, workers, fn, items):
    """``[fn(x) for x in items]``, in pool ``name``'s ``workers`` threads when :data:`THREADED`
    (one pool per name: a task waiting on another pool's tasks cannot starve it).

    The results are in order and the first call that raises, in order, raises here. Interrupted
    while it waits (any exception that is not an :class:`Exception`), it stops the calls: those
    not started never start, the running ones raise :class:`Stopped` at their next
    :func:`thread_map`, and it returns (raising the interruption) once they have ended.
    """
    items = list(items)
    check_stop()
    if not THREADED or len(items) <= 1:
        return [fn(x) for x in items]
    with _pools_lock:
        if name not in _pools:
            _pools[name] = ThreadPoolExecutor(workers, thread_name_prefix=f"tvcid-{name}")
        pool = _pools[name]
    # a task's own calls share its event: one interruption stops the whole tree of tasks
    stop = getattr(_task_state, "stop", None) or threading.Event()
    futures = []
    try:
        for x in items:
            futures.append(pool.submit(_task, stop, fn, x))
        return [f.result() for f in futures]
    except BaseException as exc:
        interrupted = not isinstance(exc, Exception)
        if interrupted:
            stop.set()
        for f in futures:  # as Executor.map does: the calls not started are not wanted
            f.cancel()
        if interrupted:
            # the running calls end at their next batch of simulations; a second Ctrl-C here
            # leaves at once
            wait(futures)
        raise


@contextmanager
def one_blas_thread():
    """Limit BLAS/LAPACK to one thread inside the block (``threadpoolctl``); restored after."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
