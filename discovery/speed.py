"""What a run's work costs: process CPU seconds, the kernel's reference speed, and whether the
machine was idle enough for a timing to count as the speed.

* :func:`cpu_seconds` -- CPU seconds of this process and of its finished children, the clock
  ``tvcid discover`` records per stage (``cpu_seconds`` in ``discovery.json``).
* :func:`kernel_reference` -- CPU seconds per kernel step of a small fixed closed-loop batch: the
  unit a run's CPU seconds over its ``simulated_steps`` are compared with, measured before and
  after a timed run (``python -m tvcid.studies.benchmarks.discover_speed``).
* :func:`evaluation_steps` -- the kernel steps one evaluated point of a likelihood costs,
  record by record and part by part.
* :func:`idle_check` -- whether such a run counts as the speed: the 1-minute load average at its
  start at most :data:`MAX_LOAD`, and its two references within :data:`MAX_REFERENCE_DRIFT`.
"""
from __future__ import annotations

import os
import resource
import time

__all__ = ["cpu_seconds", "kernel_reference", "evaluation_steps", "idle_check", "load_average", "MAX_LOAD", "MAX_REFERENCE_DRIFT",
           "REFERENCE_RUNS", "REFERENCE_SECONDS", "REFERENCE_DT"]

#: 1-minute load average at a timed run's start above which the run is flagged, not the speed.
MAX_LOAD = 0.5
#: Relative difference of the kernel references before and after a run above which it is
#: flagged (the machine's speed changed under it).
MAX_REFERENCE_DRIFT = 0.10
#: The reference batch: closed-loop runs of M000 under controller A, their length (s) and step
#: (s), the search's step.
REFERENCE_RUNS = 32
REFERENCE_SECONDS = 4.0
REFERENCE_DT = 5e-4


def cpu_seconds() -> float:
    """CPU seconds (user and system) of this process, every thread, and of its children that
    have ended and been waited for.

    A pool's live workers are not children that have ended: their work is counted by the tasks
    themselves (their own :func:`time.process_time`) where it ran in another process.
    """
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def kernel_reference(repeats=3) -> float:
    """CPU seconds per kernel step of a fixed closed-loop batch, the best of ``repeats``.

    :data:`REFERENCE_RUNS` runs of M000 (backlash varied by 1 % from run to run) under
    controller A for :data:`REFERENCE_SECONDS` at :data:`REFERENCE_DT`, simulated as one batch;
    the steps counted as ``simulated_steps`` counts them, each run's ``t_end / dt``. The process
    CPU (every kernel thread) is what is timed, so the value does not depend on how many cores
    the batch spreads over, only on how fast each runs.

    Returns
    -------
    float
        Seconds of CPU per step of one run.
    """
    from tvcid.models import CONTROLLER_A, hypothesis, simulate_batch

    sets = [hypothesis("M000").replace(backlash=1e-4 * (1 + 0.01 * i))
            for i in range(REFERENCE_RUNS)]
    simulate_batch(sets[:2], CONTROLLER_A, 0.1, dt=REFERENCE_DT, rate=None)  # compile / load
    steps = REFERENCE_RUNS * REFERENCE_SECONDS / REFERENCE_DT
    best = float("inf")
    for _ in range(repeats):
        t0 = time.process_time()
        simulate_batch(sets, CONTROLLER_A, REFERENCE_SECONDS, dt=REFERENCE_DT, rate=None)
        best = min(best, (time.process_time() - t0) / steps)
    return best


def evaluation_steps(terms) -> list:
    """Kernel steps one evaluated point costs, per likelihood term, split by what they simulate.

    Parameters
    ----------
    terms : list
        Likelihood terms (:mod:`tvcid.discovery.calibration.likelihood`) after their set-up.

    Returns
    -------
    list of dict
        Per term with a simulator: ``name``, ``kind`` (``cycle`` for a closed-loop record,
        ``open`` for an open-loop one), ``dt`` (the step its runs take, s), ``seconds`` (a run's
        length), ``steps`` and ``parts``: a cycle's ``settle`` (the transient before the
        compared window), ``window`` and ``beyond`` (what a run simulates past the window); an
        open-loop record's ``record``, and, where its edges or solver check divided the step,
        ``refined``: the steps beyond what the term's given step would take.
    """
    rows = []
    for term in terms:
        sim = getattr(term, "simulator", None)
        if sim is None:
            continue
        dt, end = float(sim.dt), float(sim.t_end)
        if getattr(term.recording, "kind", "") == "closed":
            span = float(term.tau[-1])
            settle = float(term.transient)
            parts = {"settle": settle / dt, "window": span / dt,
                     "beyond": max(end - settle - span, 0.0) / dt}
            kind = "cycle"
        else:
            coarse = end / float(term.dt)
            parts = {"record": coarse, "refined": end / dt - coarse}
            kind = "open"
        rows.append({"name": term.name, "kind": kind, "dt": dt, "seconds": end,
                     "steps": end / dt, "parts": parts})
    return rows


def idle_check(load_average, before, after, max_load=MAX_LOAD,
               max_drift=MAX_REFERENCE_DRIFT) -> dict:
    """Whether a timed run counts as the speed: an idle start and a steady kernel.

    Parameters
    ----------
    load_average : float
        The 1-minute load average at the run's start (:func:`os.getloadavg`'s first value).
    before, after : float
        :func:`kernel_reference` measured before and after the run.
    max_load, max_drift : float
        The limits: the load average at most ``max_load``, ``|after - before| / before`` at
        most ``max_drift``.

    Returns
    -------
    dict
        ``passed`` (bool), ``reason`` (``None`` when passed, else every limit exceeded, in
        words), ``load_average``, ``reference_drift`` and the limits.
    """
    drift = abs(after - before) / before if before > 0 else float("inf")
    reasons = []
    if not load_average <= max_load:
        reasons.append(f"load average {load_average:.2f} at the start > {max_load:g}")
    if not drift <= max_drift:
        reasons.append(f"kernel references {before:.3g} and {after:.3g} s per step differ by "
                       f"{drift:.0%} > {max_drift:.0%}")
    return {"passed": not reasons, "reason": "; ".join(reasons) or None,
            "load_average": float(load_average), "reference_drift": float(drift),
            "max_load": float(max_load), "max_drift": float(max_drift)}


def load_average() -> float:
    """The 1-minute load average now."""
    return float(os.getloadavg()[0])
