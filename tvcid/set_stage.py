"""The set stage of ``tvcid discover``: the members of the set the recordings leave open,
calibrated, screened by their weight, weighed and combined (:func:`calibrate_set`).

Each member's own work is :func:`tvcid.members.calibrate_member_task`, a task of an executor
(this process, or a Dask cluster); this module runs the two rounds, weighs the members by their
evidence (:mod:`tvcid.discovery.members.set_weights`), decides every structural choice by one rule
and mixes the members (:func:`tvcid.discovery.members.set_posterior.combine`).
"""
from __future__ import annotations

import math
import os
import time

from tvcid.discovery.members.set_weights import UNSURE_NATS
from tvcid.discovery.speed import cpu_seconds

from .result import DiscoveryResult

__all__ = ["calibrate_set", "screened_members", "MAX_MEMBERS", "SCREEN_STEPS", "SCREENING"]

#: Distinct members of the set calibrated at most (best score first); the rest are listed in
#: ``set_posterior.not_calibrated`` with their share of the weight by the ranking.
MAX_MEMBERS = 6
#: Steps of every member's chain before the members are weighed and those under the deciding
#: share are screened (:func:`calibrate_set`).
SCREEN_STEPS = 300
#: A member's sampling in the screening round: its start keeps the local search's maximum (no
#: restarts while a recording shows a misfit), and an importance-sampled member stops after two
#: rounds, reliable or not, with no chain after them (``Calibration``'s ``polish_restarts``,
#: ``importance_rounds``, ``importance_only``). A member the weights keep continues from there,
#: drawing the points a single run would; a screened one stops.
SCREENING = {"polish_restarts": 0, "importance_rounds": 2, "importance_only": True}
#: Pareto ``k`` of a screening's importance run at or over which its evidence (PSIS's threshold
#: of a reliable estimate) screens the member only with a margin: ...
SCREEN_MAX_K = 0.7
#: ... its weight, even at its allowance, under the deciding share by this many nats: the margin
#: the final weights ask of a member whose weight is not final
#: (:data:`tvcid.discovery.members.set_weights.UNSURE_NATS`).
SCREEN_UNSURE_NATS = UNSURE_NATS


