"""The checkpoint file of a calibration run: emcee's ``HDFBackend`` that waits out readers.

HDF5 locks a file while it is open. emcee reopens the backend's file for every step, so anyone
reading the checkpoint of a running chain (``h5ls``, a notebook, a monitoring script) made the
run die with ``BlockingIOError: unable to lock file``. The run can be resumed, but a checkpoint
must not be a way to lose a run: the writer retries instead.
"""
from __future__ import annotations

import errno
import time

from emcee.backends import HDFBackend

__all__ = ["CheckpointBackend", "H5_GROUP"]

#: The HDF5 group of a calibration's checkpoint that holds its own attributes beside emcee's chain
#: (set-up, discrepancy factors, chosen transients, the Laplace proposal, ...).
H5_GROUP = "tvcid"


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
