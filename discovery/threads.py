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
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

__all__ = ["one_blas_thread", "thread_map", "THREADED"]

#: ``False`` runs every :func:`thread_map` as a plain loop (the tests compare both).
THREADED = True
_pools = {}
_pools_lock = threading.Lock()


def thread_map(name, workers, fn, items):
    """``[fn(x) for x in items]``, in pool ``name``'s ``workers`` threads when :data:`THREADED`
    (one pool per name: a task waiting on another pool's tasks cannot starve it)."""
    items = list(items)
    if not THREADED or len(items) <= 1:
        return [fn(x) for x in items]
    with _pools_lock:
        if name not in _pools:
            _pools[name] = ThreadPoolExecutor(workers, thread_name_prefix=f"tvcid-{name}")
    return list(_pools[name].map(fn, items))


@contextmanager
def one_blas_thread():
    """Limit BLAS/LAPACK to one thread inside the block (``threadpoolctl``); restored after."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
