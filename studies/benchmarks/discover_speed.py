"""Speed of ``tvcid discover`` on four recordings of M000 (goal: <= 10 minutes on 2 cores).

``python -m tvcid.studies.benchmarks.discover_speed [--search standard|thorough] [--out DIR]``

The recordings are M000's (the bundled set's model and noise, ``data/generate.py``): limit cycles at
controllers A and B of 40 s, an open-loop square (+-20 mrad, 1 Hz) and sine (20 mrad, 2 Hz) of 10 s,
1 kHz, written with measured-style sidecars (no hypothesis, no parameters, the commands only as
samples). ``tvcid discover`` runs on them as a user would run it (default options: SINDy, the
searches, the ranking, the MCMC to convergence) and ``DIR/bench.json`` records (:func:`record`),
per stage and per member of the set, the kernel steps (``simulated_steps``), the nominal
simulated seconds, the CPU seconds and the wall seconds (``stages``), beside the goal (600 s), the
machine's cores, its load average before and after, the commit of the code, and two references
measured in the same run. The batch kernel's wall time per simulated second
(:func:`tvcid.studies.benchmarks.goals.kernel_reference`: 64 closed-loop runs of M000 at the search's
5e-4 s step), so that a slower machine can be told from a slower discovery
(``discovery_in_kernel_seconds``: the discovery's wall time over that reference); the goal is judged
on that ratio (:meth:`tvcid.studies.benchmarks.goals.Goal.speed`). And the kernel's CPU seconds per step
(:func:`tvcid.discovery.speed.kernel_reference`) before and after the run: a run whose two references
differ by more than 10 %, or that starts at a 1-minute load average above 0.5, is flagged
(``idle_check``, with the reason) and not judged as the speed. The last line printed is the goal,
met or NOT met, or the flag; so is the exit status (0 met, 1 not, 2 flagged). Non-finite numbers
are written as ``null``. ``bench.json`` also holds the run's answers (:func:`answers`) and, with
``--compare`` an earlier run's ``bench.json`` or ``discovery.json``, how far they moved
(:func:`compare_answers`: the same winner and set, and each interval of a member carrying weight
within 0.2 of its width).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from tvcid.discovery.structure.structure_search import SEARCHES
from tvcid.models import CONTROLLER_A, CONTROLLER_B, OpenLoop, hypothesis, simulate
from tvcid.models.recording import recording_from_trajectory, save_recording
from tvcid.models.strict_json import write_json

from tvcid.discovery.speed import idle_check
from tvcid.discovery.speed import kernel_reference as cpu_per_step

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


def record(summary, wall, load_average, before, after) -> dict:
    """What ``bench.json`` holds of one timed ``tvcid discover`` beyond the set-up.

    Parameters
    ----------
    summary : dict
        The run's ``discovery.json``.
    wall : float
        Its wall time (s).
    load_average : sequence of float
        :func:`os.getloadavg` at its start.
    before, after : float
        :func:`tvcid.discovery.speed.kernel_reference` (CPU seconds per kernel step) before and after.

    Returns
    -------
    dict
        ``wall_seconds``; ``stages`` (wall), ``cpu_seconds``, ``simulated_seconds`` and
        ``simulated_steps`` per stage; ``members`` (each member's structure, steps, simulated,
        CPU and wall seconds); the references and ``idle_check``
        (:func:`tvcid.discovery.speed.idle_check` on the 1-minute load average); the chain's
        convergence and steps (points, for an importance-sampled winner: ``sampler``), the
        winner and the run's answers (:func:`answers`).
    """
    members = (summary.get("set_posterior") or {}).get("members") or ()
    return {
        "wall_seconds": wall,
        "stages": summary["timings"],
        "cpu_seconds": summary.get("cpu_seconds"),
        "simulations": summary["simulations"],
        "simulated_seconds": summary.get("simulated_seconds"),
        "simulated_steps": summary.get("simulated_steps"),
        "members": [{k: m.get(k) for k in ("structure", "simulated_steps", "simulated_seconds",
                                            "cpu_seconds", "wall_seconds")} for m in members],
        "load_average_start": list(load_average),
        "kernel_cpu_seconds_per_step": {"before": before, "after": after},
        "idle_check": idle_check(load_average[0], before, after),
        "converged": summary["posterior"]["converged"],
        "mcmc_steps": summary["posterior"]["iterations"],
        "sampler": summary["posterior"].get("sampler", "ensemble"),
        "winner": summary["structures"][0]["structure"],
        "answers": answers(summary),
    }


#: A member carries weight from this share on (the set's deciding share).
CARRIES_WEIGHT = 0.05


def answers(summary) -> dict:
    """What a run answers, to compare with another run on the same recordings: the winner, the
    set (its structures, in the ranking's order), each calibrated member's weight and its
    quantities' 90 % intervals."""
    sp = summary.get("set_posterior") or {}
    return {"winner": summary["structures"][0]["structure"],
            "set": list(summary["indistinguishable"]),
            "members": {m["structure"]: {
                "weight": m.get("weight"),
                "intervals": {q: [v["q05"], v["q95"]] for q, v in m["quantities"].items()}}
                for m in sp.get("members") or ()}}


def compare_answers(now, before) -> dict:
    """``now``'s answers (:func:`answers`) against ``before``'s: the same winner and set (its
    structures, in whatever order the ranking's scores put them), and for
    every member carrying weight in either (``CARRIES_WEIGHT``) each quantity's 90 % interval's
    ends moved by ``(|q05 - q05'| + |q95 - q95'|) / (q95' - q05')``, ``before``'s width;
    ``largest_move`` over them, and ``same`` when the winner and set agree and no move reaches
    0.2."""
    moves = {}
    for name in set(now["members"]) | set(before["members"]):
        a, b = now["members"].get(name), before["members"].get(name)
        heavy = max((m or {}).get("weight") or 0.0 for m in (a, b)) >= CARRIES_WEIGHT
        if not heavy:
            continue
        if a is None or b is None:
            moves[name] = {"missing": "now" if a is None else "before"}
            continue
        for q, (lo, hi) in b["intervals"].items():
            if q in a["intervals"] and hi > lo:
                lo2, hi2 = a["intervals"][q]
                moves.setdefault(name, {})[q] = (abs(lo2 - lo) + abs(hi2 - hi)) / (hi - lo)
    values = [v for m in moves.values() for v in m.values() if isinstance(v, float)]
    missing = [n for n, m in moves.items() if "missing" in m]
    largest = max(values) if values else 0.0
    same_set = sorted(now["set"]) == sorted(before["set"])
    return {"same_winner": now["winner"] == before["winner"],
            "same_set": same_set, "moves": moves,
            "largest_move": largest, "missing": missing,
            "same": (now["winner"] == before["winner"] and same_set
                     and not missing and largest < 0.2)}


def main(argv=None) -> int:
    from tvcid.pipeline import discover

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--search", default="standard", choices=tuple(SEARCHES))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(OUT))
    parser.add_argument("--compare", default=None,
                        help="a bench.json or discovery.json of an earlier run on the same "
                             "recordings: its answers are compared with this run's")
    parser.add_argument("--compare-commit", default=None,
                        help="the commit a --compare discovery.json was made at")
    args = parser.parse_args(argv)
    before_answers = (_answers_of(Path(args.compare), args.compare_commit) if args.compare
                      else None)
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
    before = cpu_per_step()
    t0 = time.perf_counter()
    summary = discover(paths, run_dir, seed=args.seed, search=args.search, progress=False).summary
    wall = time.perf_counter() - t0
    # the load before any of the benchmark's own work (its recordings, its references)
    report.update(record(summary, wall, report["load_average_before"], before, cpu_per_step()))
    report["load_average_after"] = os.getloadavg()
    report["discovery_in_kernel_seconds"] = wall / report["kernel_seconds_per_simulated_second"]
    goal = Goal.speed(f"tvcid discover ({args.search}) wall time on {os.cpu_count()} cores",
                      wall, report["kernel_seconds_per_simulated_second"], GOAL_SECONDS)
    flag = report["idle_check"]
    report["goal_met"] = goal.met if flag["passed"] else None  # a flagged run is not the speed
    report["goals"] = [goal.to_dict()]
    if before_answers is not None:
        report["compared_with"] = {"commit": before_answers[0],
                                   **compare_answers(report["answers"], before_answers[1]),
                                   "simulated_steps": before_answers[2]}
    write_json(out / "bench.json", report, default=str)
    stages = ", ".join(f"{k} {v:.0f} s" for k, v in summary["timings"].items()
                       if k not in ("total", "discovery"))
    unit = "points" if report["sampler"] == "importance" else "steps"
    print(f"tvcid discover ({args.search}) on 2 x 40 s cycles + 2 x 10 s open-loop tests: "
          f"{wall:.0f} s wall on {os.cpu_count()} cores; {stages}; "
          f"{summary['simulations']} simulations; the winner's posterior "
          f"{summary['posterior']['iterations']} {unit}, "
          f"converged {summary['posterior']['converged']}; load average "
          f"{report['load_average_before']} -> {report['load_average_after']}")
    if not flag["passed"]:
        print(f"flagged, not the speed: {flag['reason']}")
        return 2
    return goal_report([goal])


def _answers_of(path, args_commit=None):
    """``(commit, answers, kernel steps per stage)`` of a stored ``bench.json`` (its
    ``answers``) or of a run's ``discovery.json`` (made at ``args_commit``, or None)."""
    import json

    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"--compare {path}: cannot read it ({exc})") from None
    if "answers" in data:
        return data.get("commit"), data["answers"], data.get("simulated_steps")
    if "set_posterior" in data:
        return args_commit, answers(data), data.get("simulated_steps")
    raise SystemExit(f"--compare {path}: neither a bench.json with answers nor a discovery.json "
                     "with a set's posterior")


if __name__ == "__main__":
    sys.exit(main())
