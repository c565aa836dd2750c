"""Process pools whose workers end with their parent, and scripts that Ctrl-C or SIGTERM stop
cleanly: the one way tvcid runs independent work in other processes."""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

__all__ = ["EXIT_INTERRUPTED", "Terminated", "init_worker", "map_pool", "process_pool",
           "run_interruptible", "sigterm_raises", "interruptions_raise"]


#: Exit status of a script stopped by Ctrl-C or SIGTERM (128 + SIGINT, as ``tvcid`` uses).
EXIT_INTERRUPTED = 130
#: Seconds a worker gets to end after SIGTERM before it is killed: one in a calibration defers
#: the signal to the end of the step, so that its chain's checkpoint is whole.
STOP_GRACE = 3.0
#: Seconds between a worker's checks that its parent still runs (where the kernel cannot say).
PARENT_POLL = 0.5
#: ``prctl`` option: the signal a process gets when its parent dies (linux/prctl.h).
_PR_SET_PDEATHSIG = 1


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C: ``except Exception`` (a draw's failure) must not swallow it."""


def _raise_terminated(signum, frame):
    raise Terminated("SIGTERM")


@contextlib.contextmanager
def _handlers(**handlers):
    """Signal handlers (``SIGTERM=...``) over the block, then the previous ones; only in the main
    thread (elsewhere Python refuses to set them: a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    for name, handler in handlers.items():
        previous[name] = signal.signal(getattr(signal, name), handler)
    try:
        yield
    finally:
        for name, handler in previous.items():
            signal.signal(getattr(signal, name), signal.SIG_DFL if handler is None else handler)


@contextlib.contextmanager
def _sigint_held():
    """SIGINT blocked in this thread over the block: a process started in it begins with SIGINT
    blocked (a Ctrl-C before :func:`init_worker` ignores it must not interrupt its start-up),
    and a Ctrl-C meanwhile reaches this process when the block ends."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def sigterm_raises():
    """SIGTERM raises :class:`Terminated` over the block (the default would end the process at
    once, leaving its workers behind)."""
    return _handlers(SIGTERM=_raise_terminated)


def interruptions_raise():
    """Ctrl-C (SIGINT) raises KeyboardInterrupt and SIGTERM :class:`Terminated` over the block,
    whatever handlers the process started with: a command started in the background of a script
    begins with SIGINT ignored, and ``kill -INT`` would not stop it. The handlers found are put
    back after; only in the main thread (elsewhere a no-op)."""
    return _handlers(SIGINT=signal.default_int_handler, SIGTERM=_raise_terminated)


def run_interruptible(main, argv=None) -> int:
    """``main(argv)``'s exit status; Ctrl-C or SIGTERM give one line on stderr and status 130.

    The ``__main__`` of a benchmark script: its pool's workers are stopped on the way out, and
    what it saved (each finished draw) is kept for a rerun to resume.
    """
    spec = getattr(sys.modules.get(main.__module__), "__spec__", None)
    prog = f"python -m {spec.name}" if spec is not None else Path(sys.argv[0]).name
    with interruptions_raise():
        try:
            return main(argv)
        except KeyboardInterrupt:
            print(f"{prog}: interrupted; finished draws are kept (run the same command again to "
                  "resume)", file=sys.stderr)
            return EXIT_INTERRUPTED


def _die_with_parent():
    """Linux: the kernel sends this process SIGTERM when its parent dies (a no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):  # no libc symbol: the watcher thread still works
        pass


def _watch_parent(parent_pid):
    """Exit as soon as this process's parent is no longer ``parent_pid`` (it died: the process
    was adopted)."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL)
    os._exit(1)  # the parent is gone: nobody wants this worker's result


def init_worker(parent_pid):
    """Initializer of every pool worker: it never outlives ``parent_pid``, its spawning process.

    Ctrl-C reaches the whole process group; workers ignore SIGINT and the parent stops them (no
    traceback from each). A parent that dies without stopping them (SIGKILL): on Linux the kernel
    sends each SIGTERM, and everywhere a daemon thread notices the new parent pid and exits (also
    for a worker whose calibration defers SIGTERM).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # blocked since its start (_sigint_held)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    _die_with_parent()
    if os.getppid() != parent_pid:  # the parent died before the line above took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="watch-parent",
                     daemon=True).start()


def _interruptible_task(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a pool worker, which ends when the task is interrupted.

    A calibration defers SIGTERM (and Ctrl-C) to the end of its step and then raises
    KeyboardInterrupt; the worker would report it and take the next task.
    """
    try:
        return fn(*args, **kwargs)
    except KeyboardInterrupt:
        os._exit(EXIT_INTERRUPTED)


