"""One interface for independent work (benchmark, coverage and prediction draws): local processes
on this machine, or a Dask cluster.

:func:`executor_from` is what the command lines call: ``executor_from(jobs)`` runs the calls in
this process (``jobs=1``) or in ``jobs`` spawned processes (:func:`tvcid.discovery.parallel.process_pool`,
whose workers end with this process); ``executor_from(dask=ADDRESS)`` runs them on the Dask
scheduler at ``ADDRESS`` (``tcp://HOST:8786``), or on a ``LocalCluster`` of ``N`` one-thread
worker processes for ``local:N``. Each call's randomness comes from the seed among its
arguments, so every executor returns the same results for the same calls.

Dask is an optional extra (``pip install tvcid[dask]``) imported only by :class:`DaskExecutor`.
Closing an executor (also when an exception, Ctrl-C or SIGTERM leaves its ``with`` block)
cancels the calls not yet finished: local workers are stopped; on a Dask cluster the queued
calls never start and a running one is stopped on its worker (:func:`_stopped_when_released`),
as it is when the client process is killed and the scheduler drops its futures.
"""
from __future__ import annotations

import contextlib
import logging
import re
import signal
import threading

from .parallel import _handlers, process_pool, sigterm_raises

__all__ = ["DaskExecutor", "Executor", "LocalProcesses", "TaskCancelled", "check_dask_address",
           "executor_from"]

#: What a user without the extra is told to run.
DASK_INSTALL = "pip install tvcid[dask]"
#: Seconds between a Dask task's checks that its future is still wanted.
CANCEL_POLL = 0.5
#: A scheduler address as Dask writes it (``tcp://10.0.0.5:8786``, ``tls://host:8786``), or a
#: bare ``host:port``.
_ADDRESS = re.compile(r"^((tcp|tls|ws|wss|ucx|inproc)://\S+|[\w.\-\[\]:]+:\d+)$")


class Executor:
    """Runs independent calls of one function and hands back their results; a ``with`` block
    closes it.

    Subclasses give :meth:`map`, :meth:`completed` and :meth:`close`. The calls must not share
    state: each gets all it needs (its seed among them) from its arguments.
    """

    def map(self, fn, *iterables):
        """``fn(*args)`` for each ``args`` of ``zip(*iterables)``, results in submission order.

        Every call is submitted before the first result is awaited (in this process, with one
        job: each runs when its result is asked for, so that it is recorded before the next
        starts); the first call that raises raises here, at its place. Leaving the loop early
        cancels the calls not yet finished.
        """
        raise NotImplementedError

    def completed(self, fn, *iterables):
        """``(index, result, error)`` for each call of :meth:`map`'s, as each finishes.

        ``error`` is the exception the call raised (``result`` is then None), so that one failed
        call does not stop the others; Ctrl-C and SIGTERM still propagate.
        """
        raise NotImplementedError

    def close(self):
        """Cancel the calls not yet finished and release the workers (idempotent)."""

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close()
        return False


class LocalProcesses(Executor):
    """``jobs`` spawned processes on this machine (:func:`tvcid.discovery.parallel.process_pool`), or,
    for ``jobs=1``, the calls one after the other in this process.

    As a ``with`` block it is the pool's: SIGTERM raises :class:`tvcid.discovery.parallel.Terminated`
    within it; Ctrl-C or SIGTERM stop the workers at once, another exception cancels the queued
    calls and lets the running ones end.

    Parameters
    ----------
    jobs : int
        Calls run at once (at least 1).
    """

    def __init__(self, jobs=1):
        if jobs < 1:
            raise ValueError(f"--jobs {jobs}: need at least 1")
        self.jobs = int(jobs)
        self._pool = process_pool(self.jobs) if self.jobs > 1 else None
        self._futures = []
        self._closed = False

    def map(self, fn, *iterables):
        if self._pool is None:  # lazily: each result is recorded before the next call starts
            return (fn(*args) for args in zip(*iterables))
        futures = self._submit_all(fn, iterables)
        return self._in_order(futures)

    def completed(self, fn, *iterables):
        if self._pool is None:
            return self._inline_completed(fn, iterables)
        return self._as_completed(self._submit_all(fn, iterables))

    def _submit_all(self, fn, iterables):
        futures = [self._pool.submit(fn, *args) for args in zip(*iterables)]
        self._futures.extend(futures)
        return futures

    @staticmethod
    def _inline_completed(fn, iterables):
        for i, args in enumerate(zip(*iterables)):
            try:
                value = fn(*args)
            except Exception as exc:  # noqa: BLE001 - the caller decides what a failure means
                yield i, None, exc
            else:
                yield i, value, None

    @staticmethod
    def _in_order(futures):
        try:
            for f in futures:
                yield f.result()
        finally:  # a consumer that stopped early wants none of the rest
            for f in futures:
                f.cancel()

    @staticmethod
    def _as_completed(futures):
        from concurrent.futures import as_completed

        index = {f: i for i, f in enumerate(futures)}
        try:
            for f in as_completed(futures):
                try:
                    value = f.result()
                except Exception as exc:  # noqa: BLE001 - as in _inline_completed
                    yield index[f], None, exc
                else:
                    yield index[f], value, None
        finally:
            for f in futures:
                f.cancel()

    def close(self):
        """Cancel the queued calls and stop the workers at once if any call still runs."""
        if self._closed or self._pool is None:
            self._closed = True
            return
        self._closed = True
        if all(f.done() for f in self._futures):
            self._pool.shutdown(wait=True)
        else:
            self._pool._stop_workers()

    def __enter__(self):
        if self._pool is not None:
            self._pool.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb):
        if self._pool is None:
            return False
        self._closed = True
        for f in self._futures:  # queued calls of a loop left by an exception
            f.cancel()
        # also after close(): the pool's block puts the previous SIGTERM handler back
        return self._pool.__exit__(exc_type, exc, tb)


