"""Benchmark of the Bayesian calibration: wall time to a converged posterior.

Case: M002 at controller A, one 10 s limit-cycle record (the last 10 s of a 20 s run at
dt = 2e-4, 1 kHz), independent Gaussian sensor noise of sd 1e-4 rad (seeded); posterior of
(backlash f, dead_zone zm, delay Td, sigma) with the phase-aligned waveform likelihood at its
default step (``tvcid.discovery.calibration.calibration.DEFAULT_DT``; the figures below were measured
at 5e-4 s), 10 walkers (2.5 per parameter: the Laplace independence move carries most steps; 16
walkers cost a median 41,120 simulated s over the same seven seeds, 10 walkers 28,952), warm
start and the calibration's transient (6 s given, a shorter one chosen where it is as accurate:
``Calibration(choose_transient=True)``), stopping at N > 50 tau, checked every 10 steps; seven
noise seeds (1-7).
Goal: under 60 s on 2 cores.

Also measured: simulations per second, tau and N/tau, truth against the 90 % interval, and the
log-likelihood error of the dt = 5e-4 likelihood (against dt = 2e-4) and of the 6 s transient
(against 12 s) at the truth; ``simulated_seconds``, the seconds simulated to convergence (goal:
<= 40,000), per seed and as the median over the seeds, and ``simulated_steps`` (RK4
steps; ``simulated_seconds_at_5e-4`` is the same cost in seconds at the 5e-4 s step the goal is
stated at, since a finer step costs more per simulated second).

Ridge case: :func:`tvcid.studies.benchmarks.scenarios.ridge_scenario` (paper 001's placement without the
band-pass loop, a drawn truth, limit cycles at A and B of 40 s at 1 kHz, data from the reference
path read back as measured), calibrated as ``tvcid fit`` does by default (waveform likelihood,
16 walkers, 4000-step cap) on (dead zone, backlash, delay, friction offset) from a start 20 %
off the truth (log-normal). Goal: converged within the step cap in <= 3 minutes on 2 cores, the
truths inside the 90 % intervals.

The transient is chosen by the accuracy it gives; ``--reference-transient 12`` runs the same
seeds with a fixed 12 s transient too and reports how far each posterior lies from that one
(with the default, 2 s is chosen on every seed, the medians lie within 0.11 half-widths of the
90 % interval and the widths are 0.89-1.17 of it, median 30,699 simulated s, 7 of 7 seeds within
40,000; with ``--transient 6``: within 0.15 and 0.88-1.24, median 38,740 s, 4 of 7 within).
``--continuation`` continues each run from the nearest stored run's cycle
(``Calibration(continuation=True)``; with ``--transient 6``: within 0.10, median 35,729 s).

Usage: ``python -m tvcid.studies.benchmarks.calibration [--case m002|ridge|all] [--seeds 1,2,3,4,5,6,7]
[--ridge-seeds 0] [--walkers 10] [--transient T] [--continuation] [--reference-transient 12]``;
writes
``results/bench_calibration/bench.json`` and corner/trace plots. Other jobs on the machine inflate the wall time; the load average is recorded.
The wall-time goals are judged against the batch kernel's reference measured in the same run
(:meth:`tvcid.studies.benchmarks.goals.Goal.speed`). The run ends with the goals of the cases it ran, one line each
(M002: every seed converged, every seed within 40,000 simulated seconds, the slowest seed's wall
time; ridge, per seed: converged within the step cap, every truth inside its 90 % interval, the
wall time), and its exit status is 0 when all are met, 1 otherwise. Each case's numbers carry the
commit of the code that ran them (``bench.json`` keeps the other case's from an earlier run);
non-finite numbers are written as ``null``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from tvcid.discovery.calibration import Calibration
from tvcid.models.synthetic import synthetic_recording
from tvcid.models import CONTROLLER_A, M002

from ..common import code_commit
from tvcid.models.strict_json import write_json

from .goals import Goal, kernel_reference
from .goals import report as goal_report

OUT = Path("results/bench_calibration")
NAMES = ("backlash", "dead_zone", "delay", "sigma")


def likelihood_errors(rec):
    """|ll(dt=5e-4) - ll(dt=2e-4)| and |ll(6 s or 2 s transient) - ll(12 s)| at the truth."""
    truth = M002()
    out = {}
    ref = Calibration("M002", params=("backlash",), dt=2e-4, transient=12.0).setup([rec])
    ll_ref = ref.log_posterior_.terms[0].loglike([truth], np.array([1e-4]))[0]
    for label, kw in (("dt_5e-4", dict(dt=5e-4, transient=12.0)),
                      ("transient_6s", dict(dt=2e-4, transient=6.0)),
                      ("default", dict(dt=5e-4, transient=6.0)),
                      # what the default chooses on this record (Calibration._choose_transients)
                      ("transient_2s", dict(dt=5e-4, transient=2.0))):
        cal = Calibration("M002", params=("backlash",), **kw).setup([rec])
        ll = cal.log_posterior_.terms[0].loglike([truth], np.array([1e-4]))[0]
        out[label] = float(abs(ll - ll_ref))
    return out


#: The cost goal of the M002 case (seconds simulated to convergence).
GOAL_SIMULATED_SECONDS = 40000.0
#: The ridge case's goal: converged within the step cap, in at most this wall time on 2 cores.
RIDGE_GOAL = {"wall_time_s": 180.0, "step_cap": 4000}
#: The commit of the code this process imported.
CODE_COMMIT = code_commit()


def run_case(seed, walkers, workdir, transient=None, continuation=False, choose_transient=True):
    rec = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, seed, workdir / f"m002_A_{seed}.csv",
                              keep_last=10.0)
    t0 = time.perf_counter()
    extra = {} if transient is None else {"transient": transient}
    cal = Calibration("M002", params=NAMES, n_walkers=walkers, max_steps=5000, seed=seed,
                      continuation=continuation, choose_transient=choose_transient, **extra)
    cal.fit([rec])
    wall = time.perf_counter() - t0
    post, rep = cal.posterior_, cal.report_
    rows = {}
    for n in NAMES:
        lo, hi = post.interval(n, 0.90)
        truth = post.truths[n]
        rows[n] = {"truth": truth, "q05": lo, "q50": float(np.median(post.samples[:, NAMES.index(n)])),
                   "q95": hi, "inside_90": bool(lo < truth < hi), "z": post.z_scores()[n]}
    sims = cal.log_posterior_.n_points
    return cal, rec, {
        "seed": seed,
        "transient": cal.transient,
        "continuation": bool(continuation),
        # the transient each record was simulated with (chosen by the accuracy it gives)
        "transients": getattr(cal, "transients_", None),
        "transient_errors": getattr(cal, "transient_errors_", None),
        # runs started from a stored walker's state / from the shared start (continuation only)
        "continued_runs": _continued(cal),
        "wall_time_s": wall,
        "sampling_time_s": rep.wall_time,
        "setup_and_start_s": wall - rep.wall_time,
        "simulations": sims,
        # total seconds simulated to convergence (goal: <= 40,000 for this case)
        "simulated_seconds": cal.log_posterior_.simulated_seconds,
        # RK4 steps, and the seconds they would simulate at the 5e-4 s step the goal is stated at
        # (a record at half the step costs twice per simulated second)
        "dt": cal.dt_,
        "simulated_steps": cal.log_posterior_.simulated_steps,
        "simulated_seconds_at_5e-4": 5e-4 * cal.log_posterior_.simulated_steps,
        "start_simulated_seconds": cal.start_simulated_seconds_,
        # the Laplace move's share of the steps after its trial, and that trial's acceptance
        "laplace": {k: v for k, v in (cal.laplace_ or {}).items() if k not in ("mean", "cov")},
        "simulations_per_s": sims / wall,
        "iterations": rep.iterations,
        "tau": dict(zip(NAMES, rep.tau)),
        "n_over_tau": rep.n_over_tau,
        "acceptance": rep.acceptance,
        "converged": rep.converged,
        "parameters": rows,
        "correlation": post.summary()["correlation"],
    }


def _continued(cal):
    c = [t.continuation for t in cal.terms_ if getattr(t, "continuation", None) is not None]
    return {"continued": sum(x.continued for x in c), "fresh": sum(x.fresh for x in c)} if c else None


def run_ridge_case(seed, workdir):
    """The ridge case for one drawn truth (see the module docstring)."""
    import math

    from tvcid.studies.benchmarks.scenarios import RIDGE_PARAMETERS, ridge_scenario, write_recordings

    scenario = ridge_scenario(seed)
    paths = write_recordings(scenario, workdir / f"ridge_{seed}")
    truth = scenario.truth
    rng = np.random.default_rng([seed, 1])
    start = {n: getattr(truth, n) * math.exp(0.2 * rng.standard_normal()) for n in RIDGE_PARAMETERS}
    t0 = time.perf_counter()
    cal = Calibration(truth, params=RIDGE_PARAMETERS, start=start, seed=seed).fit(paths)
    wall = time.perf_counter() - t0
    post, rep = cal.posterior_, cal.report_
    rows = {}
    for j, n in enumerate(RIDGE_PARAMETERS):
        lo, hi = post.interval(n, 0.90)
        v = float(getattr(truth, n))
        lo99, hi99 = post.interval(n, 0.99)
        rows[n] = {"truth": v, "q05": lo, "q50": float(np.median(post.samples[:, j])), "q95": hi,
                   "inside_90": bool(lo <= v <= hi), "inside_99": bool(lo99 <= v <= hi99),
                   "relative_width": (hi - lo) / abs(v)}
    lp = cal.log_posterior_
    at_truth = float(np.ravel(lp(lp.internal(np.array([[getattr(truth, n) for n in cal.names_]]))))[0])
    return {"seed": seed, "wall_time_s": wall, "iterations": rep.iterations,
            "step_cap": cal.max_steps, "converged": rep.converged,
            "tau": dict(zip(RIDGE_PARAMETERS, rep.tau)), "acceptance": rep.acceptance,
            "simulated_seconds": cal.log_posterior_.simulated_seconds,
            "dt": cal.dt_, "simulated_steps": cal.log_posterior_.simulated_steps,
            "inflation": list(cal.inflation_),
            "transients": getattr(cal, "transients_", None),
            "transient_errors": getattr(cal, "transient_errors_", None),
            "start_simulated_seconds": cal.start_simulated_seconds_,
            "laplace": {k: v for k, v in (cal.laplace_ or {}).items() if k not in ("mean", "cov")},
            # joint coverage: the share of posterior samples more probable than the truth (uniform
            # over draws when calibrated; under 0.9 = the truth inside the 90 % HPD region)
            "truth_hpd_rank": float(np.mean(post.log_prob > at_truth)),
            "parameters": rows}


def transient_accuracy(results, seeds, walkers, reference):
    """How far each seed's posterior moved from the same seed's at a ``reference`` transient:
    the median's shift in half-widths of the reference's 90 % interval, and the interval's width
    ratio, per parameter (the window is chosen by the accuracy it gives)."""
    out = []
    for seed, res in zip(seeds, results):
        # the reference simulates its own transient, never a shorter one chosen for it
        _, _, ref = run_case(seed, walkers, OUT, reference, choose_transient=False)
        shift, ratio = {}, {}
        for n in NAMES:
            a, b = ref["parameters"][n], res["parameters"][n]
            half = (a["q95"] - a["q05"]) / 2.0
            shift[n] = float((b["q50"] - a["q50"]) / half)
            ratio[n] = float((b["q95"] - b["q05"]) / (a["q95"] - a["q05"]))
        out.append({"seed": seed, "reference_transient": reference,
                    "reference_simulated_seconds": ref["simulated_seconds"],
                    "shift_in_half_widths": shift, "width_ratio": ratio})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("m002", "ridge", "all"), default="all")
    ap.add_argument("--seeds", default="1,2,3,4,5,6,7", help="comma-separated noise seeds")
    ap.add_argument("--ridge-seeds", default="0", help="comma-separated ridge-case truth seeds")
    ap.add_argument("--walkers", type=int, default=10, help="walkers of the M002 case")
    ap.add_argument("--transient", type=float, default=None,
                    help="transient (s) of the M002 case (default: the calibration's, 6 s)")
    ap.add_argument("--reference-transient", type=float, default=None,
                    help="also run the M002 seeds at this transient and report how far each "
                         "posterior moved from it (median shift in half-widths, width ratio)")
    ap.add_argument("--continuation", action="store_true",
                    help="M002 case: each run continues the nearest stored run's cycle "
                         "(Calibration(continuation=True))")
    ap.add_argument("--no-plots", action="store_true")
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "bench.json"
    report = json.loads(path.read_text()) if path.exists() else {}  # the other case's numbers stay
    report.update({"cores": os.cpu_count(), "load_average_before": os.getloadavg()})
    reference = kernel_reference()
    goals = []
    if args.case in ("m002", "all"):
        report.update(_m002(args))
        report["kernel_seconds_per_simulated_second"] = reference
        goals += m002_goals(report, reference)
    if args.case in ("ridge", "all"):
        report["ridge"] = [{**run_ridge_case(int(s), OUT), "commit": CODE_COMMIT}
                           for s in args.ridge_seeds.split(",")]
        report["ridge_goal"] = RIDGE_GOAL
        report["ridge_kernel_seconds_per_simulated_second"] = reference
        goals += ridge_goals(report["ridge"], reference)
        for r in report["ridge"]:
            cells = ", ".join(f"{n} {'in' if c['inside_90'] else 'OUT'} (width "
                              f"{c['relative_width']:.3f})" for n, c in r["parameters"].items())
            print(f"ridge seed {r['seed']}: {r['wall_time_s']:.0f} s, {r['iterations']} steps, "
                  f"converged {r['converged']}, {r['simulated_seconds']:.0f} simulated s, truth's HPD rank "
                  f"{r['truth_hpd_rank']:.2f}; {cells}")
    report["load_average_after"] = os.getloadavg()
    write_json(path, report, default=float)
    print(f"load average before/after: {report['load_average_before']} / "
          f"{report['load_average_after']}")
    print(f"wrote {path}")
    return goal_report(goals)


def m002_goals(report, reference) -> list:
    """The M002 case's goals (module docstring) from its ``report`` and the kernel ``reference``
    (s per simulated second) of the same run."""
    runs = report["runs"]
    n = len(runs)
    return [
        Goal.count("M002 seeds converged", sum(bool(r["converged"]) for r in runs), n),
        Goal.count(f"M002 seeds within {GOAL_SIMULATED_SECONDS:,.0f} simulated seconds",
                   report["seeds_within_goal"], n),
        Goal.speed(f"M002 wall time to a converged posterior, slowest of {n} seeds",
                   max(r["wall_time_s"] for r in runs), reference, report["goal_wall_time_s"]),
    ]


def ridge_goals(rows, reference) -> list:
    """The ridge case's goals, per truth seed (module docstring)."""
    goals = []
    for r in rows:
        cells = r["parameters"].values()
        goals += [
            Goal.flag(f"ridge seed {r['seed']} converged within {r['step_cap']} steps",
                      r["converged"], yes=f"yes, {r['iterations']} steps",
                      no=f"no, {r['iterations']} steps"),
            Goal.count(f"ridge seed {r['seed']} truths inside their 90 % intervals",
                       sum(bool(c["inside_90"]) for c in cells), len(cells)),
            Goal.speed(f"ridge seed {r['seed']} wall time", r["wall_time_s"], reference,
                       RIDGE_GOAL["wall_time_s"]),
        ]
    return goals


