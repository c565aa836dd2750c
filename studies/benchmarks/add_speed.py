"""Cost of ``tvcid discover --add`` against a fresh run on the same recordings (goal: at most a
third, the same ranking within the set's margin).

``python -m tvcid.studies.benchmarks.add_speed [--seed S] [--out DIR]``

The recordings are the speed benchmark's (:mod:`tvcid.studies.benchmarks.discover_speed`: M000's limit
cycles at controllers A and B, 40 s, an open-loop square and sine, 10 s, measured-style
sidecars). An earlier run ranks the structures on the two cycles and the square; ``--add`` then
adds the sine (:func:`tvcid.pipeline.add_recordings`); a fresh run ranks them on all four
(:func:`tvcid.pipeline.discover`). Both stop after the ranking and the next test (``--no-mcmc``):
the calibration of the set starts again in either case and costs the same. Deciding figures: the
ratio of ``--add``'s simulations and wall time to the fresh run's (ranking stage and whole run),
whether the set is the same, and the difference of the winners' scores against the set's margin
(the winner itself may be another member of the set: the data do not rank them). ``DIR/bench.json`` holds them with the commit and the machine's load average;
the goals are printed as met or NOT met and set the exit status.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

from tvcid.models.strict_json import write_json

from ..common import code_commit
from .discover_speed import write_recordings
from .goals import Goal
from .goals import report as goal_report

OUT = Path("results/bench_add_speed")
#: ``--add`` costs at most this fraction of a fresh run.
GOAL_RATIO = 1 / 3


def _timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    result = fn(*args, **kwargs)
    return result.summary, time.perf_counter() - t0


def main(argv=None) -> int:
    from tvcid.pipeline import add_recordings, discover

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args(argv)
    out = Path(args.out)
    paths = write_recordings(out / "recordings")
    earlier_paths, new = paths[:3], paths[3]
    for d in ("fresh", "loop"):  # finished rankings would be reused: time fresh runs
        shutil.rmtree(out / d, ignore_errors=True)
    report = {"cores": os.cpu_count(), "load_average_before": os.getloadavg(),
              "commit": code_commit(), "earlier": [p.name for p in earlier_paths], "added": new.name}
    fresh, t_fresh = _timed(discover, paths, out / "fresh", seed=args.seed, mcmc=False,
                            progress=False)
    earlier, t_earlier = _timed(discover, earlier_paths, out / "loop", seed=args.seed, mcmc=False,
                                progress=False)
    loop, t_loop = _timed(add_recordings, [new], out / "loop", mcmc=False, progress=False)
    best_f, best_l = fresh["structures"][0], loop["structures"][0]
    margin = best_f.get("margin") or 0.0
    report.update({
        "fresh": {"wall_seconds": t_fresh, "ranking_seconds": fresh["timings"]["discovery"],
                  "simulations": fresh["simulations"], "set": fresh["indistinguishable"],
                  "winner": best_f["structure"], "score": best_f["score"], "margin": margin},
        "earlier": {"wall_seconds": t_earlier, "simulations": earlier["simulations"],
                    "set": earlier["indistinguishable"]},
        "add": {"wall_seconds": t_loop, "ranking_seconds": loop["timings"]["discovery"],
                "simulations": loop["simulations"], "set": loop["indistinguishable"],
                "winner": best_l["structure"], "score": best_l["score"]},
        "load_average_after": os.getloadavg(),
    })
    sims = loop["simulations"] / fresh["simulations"]
    wall = t_loop / t_fresh
    ranking = loop["timings"]["discovery"] / fresh["timings"]["discovery"]
    same_set = set(loop["indistinguishable"]) == set(fresh["indistinguishable"])
    within = abs(best_l["score"] - best_f["score"]) <= margin
    report["ratios"] = {"simulations": sims, "wall": wall, "ranking_wall": ranking}
    goals = [
        Goal.at_most("--add's simulations over a fresh run's", sims, GOAL_RATIO, fmt="{:.2f}"),
        Goal.at_most("--add's wall time over a fresh run's (same machine, same run)", wall,
                     GOAL_RATIO, fmt="{:.2f}"),
        Goal.flag("the fresh run's set, the winners' scores within the set's margin",
                  same_set and within),
    ]
    report["goals"] = [g.to_dict() for g in goals]
    write_json(out / "bench.json", report, default=str)
    print(f"fresh run on 4 recordings: {t_fresh:.0f} s ({fresh['timings']['discovery']:.0f} s "
          f"ranking), {fresh['simulations']} simulations; --add of {new.name} to a run on 3: "
          f"{t_loop:.0f} s ({loop['timings']['discovery']:.0f} s ranking), {loop['simulations']} "
          f"simulations; ratios {sims:.2f} (simulations), {wall:.2f} (wall), {ranking:.2f} "
          f"(ranking wall); winner {best_l['structure']} vs {best_f['structure']}, set "
          f"{'the same' if same_set else 'different'}, scores {best_l['score']:.4g} vs "
          f"{best_f['score']:.4g} (margin {margin:.3g}); load average "
          f"{report['load_average_before']} -> {report['load_average_after']}")
    return goal_report(goals)


if __name__ == "__main__":
    sys.exit(main())