class TaskCancelled(BaseException):
    """Raised inside a Dask task whose future was cancelled or released (its client closed or
    died). Not an :class:`Exception`, so that a draw's ``except Exception`` lets it through."""


def _raise_in_thread(ident, exc_type):
    """Raise ``exc_type`` in thread ``ident`` at its next Python instruction; ``None`` withdraws
    one not yet raised (CPython's ``PyThreadState_SetAsyncExc``)."""
    import ctypes

    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident),
                                               None if exc_type is None else ctypes.py_object(exc_type))


@contextlib.contextmanager
def _stopped_when_released(poll=CANCEL_POLL):
    """Within a Dask task: :class:`TaskCancelled` is raised in the block once the worker no
    longer wants the task's result.

    A worker cannot stop a running task: when its future is cancelled, or released because the
    client closed or died, the worker marks the task ``cancelled`` and lets it run to its end.
    A draw lasts up to an hour, so a thread here polls the task's state and, once it is
    cancelled, raises in the task's thread (at its next Python instruction: a numba kernel or a
    BLAS call in progress ends first). Outside a Dask worker, or where the worker's state cannot
    be read, the block runs as it is.
    """
    try:
        from distributed import get_worker
        from distributed.worker import thread_state

        key = thread_state.key
        tasks = get_worker().state.tasks
    except (ImportError, AttributeError, ValueError):
        yield
        return
    ident = threading.get_ident()
    lock = threading.Lock()
    done = threading.Event()

    def watch():
        while not done.wait(poll):
            task = tasks.get(key)
            if task is None or task.state in ("cancelled", "released", "forgotten"):
                with lock:  # not once the block has ended: the exception would hit the worker
                    if not done.is_set():
                        _raise_in_thread(ident, TaskCancelled)
                return

    threading.Thread(target=watch, name=f"cancel-{key}", daemon=True).start()
    try:
        yield
    finally:
        with lock:
            done.set()
        _raise_in_thread(ident, None)  # one sent as the block ended must not reach the worker


def _run_on_worker(fn, *args):
    """``fn(*args)`` on a Dask worker, stopped when its future is cancelled."""
    with _stopped_when_released():
        return fn(*args)


def _import_distributed():
    """``distributed``, or an ImportError naming the extra to install."""
    try:
        import distributed
    except ImportError:
        raise ImportError(f"Dask's distributed scheduler is not installed: {DASK_INSTALL}") from None
    return distributed


def check_dask_address(address) -> str:
    """``address`` if it is ``local:N`` (N >= 1) or a scheduler address (``tcp://HOST:8786``)
    and Dask is installed; else a ValueError (a bad address) or an ImportError (no Dask), each
    one line."""
    text = str(address).strip()
    if text == "local" or text.startswith("local:"):
        n = text[len("local:"):]
        if not (n.isdigit() and int(n) >= 1):
            raise ValueError(f"{address!r}: local:N needs N, a number of workers >= 1 (e.g. "
                             "local:2)")
    elif not _ADDRESS.match(text):
        raise ValueError(f"{address!r}: not a Dask scheduler address (tcp://HOST:8786) nor "
                         "local:N")
    _import_distributed()
    return text


