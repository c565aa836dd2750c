"""A member's posterior on limit cycles alone, by each sampler, against a long reference chain.

``python -m tvcid.studies.benchmarks.cycles_posterior [--draws N] [--seed S] [--nested L]
[--reference-steps R] [--out DIR]``

The draws are the generator's designs that hold limit cycles alone
(:func:`tvcid.studies.benchmarks.scenarios.draw_design` within the ``wide`` ranges, seeds from
9000 on, which no test uses, those with an open-loop test skipped), each truth redrawn until it
oscillates at every setting (:func:`.scenarios.draw_scenario`), its recordings made by the
reference simulator and read back as measured recordings. The member is the truth's structure
started at the truth, calibrated as ``tvcid discover``'s set stage calibrates a member
(:func:`tvcid.discovery.members.member_calibration.calibrate_member`), three ways:

* ``default``: the importance rounds, then the chain to its 2,000-step cap;
* ``nested``: the importance rounds, then nested sampling with ``L`` live points over the
  start's widened proposal (:mod:`tvcid.discovery.calibration.nested_stage`), then the chain
  where its diagnostics fail;
* ``reference``: the chain run to ``R`` steps whatever its convergence test says.

Per method the row holds what the member's report would print (the 90 % intervals in the
sampling coordinates, log for log-uniform priors), what each stage before the chain gave (the
importance rounds' and the nested run's points, effective points, Pareto ``k``; the nested run's
likelihood calls, whether it finished, its evidence), what the sampler's own diagnostic says
(converged; effective points: a chain's kept steps times its walkers over its largest
autocorrelation time, an importance or nested run's Kish number), the kernel steps of the
sampling (the start's apart), the CPU seconds of the member's whole calibration (its start
included; where a method resumed from its checkpoint, ``resumed`` and only its last call's
cost), and, against the reference, each interval's
largest end move over the reference's width. The reference's own halves say how far it is
itself from converged (``interval_drift``).

Goals, per method: in every draw, each interval end within 0.2 of the reference's width in at
most 600 CPU seconds of the member's calibration (5 minutes of 2 cores; a resumed method is
not judged in time); no draw off the reference while the method's own diagnostic says
converged. The calibrations run with one BLAS thread, as ``tvcid discover``'s members do.

``DIR/bench.json`` (default ``results/bench_cycles_posterior``) holds the rows, resumed by seed,
each with the commit of the code; each method's checkpoint lives under ``DIR/drawS/``, so a
stopped run resumes inside a member's chain.
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from tvcid.models.strict_json import write_json

from ..common import code_commit
from .draws import finished_rows
from .goals import Goal
from .goals import report as goal_report
from .scenarios import draw_design, draw_scenario, write_recordings

OUT = Path("results/bench_cycles_posterior")
FIRST_SEED = 9000
#: Live points of the nested method.
NESTED_LIVE = 1000
#: Steps of the reference chain: five times the members' cap.
REFERENCE_STEPS = 10_000
#: The goal: each end of a 90 % interval within this share of the reference's width...
GOAL_SHARE = 0.2
#: ... in at most this many CPU seconds of the member's calibration (5 minutes of 2 cores).
GOAL_CPU_SECONDS = 600.0


def cycles_only_seeds(first, n, ranges="wide"):
    """The first ``n`` seeds from ``first`` whose drawn design holds closed-loop recordings
    alone."""
    out, seed = [], int(first)
    while len(out) < n:
        recs, _ = draw_design(np.random.default_rng(seed), ranges)
        if all(r.kind == "closed" for r in recs):
            out.append(seed)
        seed += 1
    return out


def interval_moves(intervals, reference) -> dict:
    """Per parameter, the larger of the two ends' moves from the reference's 90 % interval, over
    its width (sampling coordinates)."""
    out = {}
    for name, (lo, hi) in intervals.items():
        rlo, rhi = reference[name]
        width = rhi - rlo
        out[name] = float(max(abs(lo - rlo), abs(hi - rhi)) / width) if width > 0 else math.inf
    return out


def _method_row(post, start_steps, cpu, wall) -> dict:
    """What one method's calibration gives (see the module's docstring)."""
    cal = post.calibration
    rep = post.report
    z = post.internal
    q05, q95 = np.quantile(z, (0.05, 0.95), axis=0)
    method = getattr(rep, "method", "ensemble")
    if method in ("importance", "nested"):
        ess = float(rep.n_over_tau)
    else:
        tau = float(np.max(rep.tau)) if np.all(np.isfinite(rep.tau)) else math.inf
        ess = float((rep.iterations - post.burn) * cal.n_walkers / tau) if tau > 0 else 0.0
    steps = float(cal.log_posterior_.simulated_steps) - float(start_steps)
    stages = {}
    for name, run in (("importance", getattr(cal, "importance_", None)),
                      ("nested", getattr(cal, "nested_", None))):
        if run is not None:  # what each stage before the chain gave, whatever followed it
            k = run.pareto_k
            stages[name] = {"points": run.n, "effective_points": run.ess,
                            "pareto_k": k if math.isfinite(k) else None,
                            **({"likelihood_calls": run.n_like, "finished": run.finished,
                                "log_z": run.log_z, "log_z_se": run.log_z_se}
                               if name == "nested" else {})}
    return {
        "sampler": method, "converged": bool(rep.converged), "report": rep.to_dict(),
        "intervals": {n: [float(a), float(b)] for n, a, b in zip(post.names, q05, q95)},
        "effective_points": ess, "sampling_steps": steps, "start_steps": float(start_steps),
        "effective_points_per_billion_steps": ess / steps * 1e9 if steps > 0 else None,
        "cpu_seconds": cpu, "wall_seconds": wall, "interval_drift": post.interval_drift(),
        "stages": stages,
    }


def calibrate(scenario, recordings, backend, **options) -> dict:
    """One method's row: the member of the truth's structure calibrated with ``options``, with
    one BLAS thread as ``tvcid discover`` calibrates a member; ``resumed`` where a checkpoint
    of it was there (its kernel steps and CPU seconds are then only this call's)."""
    from tvcid.discovery.members.member_calibration import calibrate_member
    from tvcid.discovery.threads import one_blas_thread

    backend = Path(backend)
    resumed = backend.exists() or backend.with_name(backend.stem + "-nested.h5").exists()
    structure = scenario.structure
    c0, w0 = time.process_time(), time.perf_counter()
    with one_blas_thread():
        post, _, simulated = calibrate_member(scenario.truth, structure, recordings,
                                              seed=scenario.seed, backend=backend, **options)
    return {**_method_row(post, simulated["start_steps"], time.process_time() - c0,
                          time.perf_counter() - w0), "resumed": resumed}


def measure_draw(seed, out_dir, nested=NESTED_LIVE, reference_steps=REFERENCE_STEPS) -> dict:
    """One draw's row (see the module's docstring)."""
    from tvcid.models.recording import load_recordings

    scenario = draw_scenario(seed, ranges="wide")
    draw_dir = Path(out_dir) / f"draw{seed}"
    recordings = load_recordings(write_recordings(scenario, draw_dir, reuse=True))
    methods = {
        "default": calibrate(scenario, recordings, draw_dir / "default.h5"),
        "nested": calibrate(scenario, recordings, draw_dir / "nested.h5", nested=nested),
        "reference": calibrate(scenario, recordings, draw_dir / "reference.h5",
                               max_steps=reference_steps, stop_when_converged=False),
    }
    ref = methods["reference"]["intervals"]
    for name in ("default", "nested"):
        moves = interval_moves(methods[name]["intervals"], ref)
        methods[name]["moves"] = moves
        methods[name]["largest_move"] = max(moves.values())
        methods[name]["within_goal"] = bool(max(moves.values()) <= GOAL_SHARE)
    return {"seed": seed, "structure": scenario.structure.name, "design": scenario.to_dict(),
            "commit": code_commit(), "nested_live": nested, "reference_steps": reference_steps,
            "methods": methods}


def summarise(rows) -> dict:
    """Per method: draws within the goal, converged by its own diagnostic, the diagnostic's
    verdict where the goal fails (flagged or not), and the medians of the effective points per
    billion kernel steps and of the sampling's CPU seconds."""
    out = {"draws": len(rows), "goal_share": GOAL_SHARE}
    for name in ("default", "nested"):
        ms = [r["methods"][name] for r in rows]
        rate = [m["effective_points_per_billion_steps"] for m in ms
                if m["effective_points_per_billion_steps"] is not None]
        out[name] = {
            "within_goal": sum(m["within_goal"] for m in ms),
            "converged": sum(m["converged"] for m in ms),
            "missed_and_unflagged": sum((not m["within_goal"]) and m["converged"] for m in ms),
            "samplers": sorted({m["sampler"] for m in ms}),
            "median_effective_points_per_billion_steps": float(np.median(rate)) if rate else None,
            "median_cpu_seconds": float(np.median([m["cpu_seconds"] for m in ms])) if ms else None,
            # a resumed run's cost is only its last call's: not judged in time
            "within_goal_in_time": sum(m["within_goal"] and not m.get("resumed")
                                       and m["cpu_seconds"] <= GOAL_CPU_SECONDS for m in ms),
            "resumed": sum(bool(m.get("resumed")) for m in ms),
        }
    drift = [r["methods"]["reference"]["interval_drift"] for r in rows]
    out["reference_largest_drift"] = max((d["largest"] for d in drift if d), default=None)
    return out


def cycles_goals(table) -> list:
    """Per method: every draw's intervals within :data:`GOAL_SHARE` of the reference's width in
    at most :data:`GOAL_CPU_SECONDS` of the member's calibration; no draw missing the goal
    while its own diagnostic says converged."""
    n = table["draws"]
    goals = []
    for name in ("default", "nested"):
        m = table[name]
        goals.append(Goal.count(
            f"{name}: 90 % intervals within {GOAL_SHARE} of the reference's width in <= "
            f"{GOAL_CPU_SECONDS:.0f} CPU s", m["within_goal_in_time"], n))
        goals.append(Goal.at_most(f"{name}: draws off the reference that its diagnostic passed",
                                  m["missed_and_unflagged"] if n else None, 0, fmt="{:d}"))
    return goals


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=10)
    parser.add_argument("--seed", type=int, default=FIRST_SEED,
                        help="first seed scanned for designs with limit cycles alone")
    parser.add_argument("--nested", type=int, default=NESTED_LIVE,
                        help="live points of the nested method")
    parser.add_argument("--reference-steps", type=int, default=REFERENCE_STEPS)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    if args.draws < 1 or args.nested < 2 or args.reference_steps < 100:
        parser.error("--draws must be >= 1, --nested >= 2 and --reference-steps >= 100")
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench.json"
    seeds = cycles_only_seeds(args.seed, args.draws)
    rows = [r for r in finished_rows(path, False, args.seed, seeds[-1] - args.seed + 1)
            if r["seed"] in seeds]
    done = {r["seed"] for r in rows}
    for seed in seeds:
        if seed in done:
            continue
        row = measure_draw(seed, out, args.nested, args.reference_steps)
        rows.append(row)
        rows.sort(key=lambda r: r["seed"])
        write_json(path, {"quick": False, "rows": rows, "table": summarise(rows)})
        m = row["methods"]
        print(f"draw {seed} {row['structure']}: default {m['default']['sampler']} "
              f"move {m['default']['largest_move']:.2f} converged {m['default']['converged']}; "
              f"nested {m['nested']['sampler']} move {m['nested']['largest_move']:.2f} "
              f"converged {m['nested']['converged']}", flush=True)
    table = summarise(rows)
    write_json(path, {"quick": False, "rows": rows, "table": table})
    for k, v in table.items():
        print(f"{k}: {v}")
    return goal_report(cycles_goals(table))


if __name__ == "__main__":
    raise SystemExit(main())
