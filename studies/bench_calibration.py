"""Benchmark of the Bayesian calibration (issue 5): wall time to a converged posterior.

Case: M002 at controller A, one 10 s limit-cycle record (the last 10 s of a 20 s run at
dt = 2e-4, 1 kHz), independent Gaussian sensor noise of sd 1e-4 rad (seeded); posterior of
(backlash f, dead_zone zm, delay Td, sigma) with the phase-aligned waveform likelihood at
dt = 5e-4, 16 walkers, DEMove/DESnookerMove, warm start and a 6 s transient, stopping at
N > 50 tau. Goal: under 60 s on 2 cores.

Also measured: simulations per second, tau and N/tau, truth against the 90 % interval, and the
log-likelihood error of the dt = 5e-4 likelihood (against dt = 2e-4) and of the 6 s transient
(against 12 s) at the truth.

Usage: ``python -m studies.bench_calibration [--seeds 7] [--walkers 16]``; writes
``results/bench_calibration/bench.json`` and corner/trace plots. Other jobs on the machine
inflate the wall time; the load average is recorded.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from discovery.calibration import Calibration, synthetic_recording
from models import CONTROLLER_A, M002

OUT = Path("results/bench_calibration")
NAMES = ("backlash", "dead_zone", "delay", "sigma")


def likelihood_errors(rec):
    """|ll(dt=5e-4) - ll(dt=2e-4)| and |ll(6 s transient) - ll(12 s)| at the truth."""
    truth = M002()
    out = {}
    ref = Calibration("M002", params=("backlash",), dt=2e-4, transient=12.0).setup([rec])
    ll_ref = ref.log_posterior_.terms[0].loglike([truth], np.array([1e-4]))[0]
    for label, kw in (("dt_5e-4", dict(dt=5e-4, transient=12.0)),
                      ("transient_6s", dict(dt=2e-4, transient=6.0)),
                      ("default", dict(dt=5e-4, transient=6.0))):
        cal = Calibration("M002", params=("backlash",), **kw).setup([rec])
        ll = cal.log_posterior_.terms[0].loglike([truth], np.array([1e-4]))[0]
        out[label] = float(abs(ll - ll_ref))
    return out


def run_case(seed, walkers, workdir):
    rec = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, seed, workdir / f"m002_A_{seed}.csv",
                              keep_last=10.0)
    t0 = time.perf_counter()
    cal = Calibration("M002", params=NAMES, n_walkers=walkers, max_steps=5000, seed=seed)
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
        "wall_time_s": wall,
        "sampling_time_s": rep.wall_time,
        "setup_and_start_s": wall - rep.wall_time,
        "simulations": sims,
        # total seconds simulated to convergence (issue 12 goal: <= 40,000 for this case)
        "simulated_seconds": cal.log_posterior_.simulated_seconds,
        "simulations_per_s": sims / wall,
        "iterations": rep.iterations,
        "tau": dict(zip(NAMES, rep.tau)),
        "n_over_tau": rep.n_over_tau,
        "acceptance": rep.acceptance,
        "converged": rep.converged,
        "parameters": rows,
        "correlation": post.summary()["correlation"],
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="7", help="comma-separated noise seeds")
    ap.add_argument("--walkers", type=int, default=16)
    ap.add_argument("--no-plots", action="store_true")
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    seeds = [int(s) for s in args.seeds.split(",")]
    load_before = os.getloadavg()
    results = []
    for seed in seeds:
        cal, rec, res = run_case(seed, args.walkers, OUT)
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
    report = {
        "case": "M002, controller A, one 10 s record at 1 kHz, sensor noise 1e-4 rad; "
                "(backlash, dead_zone, delay, sigma), waveform likelihood, dt 5e-4, 16 walkers",
        "cores": os.cpu_count(),
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "goal_wall_time_s": 60.0,
        "runs": results,
        "loglike_errors_at_truth": errors,
    }
    (OUT / "bench.json").write_text(json.dumps(report, indent=2, default=float) + "\n")
    print(f"{'seed':>4} {'wall s':>7} {'sims/s':>7} {'steps':>6} {'tau max':>7} {'N/tau':>6} "
          f"{'acc':>5} conv")
    for r in results:
        print(f"{r['seed']:>4} {r['wall_time_s']:7.1f} {r['simulations_per_s']:7.0f} "
              f"{r['iterations']:6d} {max(r['tau'].values()):7.1f} {r['n_over_tau']:6.1f} "
              f"{r['acceptance']:5.2f} {r['converged']}")
    print(f"\n{'parameter':<10} {'truth':>10} {'q05':>11} {'q50':>11} {'q95':>11} {'z':>6} in90")
    for r in results:
        for n, row in r["parameters"].items():
            print(f"{n:<10} {row['truth']:10.5g} {row['q05']:11.5g} {row['q50']:11.5g} "
                  f"{row['q95']:11.5g} {row['z']:6.2f} {row['inside_90']}")
    print(f"\nlog-likelihood errors at the truth: {errors}")
    print(f"load average before/after: {load_before} / {report['load_average_after']}")
    print(f"wrote {OUT / 'bench.json'}")


if __name__ == "__main__":
    main()
