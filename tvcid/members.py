"""The set's members calibrated as independent tasks of an executor (:mod:`tvcid.discovery.executors`).

:func:`calibrate_member_task` does all of one member's own work: its chain
(:func:`member_chain`, checkpointed in ``chain-<tag>.h5`` of the output
directory), its summary, its step error and the importance draws of its evidence for the weights
(:func:`tvcid.discovery.members.member_evidence.member_importance_draws`); or, screening, the chain
and the draws alone. It
gets everything as arguments and hands back a :class:`MemberRun`, both of which pickle, so it
runs the same in this process (the default) or on a Dask worker; :func:`tvcid.set_stage.calibrate_set`
combines the runs in the members' order.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field

from tvcid.models.strict_json import jsonable

__all__ = ["MemberRun", "calibrate_member_task"]


@dataclass
class MemberRun:
    """One member's calibration, or why it has none.

    Attributes
    ----------
    structure : str
    failed : str or None
        Why its chain could not start (:class:`tvcid.discovery.calibration.start.NoFiniteStartError`);
        the other fields are then empty.
    posterior : tvcid.discovery.calibration.Posterior or None
    kept : dict
        Its row of ``set_posterior.members`` (the posterior's summary, step error, chain file).
    quantities, prior_quantities : dict
        Combined quantity -> draws, of the posterior and of the priors alone.
    step_error : dict
        Combined quantity -> its step error.
    draws : tvcid.discovery.members.member_evidence.ImportanceDraws or None
        Its evidence's importance draws, for the weights (only when the set has several members).
    simulated_seconds : float
        Seconds simulated: the chain (start included), the step error, the importance draws.
    simulated_steps : float
        Kernel steps of the same runs.
    start_seconds, start_steps : float
        Of which the chain's start (its optimisation and curvature).
    evidence_seconds, evidence_steps : float
        Of which the importance draws of its evidence, for the weights.
    cpu_seconds, wall_seconds : float
        The task's CPU seconds (its process's, every thread) and wall seconds.
    pid : int
        The id of the process it ran in: a task run in another process adds its CPU seconds to
        the stage's (:func:`tvcid.set_stage.calibrate_set`).
    """

    structure: str
    failed: str | None = None
    posterior: object = None
    kept: dict = field(default_factory=dict)
    quantities: dict = field(default_factory=dict)
    prior_quantities: dict = field(default_factory=dict)
    step_error: dict = field(default_factory=dict)
    draws: object = None
    simulated_seconds: float = 0.0
    simulated_steps: float = 0.0
    start_seconds: float = 0.0
    start_steps: float = 0.0
    evidence_seconds: float = 0.0
    evidence_steps: float = 0.0
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0
    pid: int = 0


def calibrate_member_task(row, recs, offsets, fixed, seed, quick, max_steps, progress, out,
                          weigh, screen=False, sampling=None):
    """One member's calibration and what the set needs of it.

    Parameters
    ----------
    row : dict
        The member's row of the ranking.
    recs : list of tvcid.models.recording.Recording
    offsets : dict
        Sensor offset per recording (rad), removed before the calibration.
    fixed : dict or None
    seed : int
    quick : bool
    max_steps : int or None
    progress : bool
    out : pathlib.Path
        Where the chain is checkpointed (created if missing).
    weigh : bool
        Draw the importance points of its evidence for the members' weights.
    screen : bool
        The chain (to ``max_steps``) and the importance draws only: what the screening of the
        set's members by weight needs (:func:`tvcid.set_stage.calibrate_set`).
    sampling : dict, optional
        Limits of the member's sampling, passed to
        :func:`tvcid.discovery.members.member_calibration.calibrate_member`
        (``polish_restarts``, ``importance_rounds``, ``importance_only``; default none): the
        screening's (:data:`tvcid.set_stage.SCREENING`).

    Returns
    -------
    MemberRun
    """
    from tvcid.discovery.threads import one_blas_thread

    t0, c0 = time.perf_counter(), time.process_time()
    with one_blas_thread():  # also on a worker: the kernels own its cores
        run = _member_task(row, recs, offsets, fixed, seed, quick, max_steps, progress, out,
                           weigh, screen, sampling)
    run.cpu_seconds, run.wall_seconds = time.process_time() - c0, time.perf_counter() - t0
    run.pid = os.getpid()
    return run


def _member_task(row, recs, offsets, fixed, seed, quick, max_steps, progress, out, weigh,
                 screen, sampling):
    """:func:`calibrate_member_task`'s work, untimed."""
    from tvcid.discovery.calibration.pinned import pinned_combinations
    from tvcid.discovery.calibration.start import NoFiniteStartError
    from tvcid.discovery.calibration.step_error import measure_step_error
    from tvcid.discovery.calibration.widening import widen_quantiles
    from tvcid.discovery.members.member_evidence import member_importance_draws
    from tvcid.discovery.members.set_posterior import not_pinned, prior_quantities
    from tvcid.models.quantities import member_quantities

    out.mkdir(parents=True, exist_ok=True)  # a worker's own disk may not hold it yet
    try:
        post, priors, seconds, chain = member_chain(row, recs, offsets, fixed, seed, quick,
                                                    max_steps, progress, out, sampling)
    except NoFiniteStartError as exc:
        return MemberRun(row["structure"], failed=str(exc))
    simulated = seconds["start"] + seconds["sampling"]
    steps = post.calibration.log_posterior_.simulated_steps  # the chain's, start included
    draws, evidence = None, {}
    if weigh:
        draws = member_importance_draws(post, seed=seed)
        simulated += draws.simulated_seconds
        steps += draws.simulated_steps
        evidence = {"evidence_seconds": draws.simulated_seconds,
                    "evidence_steps": draws.simulated_steps}
    if screen:
        return MemberRun(row["structure"], kept={"converged": post.report.converged,
                                                 "iterations": int(post.report.iterations),
                                                 "pareto_k": getattr(post.report, "pareto_k",
                                                                     None)},
                         draws=draws, simulated_seconds=simulated, simulated_steps=steps,
                         start_seconds=seconds["start"],
                         start_steps=seconds.get("start_steps", 0.0), **evidence)
    s = post.summary()
    kept = {k: s[k] for k in ("parameters", "converged", "tau", "correlation", "iterations",
                              "acceptance", "n_over_tau", "at_prior_bound", "laplace_move",
                              "interval_drift", "sampler") + (("pareto_k", "rounds")
                                                              if "pareto_k" in s else ())}
    kept["not_pinned"] = not_pinned(post, priors)
    kept["pinned"] = pinned_combinations(post.samples, post.names, priors).to_dict()
    step = measure_step_error(post, seed=seed, params=row["params"])
    simulated += step.simulated_seconds
    steps += step.simulated_steps
    kept["step_error"] = step.to_dict()
    kept["parameters"] = widen_quantiles(kept["parameters"],
                                         {n: v["error"] for n, v in step.parameters.items()},
                                         {n: (p.low, p.high) for n, p in priors.items()})
    kept["structure"], kept["chain"] = row["structure"], chain
    kept["merged_into"] = row["merged_into"]
    samples = {n: post.samples[:, j] for j, n in enumerate(post.names)}
    return MemberRun(
        row["structure"], posterior=post, kept=kept,
        quantities=member_quantities(row["params"], samples),
        prior_quantities=prior_quantities(row["params"], priors, seed=seed),
        step_error={n: v["error"] for n, v in step.quantities.items()}, draws=draws,
        simulated_seconds=simulated, simulated_steps=steps, start_seconds=seconds["start"],
        start_steps=seconds.get("start_steps", 0.0), **evidence)


