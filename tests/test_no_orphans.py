"""No worker process outlives the command that started it.

A command running a process pool (``python -m tvcid.studies.benchmarks.coverage --jobs``, ``tvcid fit
--processes``, ``tvcid study all --jobs``) sent SIGTERM, or Ctrl-C (SIGINT to its whole process
group, workers included), stops its workers and waits for them before it exits with status 130
and one line on stderr; killed outright (SIGKILL), it leaves workers that notice and end by
themselves.

Each test starts the real command with two workers as a subprocess in a session of its own, waits
until they are at work, signals the command, and reads ``/proc`` for the processes it had started.
"""
import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sigkill import CLI

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "data" / "m000_closed_A.csv"
#: Seconds a command gets to put both workers to work (a few on an idle machine).
READY_TIMEOUT = 90.0
#: Seconds a signalled command gets to exit (its workers get 3 s to end before they are killed).
EXIT_TIMEOUT = 30.0
#: Seconds orphaned workers get to notice that their parent is gone (they poll every 0.5 s).
ORPHAN_TIMEOUT = 10.0


def _stat(pid):
    """``(state, ppid, start time, cpu seconds)`` of process ``pid``; None once it is reaped."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()  # the name in parentheses may hold spaces
    ticks = os.sysconf("SC_CLK_TCK")
    return fields[0], int(fields[1]), int(fields[19]), (int(fields[11]) + int(fields[12])) / ticks


def _pool_processes(parent):
    """``{pid: start time}`` of the multiprocessing children of ``parent`` (workers and the
    resource tracker), and the pids of the spawned workers among them."""
    found, workers = {}, []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        stat = _stat(entry.name)
        if stat is None or stat[1] != parent:
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().decode(errors="replace")
        except OSError:
            continue
        if "multiprocessing" in cmdline:
            found[int(entry.name)] = stat[2]
            if "spawn_main" in cmdline:
                workers.append(int(entry.name))
    return found, workers


def _cpu_seconds(pids):
    """The least CPU time any of ``pids`` has used, seconds."""
    return min((_stat(pid) or (0, 0, 0, 0.0))[3] for pid in pids)


def _running(pid, start):
    """Whether ``pid`` still runs: a zombie (dead, not yet reaped by whoever adopted it) or a
    new process under a reused pid does not."""
    stat = _stat(pid)
    return stat is not None and stat[0] not in "ZX" and stat[2] == start


def _alive(processes):
    return sorted(pid for pid, start in processes.items() if _running(pid, start))


@contextlib.contextmanager
def _started(args, stderr_path):
    """The command as a subprocess; on the way out it and every pool process it had started are
    killed, so that a failing test leaves nothing behind."""
    # a shell's background job ignores SIGINT, and so would the command (Python keeps SIG_IGN)
    ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with open(stderr_path, "w") as err:
            proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err,
                                    env={**os.environ, "NUMBA_NUM_THREADS": "1"},
                                    start_new_session=True)
    finally:
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    seen = {}
    try:
        yield proc, seen
    finally:
        seen.update(_pool_processes(proc.pid)[0])
        with contextlib.suppress(OSError):  # its session's group: whatever it started
            os.killpg(proc.pid, signal.SIGKILL)
        proc.kill()
        proc.wait()
        for pid in _alive(seen):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


def _coverage(tmp):
    out = tmp / "coverage"
    args = [sys.executable, "-m", "tvcid.studies.benchmarks.coverage", "--quick", "--jobs", "2",
            "--max-steps", "100000", "--out", str(out)]
    # each worker writes its draw's recordings before calibrating on them
    return args, lambda workers: all((out / "data" / f"draw{i:03d}").exists() for i in range(2))


def _fit(tmp):
    out = tmp / "fit"
    args = [*CLI, "fit", str(RECORD), "--hypothesis", "M002", "--params", "backlash,dead_zone",
            "--likelihood", "features", "--walkers", "8", "--max-steps", "100000",
            "--processes", "2", "--no-progress", "--out", str(out)]
    # calibrating, the workers waiting for their first batch (which comes after the
    # likelihood's set-up, over ten seconds later: the benchmark's workers are the busy ones)
    return args, lambda workers: (out / "chain.h5").exists()


def _study(tmp):
    args = [*CLI, "study", "all", "--quick", "--jobs", "2", "--results", str(tmp / "results")]
    # past their imports, which take about a second of CPU
    return args, lambda workers: _cpu_seconds(workers) >= 2.0


#: A parent whose ``map_pool`` workers sleep in their tasks. ``tvcid fit``'s batches last under
#: a second, and an idle pool worker ends when its parent's end of the task pipe closes: only a
#: busy one can be orphaned.
BUSY_MAP_POOL = """
import sys, time
from pathlib import Path
from tvcid.discovery.parallel import map_pool

with map_pool(2) as pool:
    pool.map(abs, [1, 2], chunksize=1)  # both started
    pool.map_async(time.sleep, [60, 60], chunksize=1)
    Path(sys.argv[1]).touch()
    time.sleep(60)
