"""Coverage of ``tvcid discover``'s printed intervals: structure and linear block unknown.

``python -m studies.benchmarks.set_coverage [--quick] [--draws N] [--seed S] [--ranges wide|papers]
[--jobs J | --dask ADDRESS] [--out DIR]``

Each draw (:func:`studies.benchmarks.scenarios.draw_scenario`, seeded; the discovery benchmark's
seeds by default) is a truth over every structure of the grammar and a test design over the
generator's ranges (``wide`` by default: thresholds and delays over a decade; limit cycles at
1-3 controller settings, continuous or held at 200 Hz, open-loop squares, sines and staircases or
none, acquisition at 200 Hz to 2 kHz, noise, sensor offset, quantisation). Its recordings are made by the plain-Python reference simulator and written with
measured-style sidecars (commands only as samples); the whole ``tvcid discover`` runs on them
(:func:`tvcid.pipeline.discover`): the structure search, the set, the calibration of every member
and their combination. The row records, for each quantity of the combined posterior
(:mod:`discovery.structure.set_posterior`), whether the truth lies inside the printed 90 %
interval.

Goals, over at least 30 draws: the truth inside the combined 90 % interval in 80-97 % of the
draws for each of the dead zone (the threshold ``z - off`` where the truth's dead zone acts on the
velocity signal: what motion pins), the backlash and the delay; every member's chain converged.
Rows are written to ``DIR/bench.json`` as each draw ends (a rerun resumes); each names the commit
of the code that ran it.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from discovery.structure.set_posterior import member_quantities
from models.strict_json import write_json

from ..common import code_commit
from .draws import add_draw_options, run_benchmark
from .goals import Goal
from .goals import report as goal_report
from .scenarios import draw_scenario, write_recordings

CODE_COMMIT = code_commit()
#: The band the share of truths inside a 90 % interval must fall in.
GOAL_BAND = (0.80, 0.97)
#: Quantities the goals are stated for; ``dead zone`` is the threshold for a velocity-form truth.
GOAL_QUANTITIES = ("dead zone", "backlash", "delay")
#: Draws at least, for the goals to be judged.
MIN_DRAWS = 30


def truth_quantities(truth) -> dict:
    """The combined quantities of the truth itself (:func:`member_quantities` with no draws)."""
    return {k: float(v[0]) for k, v in member_quantities(truth.to_dict(), {}).items()}


def goal_quantity(name, truth_values) -> str:
    """The combined quantity a goal's ``name`` reads for this truth."""
    if name != "dead zone":
        return name
    return "threshold" if "threshold" in truth_values else "dead_zone[error]"


def coverage_row(seed, truth, structure, summary) -> dict:
    """The row of one draw: per quantity the truth, the combined interval and whether it holds
    the truth (a quantity the set lacks, such as the dead zone at the truth's place, counts as
    outside); and the range the recordings allow (:func:`discovery.structure.set_posterior.allowed_range`)
    and whether it holds the truth (``None`` where the run has none)."""
    values = truth_quantities(truth)
    combined = summary["set_posterior"]["quantities"]
    inside = {}
    for name, value in values.items():
        q = combined.get(name)
        held = q is not None and q["q05"] is not None and q["q05"] <= value <= q["q95"]
        allowed = None if q is None else q.get("allowed")
        inside[name] = {"truth": value, "q05": None if q is None else q["q05"],
                        "q95": None if q is None else q["q95"], "inside": bool(held),
                        "allowed": allowed,
                        "inside_allowed": (bool(allowed[0] <= value <= allowed[1]) if allowed
                                           else False if q is None else None)}
    members = summary["set_posterior"]["members"]
    return {
        "seed": seed,
        "structure": structure.name,
        "truth_in_set": structure.name in set(summary["indistinguishable"]),
        "members": [m["structure"] for m in members],
        "converged": all(m["converged"] for m in members),
        "not_pinned": sorted({n for m in members for n in m["posterior"].get("not_pinned", [])}),
        "quantities": inside,
        "goals": {g: inside[goal_quantity(g, values)]["inside"] for g in GOAL_QUANTITIES},
        "goals_allowed": {g: inside[goal_quantity(g, values)]["inside_allowed"]
                          for g in GOAL_QUANTITIES},
        "commit": CODE_COMMIT,
    }


def run_draw(seed, out_dir, quick, ranges="wide") -> dict:
    """Make one draw's recordings, run ``tvcid discover`` on them, and score its intervals."""
    from tvcid.pipeline import discover

    scenario = draw_scenario(seed, ranges=ranges)
    draw_dir = Path(out_dir) / f"draw{seed:03d}"
    t0 = time.perf_counter()
    paths = write_recordings(scenario, draw_dir / "recordings", reuse=True)
    t_data = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = discover(paths, draw_dir / "discover", seed=seed, quick=quick, progress=False).summary
    row = coverage_row(seed, scenario.truth, scenario.structure, summary)
    row.update(design=scenario.to_dict(), seconds_data=t_data,
               seconds_discover=time.perf_counter() - t0,
               seconds_by_stage={k: round(float(v), 1) for k, v in summary["timings"].items()
                                 if isinstance(v, (int, float))})
    return row