def calibrate_set(record, recs, fixed, seed, quick, max_steps, progress, out, executor=None):
    """The posterior over the set: every distinct member calibrated (:func:`tvcid.members.member_chain`,
    at most :data:`MAX_MEMBERS`, best score first), and the richer structure of each component
    the set leaves open that no distinct member has
    (:func:`tvcid.discovery.members.set_posterior.richer_members`).

    A set of several members is calibrated in two rounds. First every member is sampled within
    :data:`SCREENING` (two rounds of importance sampling, or where the start gives it no
    proposal a chain of :data:`SCREEN_STEPS` steps) and the members are weighed by their evidence
    (:func:`tvcid.discovery.members.set_weights.evidence_weights`); a member whose weight stays
    under :data:`tvcid.discovery.structure.indistinguishable.DECIDING_SHARE` even at its
    estimate's allowance (by :data:`SCREEN_UNSURE_NATS` more where its importance run's Pareto
    ``k`` is :data:`SCREEN_MAX_K` or over) is *screened*: its sampling stops there and gives its
    ranges (the report says so). Then the others continue to convergence or the cap. The
    screening is written to ``discovery.json`` (``set_screening``), so a resumed run screens the
    same members. Each member's step error is
    measured (:func:`tvcid.discovery.calibration.step_error.measure_step_error`) and its evidence
    estimated again from its final chain, taken at half the step by the change the step error
    measures; the members are combined by those weights
    (:func:`tvcid.discovery.members.set_posterior.combine`), and the members beyond the cap named
    with their share of the weight by the ranking. A member whose chain cannot start (no point
    about its fit where every recording's likelihood is finite) is left out and named in
    ``set_posterior.failed``. Sets the record's ``posterior`` (the first calibrated member's, the
    winner's where it calibrates) and ``set_posterior`` (the members', their weights and the
    combined one). Each member's own work is a task of ``executor``
    (:func:`tvcid.members.calibrate_member_task`; default: one after the other in this
    process), combined here in the members' order; each member's row of
    ``set_posterior.members`` gets what its tasks cost (``simulated_steps``,
    ``simulated_seconds``, ``cpu_seconds``, ``wall_seconds``), and the stage's cost goes to the
    record's :class:`tvcid.run_record.RunCost` (``mcmc``, of which ``mcmc_start`` and
    ``mcmc_evidence``); returns ``record``."""
    from tvcid.discovery.executors import LocalProcesses
    from tvcid.discovery.members.ranking_shares import uncalibrated_share
    from tvcid.discovery.members.set_posterior import (
        MemberPosterior,
        calibration_reasons,
        combine,
        left_open_by_choices,
        richer_members,
    )
    from tvcid.discovery.members.set_weights import (
        DECIDING_SHARE,
        evidence_weights,
        merged_structures,
        unsure_members,
        weighed_choices,
    )

    from .members import calibrate_member_task

    t0, c0 = time.perf_counter(), cpu_seconds()
    rows = record.set_rows()
    best_score = rows[0]["score"]
    richer = richer_members(record.structures, record.decided)
    calibrated = rows[:MAX_MEMBERS] + richer
    reasons = calibration_reasons(rows, richer, MAX_MEMBERS)
    executor = executor if executor is not None else LocalProcesses(1)
    here = isinstance(executor, LocalProcesses) and executor.jobs == 1
    n = len(calibrated)
    cap = max_steps or (150 if quick else 2000)
    shared = (recs, record.sensor_offset, fixed, seed, quick)
    show = progress and here  # a worker's bars would garble this terminal
    cost = {"simulated_seconds": 0.0, "simulated_steps": 0.0, "start": 0.0, "start_steps": 0.0,
            "evidence_seconds": 0.0, "evidence_steps": 0.0, "elsewhere_cpu": 0.0,
            "cpu_at_start": c0}
    by_member = {}  # both rounds of each member's task

    def account(run):
        cost["simulated_seconds"] += run.simulated_seconds
        cost["simulated_steps"] += run.simulated_steps
        cost["start"] += run.start_seconds
        cost["start_steps"] += run.start_steps
        cost["evidence_seconds"] += run.evidence_seconds
        cost["evidence_steps"] += run.evidence_steps
        if run.pid != os.getpid():  # a worker's CPU: not on this process's clock
            cost["elsewhere_cpu"] += run.cpu_seconds
        own = by_member.setdefault(run.structure, dict.fromkeys(
            ("simulated_steps", "simulated_seconds", "cpu_seconds", "wall_seconds"), 0.0))
        for key in own:
            own[key] += getattr(run, key)

    screened, first_draws, first_failed, first_converged = set(), {}, {}, set()
    screen_steps = min(SCREEN_STEPS, cap)
    if n > 1 and screen_steps < cap:
        screening = record.set_screening
        names_now = [r["structure"] for r in calibrated]
        if not screening or screening.get("members") != names_now \
                or screening.get("steps") != screen_steps:
            runs = executor.map(calibrate_member_task, calibrated, *([x] * n for x in shared),
                                [screen_steps] * n, [show] * n, [out.resolve()] * n, [True] * n,
                                [True] * n, [SCREENING] * n)
            unsure = set()  # an importance run whose ratios screen only with a margin
            for row, run in zip(calibrated, runs):
                account(run)
                if run.failed is None:
                    first_draws[row["structure"]] = run.draws
                    k = run.kept.get("pareto_k")
                    if k is not None and not k < SCREEN_MAX_K:
                        unsure.add(row["structure"])
                    if run.kept.get("converged"):  # its chain stops here whatever its cap
                        first_converged.add(row["structure"])
                else:  # not started again below
                    first_failed[row["structure"]] = run.failed
            weighed = (evidence_weights(first_draws, rows=calibrated, seed=seed)
                       if len(first_draws) > 1 else None)
            screening = {"members": names_now, "steps": screen_steps,
                         "share": DECIDING_SHARE,
                         "weights": None if weighed is None else weighed.weights,
                         "upper": None if weighed is None else weighed.upper,
                         "screened": [] if weighed is None else screened_members(weighed, unsure)}
            record.set_screening = screening
            _write(out, record)  # a resumed run screens the same members
        screened = set(screening["screened"])
    todo = [r for r in calibrated if r["structure"] not in first_failed]
    m = len(todo)
    caps = [screen_steps if r["structure"] in screened else cap for r in todo]
    # a screened or converged member's draws are the first round's where it ran here (its chain
    # does not move again; on a resumed run they are drawn again, the same draws)
    settled = (screened | first_converged) & set(first_draws)
    weigh = [n > 1 and r["structure"] not in settled for r in todo]
    runs = executor.map(calibrate_member_task, todo, *([x] * m for x in shared), caps,
                        [show] * m, [out.resolve()] * m, weigh, [False] * m,
                        [SCREENING if r["structure"] in screened else None for r in todo])
    members, draws, step_shifts = [], {}, {}
    failed = [{"structure": name, "reason": why} for name, why in first_failed.items()]
    for row, run in zip(todo, runs):
        account(run)
        if run.failed is not None:
            # the rest of the set still has its posterior; the report names this member
            failed.append({"structure": row["structure"], "reason": run.failed})
            continue
        if not members:
            record.posterior = run.kept
            from .figures import write_posterior_figures

            write_posterior_figures(run.posterior, out, seed=seed)
        margin = row.get("margin")
        ratio = (row["score"] - best_score) / margin if margin else 0.0
        kept = run.kept
        if row["structure"] in screened:
            kept = {**kept, "screened": {"steps": screen_steps, "share": DECIDING_SHARE,
                                         "upper_weight": record.set_screening["upper"][
                                             row["structure"]]}}
        from .figures import write_pinned_figure

        figure = write_pinned_figure(run.posterior, kept.get("pinned") or {"pinned": []},
                                     out / f"pinned-{len(members)}.png", recs, row["params"])
        if figure is not None:
            kept = {**kept, "pinned_figure": figure.name}
        members.append(MemberPosterior(
            row["structure"], run.quantities, kept, float(ratio),
            log_prob=run.posterior.log_prob, prior_quantities=run.prior_quantities,
            step_error=run.step_error))
        step = kept.get("step_error") or {}
        if step.get("log_evidence_shift") is not None:
            step_shifts[row["structure"]] = (step["log_evidence_shift"],
                                             step["log_evidence_shift_se"])
        d = run.draws if run.draws is not None else first_draws.get(row["structure"])
        if d is not None:
            draws[row["structure"]] = d
    names = [m.structure for m in members]
    if not members:
        record.set_posterior = {"criterion": "no member calibrated", "quantities": {},
                                    "members": [], "failed": failed,
                                    "not_calibrated": [r["structure"] for r in rows[MAX_MEMBERS:]]}
        _record_cost(record, t0, cost)
        return record
    if len(members) > 1:
        weighting = evidence_weights({m: draws[m] for m in names},
                                     rows=[r for r in calibrated if r["structure"] in names],
                                     seed=seed, step_shifts=step_shifts)
        weights = weighting.weights
    else:
        weighting, weights = None, {names[0]: 1.0}
    unsure = [] if weighting is None else unsure_members({
        "members": [{"structure": m.structure, "converged": m.converged, "posterior": m.summary,
                     "weight": weights[m.structure]} for m in members],
        "weighting": weighting.to_dict()})
    choices = weighed_choices(record.decided, weights, record.indistinguishable, unsure,
                              merged_structures(record.structures))
    left_open = left_open_by_choices(choices)
    if weighting is not None:
        combined = combine(members, weights=weighting.of(names), seed=seed,
                           criterion=weighting.rule, left_open=left_open).to_dict()
        combined["weighting"] = weighting.to_dict()
    else:
        combined = combine(members, seed=seed, criterion="one structure",
                           left_open=left_open).to_dict()
    combined["choices"] = choices
    dropped = uncalibrated_share(rows + [r for r in calibrated if r not in rows], names, seed=seed)
    combined["not_calibrated"] = dropped.names
    combined["not_calibrated_share"] = dropped.share if dropped.names else None
    combined["calibrated_because"] = {n: reasons[n] for n in names}
    combined["distinct_members"] = len(rows)
    combined["failed"] = failed
    combined["screened"] = sorted(screened & set(names))
    combined["unsure"] = unsure
    for row in combined["members"]:  # what each member's own work cost, both rounds
        row.update(by_member[row["structure"]])
    record.set_posterior = combined
    _record_cost(record, t0, cost)
    return record


