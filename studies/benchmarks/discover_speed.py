"""Speed of ``tvcid discover`` on four recordings of M000 (goal: <= 10 minutes on 2 cores).

``python -m studies.benchmarks.discover_speed [--search standard|thorough] [--out DIR]``

The recordings are M000's (the bundled set's model and noise, ``data/generate.py``): limit cycles at
controllers A and B of 40 s, an open-loop square (+-20 mrad, 1 Hz) and sine (20 mrad, 2 Hz) of 10 s,
1 kHz, written with measured-style sidecars (no hypothesis, no parameters, the commands only as
samples). ``tvcid discover`` runs on them as a user would run it (default options: SINDy, the
searches, the ranking, the MCMC to convergence) and the wall time of every stage is written to
``DIR/bench.json`` beside the goal (600 s), the machine's cores, its load average before and after,
the commit of the code, and a reference measured in the same run: the batch kernel's wall time per
simulated second (:func:`studies.benchmarks.goals.kernel_reference`: 64 closed-loop runs of M000 at
the search's 5e-4 s step), so that a slower machine can be told from a slower discovery
(``discovery_in_kernel_seconds``: the discovery's wall time over that reference). The goal is judged
on that ratio (:meth:`studies.benchmarks.goals.Goal.speed`); the last line printed is the goal, met
or NOT met, and so is the exit status (0 met, 1 not). Non-finite numbers are written as ``null``.
Other jobs inflate the times; run it on an idle machine.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from discovery.structure.structure_search import SEARCHES
from models import CONTROLLER_A, CONTROLLER_B, OpenLoop, hypothesis, simulate
from models.recording import recording_from_trajectory, save_recording
from models.strict_json import write_json

from ..common import code_commit
from .goals import Goal, kernel_reference
from .goals import report as goal_report

OUT = Path("results/bench_discover_speed")
GOAL_SECONDS = 600.0
#: The design: (name, experiment, seconds, noise seed).
RECORDINGS = (
    ("closed_A", CONTROLLER_A, 40.0, 1),
    ("closed_B", CONTROLLER_B, 40.0, 2),
    ("open_square", OpenLoop.square(2e-2, 1.0), 10.0, 3),
    ("open_sine", OpenLoop.sine(2e-2, 2.0), 10.0, 4),
)
NOISE = dict(noise_power=4e-13, noise_band=500.0)
#: Sidecar keys a measured recording carries (commands only as samples).
MEASURED_KEYS = ("kind", "kp", "kd", "mu", "controller_rate", "units")


def write_recordings(out_dir: Path) -> list:
    """M000's four recordings at the issue's lengths, with measured-style sidecars."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, experiment, seconds, seed in RECORDINGS:
        params = hypothesis("M000", noise_seed=seed, **NOISE)
        tr = simulate(params, experiment, seconds, rate=1000.0)
        columns, meta = recording_from_trajectory(tr)
        keep = ("t", "u", "delta")
        measured = {k: meta[k] for k in MEASURED_KEYS if k in meta}
        measured["units"] = {k: meta["units"][k] for k in keep}
        paths.append(save_recording(out_dir / f"m000_{name}.csv", {k: columns[k] for k in keep},
                                    measured))
    return paths


def main(argv=None) -> int:
    from tvcid.pipeline import discover

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--search", default="standard", choices=tuple(SEARCHES))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args(argv)
    out = Path(args.out)
    paths = write_recordings(out / "recordings")
    report = {"cores": os.cpu_count(), "load_average_before": os.getloadavg(),
              "commit": code_commit(), "search": args.search, "goal_seconds": GOAL_SECONDS,
              "recordings": [p.name for p in paths]}
    report["kernel_seconds_per_simulated_second"] = kernel_reference()
    run_dir = out / f"run-{args.search}"
    if run_dir.exists():  # a finished ranking would be reused: time a fresh run
        for f in run_dir.iterdir():
            f.unlink()
    t0 = time.perf_counter()
    summary = discover(paths, run_dir, seed=args.seed, search=args.search, progress=False).summary
    wall = time.perf_counter() - t0
    report.update({
        "wall_seconds": wall,
        "stages": summary["timings"],
        "simulations": summary["simulations"],
        "simulated_seconds": summary.get("simulated_seconds"),
        "converged": summary["posterior"]["converged"],
        "mcmc_steps": summary["posterior"]["iterations"],
        "winner": summary["structures"][0]["structure"],
        "load_average_after": os.getloadavg(),
    })
    report["discovery_in_kernel_seconds"] = wall / report["kernel_seconds_per_simulated_second"]
    goal = Goal.speed(f"tvcid discover ({args.search}) wall time on {os.cpu_count()} cores",
                      wall, report["kernel_seconds_per_simulated_second"], GOAL_SECONDS)
    report["goal_met"] = goal.met
    report["goals"] = [goal.to_dict()]
    write_json(out / "bench.json", report, default=str)
    stages = ", ".join(f"{k} {v:.0f} s" for k, v in summary["timings"].items()
                       if k not in ("total", "discovery"))
    print(f"tvcid discover ({args.search}) on 2 x 40 s cycles + 2 x 10 s open-loop tests: "
          f"{wall:.0f} s wall on {os.cpu_count()} cores; {stages}; "
          f"{summary['simulations']} simulations; MCMC {summary['posterior']['iterations']} steps, "
          f"converged {summary['posterior']['converged']}; load average "
          f"{report['load_average_before']} -> {report['load_average_after']}")
    return goal_report([goal])


if __name__ == "__main__":
    sys.exit(main())