def guarded_draw(seed, out_dir, quick, ranges="wide") -> dict:
    """:func:`run_draw`, a failure recorded as a row (the benchmark goes on)."""
    try:
        return run_draw(seed, out_dir, quick, ranges=ranges)
    except Exception as exc:  # noqa: BLE001 - one draw's failure is a result, not a crash
        return {"seed": seed, "error": f"{type(exc).__name__}: {exc}", "ranges": ranges,
                "commit": CODE_COMMIT}


def cycles_only(row) -> bool:
    """Whether the draw's recordings are limit cycles alone (no open-loop test)."""
    kinds = [r["kind"] for r in (row.get("design") or {}).get("recordings", [])]
    return bool(kinds) and "open" not in kinds


def summarise(rows) -> dict:
    """Share of finished draws with the truth inside, per goal quantity and per combined
    quantity; draws converged; truth in the set. ``by_chains`` splits the goals' counts between
    draws whose every chain converged and the others (does a chain stopped at its cap still
    cover?); ``cycles_only`` counts the draws of limit cycles alone and their converged ones;
    ``allowed`` counts, per goal, the truths inside the range the recordings allow, over the
    draws that have one."""
    done = [r for r in rows if "error" not in r]
    n = len(done)

    def inside(part):
        return {g: sum(r["goals"][g] for r in part) for g in GOAL_QUANTITIES}

    per_goal = inside(done)
    names = sorted({q for r in done for q in r["quantities"]})
    per_quantity = {q: {"inside": sum(r["quantities"][q]["inside"] for r in done if q in r["quantities"]),
                        "draws": sum(q in r["quantities"] for r in done)} for q in names}
    by_chains = {}
    for label, converged in (("converged", True), ("stopped at the cap", False)):
        part = [r for r in done if bool(r["converged"]) is converged]
        by_chains[label] = {"draws": len(part), "inside": inside(part)}
    only = [r for r in done if cycles_only(r)]
    allowed = {g: {"inside": sum(bool(r.get("goals_allowed", {}).get(g)) for r in done),
                   "draws": sum(r.get("goals_allowed", {}).get(g) is not None for r in done)}
               for g in GOAL_QUANTITIES}
    return {"draws": n, "failed": len(rows) - n, "inside": per_goal, "quantities": per_quantity,
            "converged": sum(r["converged"] for r in done),
            "truth_in_set": sum(r["truth_in_set"] for r in done), "by_chains": by_chains,
            "cycles_only": {"draws": len(only), "converged": sum(r["converged"] for r in only)},
            "allowed": allowed}


def coverage_goals(table) -> list:
    """The goals of the module's docstring; not met under :data:`MIN_DRAWS` draws."""
    n = table["draws"]
    lo, hi = GOAL_BAND
    goals = []
    for g in GOAL_QUANTITIES:
        k = table["inside"][g]
        share = k / n if n else None
        goals.append(Goal(f"{g}: truth inside the combined 90 % interval",
                          share if n >= MIN_DRAWS else None, low=lo, high=hi, fmt="{:.0%}",
                          shown=f"{k} of {n}" + (f" = {share:.0%}" if share is not None else ""),
                          target=f"{lo:.0%} to {hi:.0%} over >= {MIN_DRAWS} draws"))
    goals.append(Goal.count("draws with every member's chain converged", table["converged"], n))
    return goals


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_draw_options(parser, "short chains (150 steps), 2 draws", 2, "results/bench_set_coverage")
    args = parser.parse_args(argv)

    def describe(row):
        inside = ", ".join(f"{g} {'in' if v else 'OUT'}" for g, v in row["goals"].items())
        return (f"draw {row['seed']}: truth {row['structure']}, set of {len(row['members'])}, "
                f"converged {row['converged']}: {inside} [{row['seconds_discover']:.0f} s]")

    def save(path, rows):
        write_json(path, {"quick": args.quick, "rows": rows, "table": summarise(rows)})

    rows = run_benchmark(args, guarded_draw, describe, save)
    table = summarise(rows)
    print(f"\n{table['draws']} draws ({table['failed']} failed); truth in the set "
          f"{table['truth_in_set']}; chains converged in {table['converged']}")
    for q, c in table["quantities"].items():
        print(f"  {q:22s} inside {c['inside']} of {c['draws']}")
    return goal_report(coverage_goals(table))


if __name__ == "__main__":
    from discovery.parallel import run_interruptible

    raise SystemExit(run_interruptible(main))
