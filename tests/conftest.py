"""Shared fixtures, one numba thread per test worker, and the order in which files are handed out."""
import functools
import os

# Set before numba and numpy are imported: two xdist workers on two cores, each with numba's and
# OpenBLAS's default of one thread per core, would run four threads on two cores (and OpenBLAS's
# spin against the kernel's: discovery/threads.py).
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402

from tvcid.models import CONTROLLER_A, hypothesis, simulate  # noqa: E402

#: Seconds each of the default suite's longest files takes on one worker (from ``--durations``).
#: Files are handed out longest first, so that no long file starts last and runs alone at the
#: end; a file missing here is handed out after these, in collection order.
FILE_SECONDS = {
    "test_studies.py": 200,
    "test_discover.py": 145,
    "test_discover_add.py": 75,
    "test_calibration_recovery.py": 70,
    "test_discover_dask.py": 58,
    "test_no_orphans.py": 46,
    "test_interrupt.py": 45,
    "test_kernel_vs_reference.py": 44,
    "test_describing_controllers.py": 43,
    "test_calibration_mismatch.py": 42,
    "test_prediction.py": 35,
    "test_controllers.py": 31,
    "test_calibration_core.py": 31,
    "test_bad_input_cli.py": 30,
    "test_step_error.py": 28,
    "test_calibration_start.py": 27,
    "test_discrimination.py": 27,
}


@functools.lru_cache(maxsize=None)
def _cycle(name, t_end=40.0, dt=2e-4, **overrides):
    return simulate(hypothesis(name, **overrides), CONTROLLER_A, t_end, dt=dt)


@pytest.fixture(scope="session")
def cycle_at_a():
    """``cycle_at_a(name, **overrides)``: a 40 s controller-A run (cached), for features."""

    def get(name, **overrides):
        return _cycle(name, **overrides)

    return get


def pytest_collection_modifyitems(session, config, items):
    """Collect the files of :data:`FILE_SECONDS` first, longest first (a stable sort: tests keep
    their order within a file).

    With ``--dist loadfile --no-loadscope-reorder`` xdist hands out whole files in collection
    order: one to each worker at the start, then the next file to a worker as soon as it has at
    most two tests of its files left to run. Handing out the longest files first lets the short
    ones fill in behind them.
    """
    items.sort(key=lambda item: -FILE_SECONDS.get(item.path.name, 0))
