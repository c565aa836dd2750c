"""Thread budget of the fitting stages: the simulation kernels own the cores, BLAS gets one thread.

The batch kernel (:func:`models.kernel.simulate_batch_kernel`) runs on every core through numba's
OpenMP layer, and the searches (:mod:`discovery.structure.search`) run recordings and refinements
in Python threads on top. The linear algebra between simulations is small (least squares on a
Jacobian of a few columns, 2 x 2 edge-timing systems), yet a multi-threaded OpenBLAS wakes its own
threads for it, and they spin against the kernel's: one structure's staged search on the speed
benchmark's four recordings took 69-70 s with OpenBLAS on 2 threads and 47 s on one (an A/B of
``/usr/bin/time``: 148 against 86 CPU seconds for the same work).
"""
from __future__ import annotations

from contextlib import contextmanager

__all__ = ["one_blas_thread"]


@contextmanager
def one_blas_thread():
    """Limit BLAS/LAPACK to one thread inside the block (``threadpoolctl``); restored after."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