def _corrected(recordings, offsets):
    """The recordings with their estimated sensor offset removed from ``delta``."""
    from tvcid.models.recording import Recording

    out = []
    for r in recordings:
        name = r.path.stem if r.path else "recording"
        cols = dict(r.columns)
        cols["delta"] = r.delta - offsets.get(name, 0.0)
        out.append(Recording(columns=cols, meta=r.meta, path=r.path))
    return out


def member_chain(row, recs, offsets, fixed, seed, quick, max_steps, progress, out,
                 sampling=None):
    """MCMC of one member of the set
    (:func:`tvcid.discovery.members.member_calibration.calibrate_member`) on all recordings with
    their offsets removed, checkpointed in ``out``. Returns ``(posterior, priors, simulated
    seconds of the start and of the sampling, chain file name)``.

    The chain's file is named by a hash of the member's parameters as strict JSON
    (:func:`tvcid.models.strict_json.jsonable` of the rebuilt :class:`tvcid.models.ActuatorParams`): the
    ranking of a fresh run holds an open saturation as infinity, the same ranking read back from
    ``discovery.json`` as ``null``, and both must name the same chain for a rerun to resume it.
    """
    from tvcid.discovery.members.member_calibration import calibrate_member
    from tvcid.models import params_from_dict
    from tvcid.models.structures import Structure

    p = params_from_dict("custom", row["params"])
    tag = hashlib.sha256(json.dumps([jsonable(p.to_dict()), "set member", quick, seed],
                                    sort_keys=True, allow_nan=False).encode()).hexdigest()[:10]
    post, priors, simulated = calibrate_member(
        p, Structure.parse(row["structure"]), _corrected(recs, offsets), fixed=fixed, seed=seed,
        max_steps=max_steps or (150 if quick else 2000), backend=out / f"chain-{tag}.h5",
        progress=progress, **(sampling or {}))
    return post, priors, simulated, f"chain-{tag}.h5"
