"""The checkpoint file of a calibration run: emcee's ``HDFBackend`` that waits out readers.

HDF5 locks a file while it is open. emcee reopens the backend's file for every step, so anyone
reading the checkpoint of a running chain (``h5ls``, a notebook, a monitoring script) made the
run die with ``BlockingIOError: unable to lock file``. The run can be resumed, but a checkpoint
must not be a way to lose a run: the writer retries instead.
"""
from __future__ import annotations

import errno
import time

import numpy as np
from emcee.backends import HDFBackend

__all__ = ["CheckpointBackend", "H5_GROUP", "read_weighted_posterior", "store_weighted_posterior"]

#: The HDF5 group of a calibration's checkpoint that holds its own attributes beside emcee's chain
#: (set-up, discrepancy factors, chosen transients, the Laplace proposal, ...).
H5_GROUP = "tvcid"
#: Its subgroup holding a posterior of weighted points (an importance or nested run adopted
#: without a chain): ``points`` (sampling coordinates) and ``weights``.
WEIGHTED_GROUP = "weighted_posterior"


class CheckpointBackend(HDFBackend):
    """``emcee.backends.HDFBackend`` whose opens retry while another process holds the lock.

    Parameters
    ----------
    filename : str
        The HDF5 file.
    lock_timeout : float
        Seconds to keep retrying a locked file before raising (default 60).
    **kwargs
        Passed to ``HDFBackend`` (``name``, ``read_only``, ...).
    """

    def __init__(self, filename, lock_timeout=60.0, **kwargs):
        super().__init__(filename, **kwargs)
        self.lock_timeout = lock_timeout

    def open(self, mode="r"):
        deadline = time.monotonic() + self.lock_timeout
        delay = 0.005
        while True:
            try:
                return super().open(mode)
            except OSError as exc:  # BlockingIOError is an OSError with errno EAGAIN
                locked = exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK) or "lock" in str(exc)
                if not locked or time.monotonic() > deadline:
                    raise
                time.sleep(delay)
                delay = min(2 * delay, 0.2)


def store_weighted_posterior(backend, points, weights) -> None:
    """Keep an adopted run's weighted ``points`` (sampling coordinates) in the checkpoint of
    ``backend`` (a :class:`CheckpointBackend`), where a chain would be: what reads a member's
    posterior from its file (:func:`tvcid.discovery.prediction.draws.load_chain_draws`) needs
    it when no chain follows."""
    with backend.open("a") as f:
        g = f.require_group(H5_GROUP)
        if WEIGHTED_GROUP in g:
            del g[WEIGHTED_GROUP]
        w = g.create_group(WEIGHTED_GROUP)
        w.create_dataset("points", data=np.asarray(points, dtype=float))
        w.create_dataset("weights", data=np.asarray(weights, dtype=float))


def read_weighted_posterior(f):
    """``(points, weights)`` of an open checkpoint ``f`` (:func:`store_weighted_posterior`), or
    ``None`` where it holds none."""
    if H5_GROUP not in f or WEIGHTED_GROUP not in f[H5_GROUP]:
        return None
    g = f[H5_GROUP][WEIGHTED_GROUP]
    return g["points"][()], g["weights"][()]