class DaskExecutor(Executor):
    """The calls as tasks of a Dask cluster: the scheduler at ``address``, or a ``LocalCluster``
    for ``local:N`` that the executor starts and closes.

    ``local:N`` starts ``N`` worker processes of one thread each (``processes=True``): as
    :class:`LocalProcesses` does, each call has a process to itself (the numba kernels and the
    calibration's threads are not shared). On a remote cluster, start each worker with
    ``--nthreads 1`` for the same reason, from a checkout of the same code: the workers import
    the functions they run, and files a call writes (a draw's recordings and chains) land on
    the worker's disk, relative to its working directory.

    Closing cancels the futures not yet finished (the queued calls never start, running ones are
    stopped: :func:`_stopped_when_released`), closes the client and the ``LocalCluster`` (whose
    workers end with this process, also when it is killed).

    Parameters
    ----------
    address : str
        ``tcp://HOST:PORT`` (any address Dask's ``Client`` takes) or ``local:N``.
    """

    def __init__(self, address):
        self.address = check_dask_address(address)
        distributed = _import_distributed()
        self._distributed = distributed
        self._futures = []
        self._closed = False
        self.cluster = None
        if self.address.startswith("local:"):
            self.cluster = distributed.LocalCluster(
                n_workers=int(self.address[len("local:"):]), threads_per_worker=1,
                processes=True, dashboard_address=None,
                # its HTTP routes on a free port: two runs on one machine must not clash
                scheduler_kwargs={"dashboard_address": ":0"},
                preload=[__name__],  # dask_setup below, in each worker process
                silence_logs=logging.ERROR)  # not the warnings of a close amid running tasks
            target = self.cluster
        else:
            target = self.address
        try:
            self.client = distributed.Client(target, set_as_default=False)
        except OSError as err:
            if self.cluster is not None:
                self.cluster.close()
            raise OSError(f"no Dask scheduler answers at {self.address} ({err})") from None
        self._signals = contextlib.ExitStack()

    def _submit_all(self, fn, iterables):
        futures = [self.client.submit(_run_on_worker, fn, *args, pure=False,
                                      key=f"{getattr(fn, '__name__', 'call')}-{i}-{_token()}")
                   for i, args in enumerate(zip(*iterables))]
        self._futures.extend(futures)
        return futures

    def _cancel(self, futures):
        left = [f for f in futures if not f.done()]
        if left and not self._closed:
            with contextlib.suppress(Exception):  # the client may be closing already
                self.client.cancel(left)

    def map(self, fn, *iterables):
        return self._in_order(self._submit_all(fn, iterables))

    def _in_order(self, futures):
        try:
            for f in futures:
                yield f.result()
        finally:
            self._cancel(futures)

    def completed(self, fn, *iterables):
        return self._as_completed(self._submit_all(fn, iterables))

    def _as_completed(self, futures):
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for f in self._distributed.as_completed(futures, loop=self.client.loop):
                try:
                    value = f.result()
                except Exception as exc:  # noqa: BLE001 - the caller decides what a failure means
                    yield index[f.key], None, exc
                else:
                    yield index[f.key], value, None
        finally:
            self._cancel(futures)

    def close(self):
        """Cancel the unfinished futures, close the client and a ``LocalCluster``; a second
        Ctrl-C or SIGTERM meanwhile does not cut it short."""
        if self._closed:
            return
        with _handlers(SIGINT=signal.SIG_IGN, SIGTERM=signal.SIG_IGN):
            try:
                self._cancel(self._futures)
            finally:
                self._closed = True
                with contextlib.suppress(Exception):
                    self.client.close()
                if self.cluster is not None:
                    self.cluster.close()
                self._signals.close()

    def __enter__(self):
        self._signals.enter_context(sigterm_raises())  # SIGTERM leaves the block through close()
        return self


def dask_setup(worker):
    """Preload of a ``local:N`` cluster's worker processes: they ignore Ctrl-C, which reaches the
    whole process group; :meth:`DaskExecutor.close` stops them."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _token():
    import uuid

    return uuid.uuid4().hex


def executor_from(jobs=1, dask=None) -> Executor:
    """The executor of a command line's ``--jobs`` and ``--dask``: :class:`DaskExecutor` when
    ``dask`` is given, else :class:`LocalProcesses` of ``jobs``.

    Parameters
    ----------
    jobs : int
        Local processes (1: in this process).
    dask : str or None
        A Dask scheduler address or ``local:N``; only with ``jobs=1``.
    """
    if dask is not None:
        if jobs != 1:
            raise ValueError("--jobs and --dask: give one or the other (--dask local:N runs N "
                             "local workers)")
        return DaskExecutor(dask)
    return LocalProcesses(jobs)