"""


def _busy_map_pool(tmp):
    ready = tmp / "ready"
    return [sys.executable, "-c", BUSY_MAP_POOL, str(ready)], lambda workers: ready.exists()


COMMANDS = {"bench_coverage": _coverage, "fit": _fit, "study": _study,
            "busy map_pool": _busy_map_pool}


def _run_and_signal(tmp_path, command, sig):
    """Start ``command`` and send it ``sig`` (SIGINT to its process group, as Ctrl-C does) once
    both workers are at work; the workers still running when it exited, the pool processes
    running a while later, its exit status and its stderr."""
    args, ready = COMMANDS[command](tmp_path)
    err_path = tmp_path / "stderr.txt"
    with _started(args, err_path) as (proc, seen):
        deadline = time.monotonic() + READY_TIMEOUT
        while True:
            assert proc.poll() is None, f"ended before it was signalled: {err_path.read_text()[-800:]}"
            assert time.monotonic() < deadline, f"workers not at work after {READY_TIMEOUT:.0f} s"
            found, workers = _pool_processes(proc.pid)
            seen.update(found)
            workers = [p for p in workers if _running(p, found[p])]
            if len(workers) >= 2 and ready(workers):
                break
            time.sleep(0.1)
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        try:
            status = proc.wait(timeout=EXIT_TIMEOUT)
        except subprocess.TimeoutExpired:
            status = None
        assert status is not None, f"{command} still runs {EXIT_TIMEOUT:.0f} s after {sig.name}"
        # a command that stopped its workers waited for them (its resource tracker ends after
        # it); orphaned ones get a moment to notice
        at_exit = _alive({pid: seen[pid] for pid in workers})
        deadline = time.monotonic() + ORPHAN_TIMEOUT
        while _alive(seen) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = _alive(seen)
    return at_exit, left, status, err_path.read_text()


@pytest.mark.parametrize("command, sig", [
    ("bench_coverage", signal.SIGTERM),
    ("bench_coverage", signal.SIGINT),
    ("fit", signal.SIGTERM),
    ("fit", signal.SIGINT),
    ("study", signal.SIGTERM),
    # the way out of the benchmark's SIGINT case, from a pool in the same class
    pytest.param("study", signal.SIGINT, marks=pytest.mark.slow),
], ids=lambda v: v.name if isinstance(v, signal.Signals) else v)
def test_interrupted_command_stops_its_workers_first(tmp_path, command, sig):
    at_exit, left, status, err = _run_and_signal(tmp_path, command, sig)
    assert at_exit == [], f"{command} exited with workers {at_exit} still running"
    assert left == [], f"{command}'s pool processes {left} outlived it"
    last = err.strip().splitlines()[-1] if err.strip() else ""
    assert status == 130 and "interrupted" in last and "Traceback" not in err, (
        f"after {sig.name}: status {status}, stderr {err[-800:]!r}")


@pytest.mark.parametrize("command", ["bench_coverage", "fit", "busy map_pool"])
def test_killed_command_leaves_no_worker_running(tmp_path, command):
    _, left, status, _ = _run_and_signal(tmp_path, command, signal.SIGKILL)
    assert status == -signal.SIGKILL
    assert left == [], (
        f"{command}'s workers {left} still run {ORPHAN_TIMEOUT:.0f} s after it was killed")


def test_map_pool_left_by_an_exception_has_stopped_its_workers():
    """Not only at the interpreter's exit (``multiprocessing``'s own clean-up): ``tvcid fit``
    called in a process that goes on."""
    from tvcid.discovery.parallel import map_pool

    pool = None
    try:
        with pytest.raises(KeyboardInterrupt):
            with map_pool(2) as pool:
                workers = {p.pid: _stat(p.pid)[2] for p in pool._pool}
                pool.map_async(time.sleep, [60, 60], chunksize=1)
                raise KeyboardInterrupt
        assert _alive(workers) == [], f"workers {_alive(workers)} still run"
    finally:
        if pool is not None:  # a failed test leaves no sleeper behind
            pool.terminate()


#: A child that notices its parent's death one way only, then sleeps; argv: the way, a file it
#: creates once set up.
ONE_WAY_CHILD = """
import os, sys, threading, time
from pathlib import Path
from tvcid.discovery import parallel as common

if sys.argv[1] == "prctl":
    common._die_with_parent()
else:
    threading.Thread(target=common._watch_parent, args=(os.getppid(),), daemon=True).start()
Path(sys.argv[2]).touch()
time.sleep(60)
"""


@pytest.mark.parametrize("way", ["prctl", "watch"])
def test_either_way_alone_ends_an_orphaned_worker(tmp_path, way):
    """The kernel's parent-death signal (Linux) and the thread watching the parent pid (the
    portable fallback) each end a worker whose parent was killed."""
    if way == "prctl" and not sys.platform.startswith("linux"):
        pytest.skip("PR_SET_PDEATHSIG is Linux's")
    ready = tmp_path / "ready"
    parent = (f"import subprocess, sys, time; "
              f"subprocess.Popen([sys.executable, '-c', {ONE_WAY_CHILD!r}, {way!r}, {str(ready)!r}]); "
              "time.sleep(60)")
    with _started([sys.executable, "-c", parent], tmp_path / "stderr.txt") as (proc, seen):
        deadline = time.monotonic() + READY_TIMEOUT
        while not ready.exists():
            assert proc.poll() is None and time.monotonic() < deadline, (
                (tmp_path / "stderr.txt").read_text())
            time.sleep(0.05)
        child = [e.name for e in Path("/proc").iterdir()
                 if e.name.isdigit() and (_stat(e.name) or (0, 0))[1] == proc.pid]
        assert len(child) == 1, child
        seen[int(child[0])] = _stat(child[0])[2]
        proc.kill()
        proc.wait()
        deadline = time.monotonic() + ORPHAN_TIMEOUT
        while _alive(seen) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _alive(seen) == [], (
            f"the child still runs {ORPHAN_TIMEOUT:.0f} s after its parent was killed")
