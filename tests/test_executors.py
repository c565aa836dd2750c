"""One executor interface for independent work (:mod:`tvcid.discovery.executors`).

The same seeded calls give the same results, in submission order, in this process, in two local
processes and on a Dask ``LocalCluster`` of two workers; the draw benchmarks' ``run_draws`` on
``--dask local:2`` records what it records locally; a bad ``--dask`` is one line naming what is
wrong. Closing a Dask executor, or killing its client, leaves no work running: a ``local:N``
cluster's worker processes end, and a task running on a cluster the executor did not start (a
"remote" one, here a ``LocalCluster`` of the test's) stops.

The Dask tests need the ``dask`` extra (``pip install tvcid[dask]``) and are skipped without it.
"""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tvcid.discovery.executors import LocalProcesses, executor_from

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
#: Out of order, so that submission order is not sorted order.
SEEDS = [5, 0, 3, 1, 4]
#: Seconds a stopped task or worker gets to be gone.
GONE_TIMEOUT = 15.0


def seeded_work(seed, n):
    """A draw in miniature: everything from ``default_rng(seed)``, then a little numpy."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(n)
    return float(np.sort(x).cumsum()[-1]), x[:3].tolist(), int(rng.integers(1 << 62))


def failing_work(seed, n):
    """:func:`seeded_work`, except that seed 3 raises."""
    if seed == 3:
        raise ValueError("draw 3 fails")
    return seeded_work(seed, n)


def tiny_draw(seed, out, quick):
    """A draw benchmark's ``draw(seed, out, quick)`` that costs nothing."""
    return {"seed": seed, "quick": quick, "out": str(out), "value": seeded_work(seed, 20)}


def looping(directory):
    """A minute of short sleeps (a draw returning to Python between its kernels); ``started`` and
    ``ended`` are written in ``directory`` as it starts and however it ends."""
    directory = Path(directory)
    (directory / "started").touch()
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            time.sleep(0.05)
        return "ran to its end"
    finally:
        (directory / "ended").touch()


def _expected():
    return [seeded_work(s, 50) for s in SEEDS]


def _completed(executor):
    """:meth:`completed` over ``SEEDS`` with the failing call, as ``{seed: result or error}``."""
    out = {}
    for i, value, error in executor.completed(failing_work, SEEDS, [50] * len(SEEDS)):
        out[SEEDS[i]] = repr(error) if error is not None else value
    return out


def _expected_completed():
    return {s: repr(ValueError("draw 3 fails")) if s == 3 else seeded_work(s, 50) for s in SEEDS}


def _wait_for(condition, timeout=GONE_TIMEOUT):
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.1)
    return condition()