def _m002(args) -> dict:
    seeds = [int(s) for s in args.seeds.split(",")]
    results = []
    for seed in seeds:
        cal, rec, res = run_case(seed, args.walkers, OUT, args.transient, args.continuation)
        results.append(res)
        if not args.no_plots:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            fig = cal.posterior_.plot_corner()
            fig.savefig(OUT / f"corner_seed{seed}.png", dpi=80)
            plt.close(fig)
            axes = cal.posterior_.plot_traces()
            axes[0].figure.savefig(OUT / f"traces_seed{seed}.png", dpi=80)
            plt.close(axes[0].figure)
    errors = likelihood_errors(rec)
    print(f"{'seed':>4} {'wall s':>7} {'sims/s':>7} {'steps':>6} {'tau max':>7} {'N/tau':>6} "
          f"{'acc':>5} conv  simulated s")
    for r in results:
        print(f"{r['seed']:>4} {r['wall_time_s']:7.1f} {r['simulations_per_s']:7.0f} "
              f"{r['iterations']:6d} {max(r['tau'].values()):7.1f} {r['n_over_tau']:6.1f} "
              f"{r['acceptance']:5.2f} {r['converged']}  {r['simulated_seconds']:.0f}")
    print(f"\n{'parameter':<10} {'truth':>10} {'q05':>11} {'q50':>11} {'q95':>11} {'z':>6} in90")
    for r in results:
        for n, row in r["parameters"].items():
            print(f"{n:<10} {row['truth']:10.5g} {row['q05']:11.5g} {row['q50']:11.5g} "
                  f"{row['q95']:11.5g} {row['z']:6.2f} {row['inside_90']}")
    print(f"\nlog-likelihood errors at the truth: {errors}")
    simulated = [r["simulated_seconds"] for r in results]
    at_coarse = [r["simulated_seconds_at_5e-4"] for r in results]
    print(f"simulated seconds: median {np.median(simulated):.0f}, "
          f"{sum(v <= GOAL_SIMULATED_SECONDS for v in simulated)} of {len(simulated)} seeds "
          f"<= {GOAL_SIMULATED_SECONDS:.0f}; in steps of 5e-4 s: median {np.median(at_coarse):.0f}, "
          f"{sum(v <= GOAL_SIMULATED_SECONDS for v in at_coarse)} within")
    against = None
    if args.reference_transient is not None:
        against = transient_accuracy(results, seeds, args.walkers, args.reference_transient)
        worst_shift = max(abs(v) for r in against for v in r["shift_in_half_widths"].values())
        ratios = [v for r in against for v in r["width_ratio"].values()]
        print(f"against a {args.reference_transient:g} s transient: medians moved by at most "
              f"{worst_shift:.2f} half-widths, widths {min(ratios):.2f}-{max(ratios):.2f} of its")
    return {
        "commit": CODE_COMMIT,
        "case": "M002, controller A, one 10 s record at 1 kHz, sensor noise 1e-4 rad; "
                "(backlash, dead_zone, delay, sigma), waveform likelihood at its default step, "
                f"{args.walkers} walkers, transient {results[0]['transient']:g} s"
                + (", runs continued from the nearest walker's state" if args.continuation else ""),
        "against_reference_transient": against,
        "goal_wall_time_s": 60.0,
        "goal_simulated_seconds": GOAL_SIMULATED_SECONDS,
        "median_simulated_seconds": float(np.median(simulated)),
        "median_simulated_seconds_at_5e-4": float(np.median(at_coarse)),
        "seeds_within_goal": int(sum(v <= GOAL_SIMULATED_SECONDS for v in simulated)),
        "runs": results,
        "loglike_errors_at_truth": errors,
    }

if __name__ == "__main__":
    sys.exit(main())
