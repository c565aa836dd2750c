"""Benchmark of the calibration's likelihood terms simulated in threads (one per recording).

``python -m tvcid.studies.benchmarks.likelihood_threads [--quick] [--seed N] [--out DIR]``

The log posterior of paper 000's model on the four bundled M000 recordings (two limit cycles
through their features, two open-loop tests through the output error; every parameter of the
structure sampled, as the set's calibration does) is evaluated at one point (what the start's
searches evaluate) and at a batch of 40 (a step of the ensemble), with the terms simulated
concurrently (:func:`tvcid.discovery.threads.thread_map`) and in a plain loop, interleaved, the median
of the repeats kept. Every figure is a ratio measured in this run on this machine. Where a
point's time goes is printed and kept too (:func:`term_costs`): each recording's share of the
batch, the seconds it simulates per point and at which step.

Goals: the same numbers bit for bit; one point at least 1.3x as fast threaded, a batch at least
as fast (on 2 or more cores). Writes ``DIR/bench.json`` (default ``results/bench_likelihood_threads``)
with the commit of the code that ran.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

import tvcid.discovery.threads as threads
from tvcid.data import path as bundled_path
from tvcid.models import M000
from tvcid.models.recording import load_recording
from tvcid.models.strict_json import write_json
from tvcid.models.structures import Structure

from ..common import code_commit
from .goals import Goal, report

DATA = bundled_path()
RECORDINGS = ("m000_closed_A", "m000_closed_B", "m000_open_square", "m000_open_sine")
#: Points of a batch (a step of an ensemble of 40 walkers).
BATCH = 40
#: Goals: speed-up of one point, of a batch (threaded over the loop).
GOALS = {"point": 1.3, "batch": 1.0}


def log_posterior():
    """The set member calibration's log posterior of M000 on the bundled recordings."""
    from tvcid.discovery.calibration import Calibration
    from tvcid.discovery.members.member_calibration import member_priors, member_walkers

    truth = M000()
    structure = Structure.of_params(truth)
    names = tuple(n for n in structure.parameter_names()
                  if n != "bandpass_saturation" or np.isfinite(truth.bandpass_saturation))
    recs = [load_recording(DATA / f"{name}.csv") for name in RECORDINGS]
    priors = member_priors(truth, structure, names, 6e-4)
    cal = Calibration(truth, params=names, priors=priors, likelihood="features", window=10.0, seed=0,
                      n_walkers=member_walkers(len(names))).setup(recs)
    return cal.log_posterior_, names


def term_costs(lp, z, repeats) -> dict:
    """Per recording (likelihood term), for the batch ``z`` evaluated term by term: the median
    seconds per point, the share of the sum, the seconds simulated per point (transient and window
    in closed loop, the record in open loop) and the RK4 step: the simulated length and the step
    set a point's cost."""
    _, x, sets = lp._prepare(z)
    sigma = lp.sigmas(x)
    out = {}
    for term in lp.terms:
        seconds = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            term.loglike(sets, sigma)
            seconds.append(time.perf_counter() - t0)
        sim = term.simulator
        out[term.name] = {"seconds_per_point": float(np.median(seconds)) / len(z),
                          "simulated_seconds": float(sim.t_end), "step": float(sim.dt)}
    total = sum(v["seconds_per_point"] for v in out.values())
    for v in out.values():
        v["share"] = v["seconds_per_point"] / total
    return out


def timed(lp, z, threaded):
    """Seconds of one ``lp(z)`` with the terms threaded or not, and its values."""
    threads.THREADED = threaded
    t0 = time.perf_counter()
    value = lp(z)
    return time.perf_counter() - t0, value


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats (smoke test)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the points' jitter")
    parser.add_argument("--out", default="results/bench_likelihood_threads", help="output directory")
    args = parser.parse_args(argv)
    repeats = 2 if args.quick else 9
    lp, names = log_posterior()
    truth = M000()
    centre = lp.internal(np.array([[getattr(truth, n) for n in names]]))[0]
    # 1 % of each parameter: in the log where the prior samples the log, else of its value
    scale = np.array([0.01 if p.log else 0.01 * abs(getattr(truth, n))
                      for n, p in zip(names, lp.priors)])
    rng = np.random.default_rng(args.seed)
    batch = centre + scale * rng.standard_normal((BATCH, len(names)))
    finite = int(np.sum(np.isfinite(lp(batch))))  # compiled and warm
    if finite < BATCH or not np.isfinite(lp(centre[None, :]))[0]:
        raise RuntimeError(f"only {finite} of {BATCH} points have a finite log posterior")
    rows, same = {}, True
    try:
        for label, z in (("point", centre[None, :]), ("batch", batch)):
            t_loop, t_threads = [], []
            for _ in range(repeats):  # interleaved: a slower moment of the machine hits both
                s, a = timed(lp, z, False)
                t_loop.append(s)
                s, b = timed(lp, z, True)
                t_threads.append(s)
                same = same and np.array_equal(a, b)
            rows[label] = {"points": len(z), "seconds_loop": float(np.median(t_loop)),
                           "seconds_threaded": float(np.median(t_threads))}
            rows[label]["speedup"] = rows[label]["seconds_loop"] / rows[label]["seconds_threaded"]
    finally:
        threads.THREADED = True
    for label, r in rows.items():
        print(f"{label:6s} {r['points']:3d} points: loop {1e3 * r['seconds_loop']:8.1f} ms, "
              f"threaded {1e3 * r['seconds_threaded']:8.1f} ms, x{r['speedup']:.2f}")
    terms = term_costs(lp, batch, repeats)
    for name, t in terms.items():
        print(f"  {name:18s} {1e3 * t['seconds_per_point']:6.2f} ms per point ({t['share']:.0%}): "
              f"{t['simulated_seconds']:.1f} s simulated at a {1e3 * t['step']:.4g} ms step")
    goals = [Goal("threaded and plain-loop log posteriors equal bit for bit", float(same), low=1.0,
                  fmt="{:.0f}", shown="equal" if same else "different", target="equal"),
             Goal(f"one point threaded, speed-up on {os.cpu_count()} cores", rows["point"]["speedup"],
                  low=GOALS["point"], fmt="{:.2f}"),
             Goal(f"a batch of {BATCH} threaded, speed-up on {os.cpu_count()} cores",
                  rows["batch"]["speedup"], low=GOALS["batch"], fmt="{:.2f}")]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "bench.json", {"commit": code_commit(), "quick": args.quick,
                                    "repeats": repeats, "cores": os.cpu_count(), "rows": rows,
                                    "terms": terms,
                                    "equal": same, "goals_met": [g.met for g in goals],
                                    "load_average_after": os.getloadavg()})
    return report(goals)


if __name__ == "__main__":
    sys.exit(main())