def _running(pid):
    """Whether ``pid`` runs (a zombie does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in "ZX"


@pytest.mark.parametrize("jobs", [1, 2])
def test_local_processes_give_the_seeded_results_in_submission_order(jobs):
    with executor_from(jobs=jobs) as executor:
        assert isinstance(executor, LocalProcesses)
        assert list(executor.map(seeded_work, SEEDS, [50] * len(SEEDS))) == _expected()
        # a failed call is handed back as its error, the others still come
        assert _completed(executor) == _expected_completed()


def test_dask_local_cluster_gives_the_same_results_as_this_process():
    pytest.importorskip("distributed")
    with executor_from(dask="local:2") as executor:
        assert len(executor.client.scheduler_info()["workers"]) == 2
        assert list(executor.map(seeded_work, SEEDS, [50] * len(SEEDS))) == _expected()
        assert _completed(executor) == _expected_completed()
        with pytest.raises(ValueError, match="draw 3 fails"):  # map raises at its place
            list(executor.map(failing_work, SEEDS, [50] * len(SEEDS)))


def test_run_draws_on_dask_records_what_it_records_locally(tmp_path):
    pytest.importorskip("distributed")
    from tvcid.studies.benchmarks.draws import run_draws

    recorded = {}
    for where in ("inline", "processes", "dask"):
        rows = recorded[where] = []
        run_draws(tiny_draw, SEEDS, tmp_path, True, 2 if where == "processes" else 1,
                  lambda seed, row, rows=rows: rows.append((seed, row)),
                  dask="local:2" if where == "dask" else None)
    assert [seed for seed, _ in recorded["inline"]] == SEEDS
    assert recorded["dask"] == recorded["inline"] == recorded["processes"]


@pytest.mark.parametrize("args, says", [
    (["--dask", "nowhere"], "argument --dask: 'nowhere': not a Dask scheduler address"),
    (["--dask", "local:0"], "argument --dask: 'local:0': local:N needs N"),
    (["--jobs", "2", "--dask", "local:2"], "argument --dask: not allowed with argument --jobs"),
])
@pytest.mark.parametrize("bench", ["coverage", "discovery", "prediction"])
def test_bad_dask_option_is_one_line(bench, args, says, capsys):
    pytest.importorskip("distributed")  # the address is checked once Dask is there
    import importlib

    main = importlib.import_module(f"tvcid.studies.benchmarks.{bench}").main
    with pytest.raises(SystemExit) as stop:
        main(args)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert says in err[-1] and "Traceback" not in "\n".join(err)


def test_dask_without_dask_installed_names_the_extra(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed: ImportError
    from tvcid.studies.benchmarks.coverage import main

    with pytest.raises(SystemExit):
        main(["--dask", "local:2"])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.endswith("argument --dask: Dask's distributed scheduler is not installed: "
                         "pip install tvcid[dask]")
    with pytest.raises(ImportError, match=r"pip install tvcid\[dask\]"):
        executor_from(dask="tcp://localhost:8786")
    with pytest.raises(ValueError, match="one or the other"):
        executor_from(jobs=2, dask="local:2")


def test_closing_a_local_cluster_ends_its_workers_and_their_running_task(tmp_path):
    pytest.importorskip("distributed")
    executor = executor_from(dask="local:2")
    with executor:
        workers = list(executor.client.run(os.getpid).values())
        assert len(workers) == 2 and all(_running(p) for p in workers)
        executor.map(looping, [tmp_path])
        assert _wait_for(lambda: (tmp_path / "started").exists(), 30.0), "the task never started"
    # left the block with the task running: cancelled, the cluster closed
    assert _wait_for(lambda: not any(_running(p) for p in workers)), (
        f"workers {[p for p in workers if _running(p)]} outlived the executor")


@pytest.fixture(scope="module")
def remote_cluster():
    """A cluster the executors under test did not start: one worker process of one thread."""
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                       dashboard_address=None,
                                       scheduler_kwargs={"dashboard_address": ":0"})
    yield cluster
    cluster.close()


def _cluster_still_serves(address):
    with executor_from(dask=address) as executor:
        return list(executor.map(seeded_work, SEEDS, [50] * len(SEEDS))) == _expected()


def test_closing_the_client_stops_its_task_on_a_remote_worker(remote_cluster, tmp_path):
    """A Dask worker lets a cancelled task run to its end; the executor's tasks stop instead."""
    address = remote_cluster.scheduler_address
    with executor_from(dask=address) as executor:
        assert executor.cluster is None  # the executor closes its client only
        executor.map(looping, [tmp_path])
        assert _wait_for(lambda: (tmp_path / "started").exists(), 30.0), "the task never started"
    assert _wait_for(lambda: (tmp_path / "ended").exists()), "the task still runs"
    assert _cluster_still_serves(address)


#: A client that starts :func:`looping` on the cluster at argv[1] (a ``local:2`` of its own or a
#: remote one), prints its workers' pids once the task runs, and waits to be killed.
KILLED_CLIENT = """
import os, sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[3])
from test_executors import looping
from tvcid.discovery.executors import executor_from

executor = executor_from(dask=sys.argv[1])
executor.map(looping, [sys.argv[2]])
while not (Path(sys.argv[2]) / "started").exists():
    time.sleep(0.05)
print(" ".join(str(p) for p in executor.client.run(os.getpid).values()), flush=True)
time.sleep(120)
"""


def _kill_client(address, directory):
    """Start :data:`KILLED_CLIENT` on ``address``, SIGKILL it once its task runs; the pids of the
    workers it saw."""
    proc = subprocess.Popen([sys.executable, "-c", KILLED_CLIENT, address, str(directory),
                             str(TESTS)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        line = proc.stdout.readline()
        assert line.strip(), "the client ended before its task ran"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        return [int(p) for p in line.split()]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_killed_client_leaves_no_local_cluster_worker_running(tmp_path):
    pytest.importorskip("distributed")
    workers = _kill_client("local:2", tmp_path)
    try:
        assert len(workers) == 2
        assert _wait_for(lambda: not any(_running(p) for p in workers)), (
            f"workers {[p for p in workers if _running(p)]} outlived their killed client")
    finally:
        for pid in workers:  # a failed test leaves nothing behind
            if _running(pid):
                os.kill(pid, signal.SIGKILL)


def test_killed_client_leaves_no_task_running_on_a_remote_worker(remote_cluster, tmp_path):
    address = remote_cluster.scheduler_address
    _kill_client(address, tmp_path)
    assert _wait_for(lambda: (tmp_path / "ended").exists()), "the killed client's task still runs"
    assert _cluster_still_serves(address)