def _stop(processes, grace=STOP_GRACE):
    """SIGTERM to each live process of ``processes``, SIGKILL to those still running ``grace``
    seconds later; returns once all have ended."""
    live = [p for p in processes if p.exitcode is None]
    for p in live:
        with contextlib.suppress(OSError, ValueError):  # ended meanwhile
            p.terminate()
    deadline = time.monotonic() + grace
    for p in live:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in live:
        if p.exitcode is None:
            with contextlib.suppress(OSError, ValueError):
                p.kill()
            p.join()


class WorkerPool(ProcessPoolExecutor):
    """A spawn-context :class:`ProcessPoolExecutor` (see :func:`process_pool`) whose ``with``
    block, left by Ctrl-C or SIGTERM, stops its workers at once (the plain one waits for their
    tasks to finish)."""

    def __init__(self, jobs):
        import multiprocessing

        super().__init__(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"),
                         initializer=init_worker, initargs=(os.getpid(),))
        self._workers = []
        self._signals = contextlib.ExitStack()

    def _remember_workers(self):
        # shutdown() forgets them, and a block may shut the pool down before it is left
        if self._processes:
            self._workers.extend(p for p in list(self._processes.values()) if p not in self._workers)

    def _stop_workers(self):
        # a second Ctrl-C or SIGTERM must not cut the stopping short
        with _handlers(SIGINT=signal.SIG_IGN, SIGTERM=signal.SIG_IGN):
            self._remember_workers()
            super().shutdown(wait=False, cancel_futures=True)
            _stop(self._workers)

    def submit(self, fn, /, *args, **kwargs):
        with _sigint_held():  # submit() starts the workers
            return super().submit(_interruptible_task, fn, *args, **kwargs)

    def shutdown(self, wait=True, *, cancel_futures=False):
        self._remember_workers()
        super().shutdown(wait=wait, cancel_futures=cancel_futures)

    def __enter__(self):
        self._signals.enter_context(sigterm_raises())
        return self

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is not None and not issubclass(exc_type, Exception):
                self._stop_workers()
            try:
                return super().__exit__(exc_type, exc, tb)
            except KeyboardInterrupt:  # while waiting for the running tasks (after a failure)
                self._stop_workers()
                raise
        finally:
            self._signals.close()


def process_pool(jobs):
    """A pool of ``jobs`` spawned processes (benchmarks and ``tvcid study all --jobs``), for a
    ``with`` block.

    Spawned, not forked: a process whose numba kernels already ran OpenMP threads cannot fork
    safely (libgomp terminates the child: seen under pytest-xdist). No worker outlives the
    block's process (:func:`init_worker`). Within the block SIGTERM raises :class:`Terminated`;
    Ctrl-C or SIGTERM stop the workers (SIGTERM, then SIGKILL after :data:`STOP_GRACE` seconds)
    before the interruption goes on, while another exception leaves the running tasks to finish.
    """
    return WorkerPool(jobs)


@contextlib.contextmanager
def map_pool(processes):
    """A spawned :class:`multiprocessing.pool.Pool` of ``processes`` workers over the block
    (``tvcid fit --processes``).

    Closed and joined when the block ends; any exception (Ctrl-C, SIGTERM, a failure) stops its
    workers at once. Its workers end with their parent as :func:`process_pool`'s do.
    """
    import multiprocessing

    with _sigint_held():
        pool = multiprocessing.get_context("spawn").Pool(processes, initializer=init_worker,
                                                         initargs=(os.getpid(),))
    try:
        with sigterm_raises():
            yield pool
            pool.close()
            pool.join()
    except BaseException:
        with _handlers(SIGINT=signal.SIG_IGN, SIGTERM=signal.SIG_IGN):
            # terminate() blocks for good on a queue lock that a killed worker held: then kill
            stopper = threading.Thread(target=pool.terminate, daemon=True)
            stopper.start()
            stopper.join(STOP_GRACE)
            if stopper.is_alive():
                _stop(list(pool._pool), grace=0.0)
        raise