def screened_members(weighed, unsure=()) -> list:
    """The members the screening stops: under the deciding share even at their allowance
    (:meth:`tvcid.discovery.members.set_weights.SetWeights.screened`), those in ``unsure`` (an
    importance run with Pareto ``k`` of :data:`SCREEN_MAX_K` or more) only
    :data:`SCREEN_UNSURE_NATS` under it."""
    from tvcid.discovery.members.set_weights import DECIDING_SHARE

    floor = DECIDING_SHARE * math.exp(-SCREEN_UNSURE_NATS)
    return [m for m in weighed.screened(DECIDING_SHARE)
            if m not in unsure or weighed.upper.get(m, weighed.weights[m]) < floor]


def _record_cost(record, t0, cost):
    """The set stage's wall time, CPU seconds (this process's, its ended children's and its
    workers'), simulated seconds and kernel steps into ``record.cost``; of which the chains'
    starts (``mcmc_start``) and the importance draws of the members' evidence
    (``mcmc_evidence``)."""
    record.cost.add("mcmc", wall=time.perf_counter() - t0,
                    cpu=cpu_seconds() - cost["cpu_at_start"] + cost["elsewhere_cpu"],
                    simulated_seconds=cost["simulated_seconds"],
                    simulated_steps=cost["simulated_steps"])
    record.cost.add("mcmc_start", simulated_seconds=cost["start"],
                    simulated_steps=cost["start_steps"])
    record.cost.add("mcmc_evidence", simulated_seconds=cost["evidence_seconds"],
                    simulated_steps=cost["evidence_steps"])


def _write(out, record):
    DiscoveryResult(record, out).save()
