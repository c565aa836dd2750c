"""The checkpoint file survives a reader: a process holding chain.h5 open does not kill the run."""
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest
from emcee.backends import HDFBackend

from tvcid.discovery.calibration import CheckpointBackend

HOLD = 1.0  # seconds the reader keeps the file open


def _hold_open(path):
    """A separate process that opens ``path`` read-only and keeps it open for HOLD seconds."""
    code = (f"import h5py, time; f = h5py.File({str(path)!r}, 'r'); print('open', flush=True); "
            f"time.sleep({HOLD}); f.close()")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "open"
    return proc


@pytest.fixture
def chain_file(tmp_path):
    path = tmp_path / "chain.h5"
    backend = CheckpointBackend(str(path))
    backend.reset(4, 2)
    return path


def test_plain_hdf_backend_dies_while_a_reader_holds_the_file(chain_file):
    reader = _hold_open(chain_file)
    try:
        with pytest.raises(OSError, match="lock"):
            HDFBackend(str(chain_file)).open("a")
    finally:
        reader.wait()


def test_checkpoint_backend_waits_for_the_reader_and_writes(chain_file):
    reader = _hold_open(chain_file)
    t0 = time.monotonic()
    backend = CheckpointBackend(str(chain_file))
    with backend.open("a") as f:
        f["mcmc"].attrs["written"] = 1
    waited = time.monotonic() - t0
    reader.wait()
    assert 0.2 * HOLD < waited < 10 * HOLD
    with h5py.File(chain_file, "r") as f:
        assert f["mcmc"].attrs["written"] == 1
    assert backend.shape == (4, 2) and np.isfinite(backend.iteration)


def test_checkpoint_backend_gives_up_after_its_timeout(chain_file):
    reader = _hold_open(chain_file)
    try:
        with pytest.raises(OSError, match="lock"):
            CheckpointBackend(str(chain_file), lock_timeout=0.1).open("a")
    finally:
        reader.wait()
