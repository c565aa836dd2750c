"""Does following the suggested tests close the set? The experiment-loop benchmark.

``python -m tvcid.studies.benchmarks.loop [--quick] [--draws N] [--seed S] [--ranges wide|papers]
[--jobs J | --dask ADDRESS] [--out DIR] [--reuse SET_COVERAGE_DIR [--wait-for-reuse]]``

For each draw of the discovery benchmark (:func:`tvcid.studies.benchmarks.scenarios.draw_scenario`,
the same seeds and ``--ranges``), ``tvcid discover`` runs on the draw's recordings (:func:`tvcid.pipeline.discover`,
the set calibrated); then, up to ``--rounds`` times while the set is not closed, the suggested
next test is recorded from the truth by the plain-Python reference path, measured by the draw's
sensor and read back as a measured recording, and added to the run
(:func:`tvcid.pipeline.add_recordings`). After every round the row records:

* the set (its unmerged members), whether it holds the truth's structure;
* the fit ceiling: the minimal structures that fit the recordings at least as well as the true
  parameters themselves (:func:`tvcid.studies.benchmarks.verdicts.as_well_as_truth`); no rule
  based on the fit can report a set smaller than that;
* whether the set is *closed* (:func:`tvcid.discovery.prediction.closure.set_closure`): one structure,
  or members whose posterior responses to every test of the menu and whose predicted cycles at
  three controller settings the recordings did not use agree within their bands, a calibrated
  member the data decide against (under the deciding share of the set's weight, its weight
  final) not counted (``not_counted``; ``unsure``: members counted whatever their weight; each
  test's and setting's pairs are kept under ``closure``, and the verdict counting every member
  beside it); whether the truth's member is counted (``truth_counted``); at round 0,
  whether the menu *can decide*: the set is closed, or a test of the menu parts two counted members
  (members that part only at unseen controller settings leave the menu nothing to decide);
* what the run cost (:meth:`tvcid.run_record.RunCost.totals`: kernel steps, CPU and wall seconds)
  and, after each ``--add``, what a fresh ``tvcid discover`` on the same recordings costs, with
  its set: the ratio of the two is what the experiment loop saves.

Goals, over at least 10 draws: the truth in the set, its member counted, at every round in every
draw (a set closed on members the truth's is not among has closed on a wrong answer); the set closed
after at most two rounds in at least 80 % of the draws whose menu can decide; an ``--add``'s
kernel steps at most a third of the fresh run's in the median and never above it; the set no
larger than the fit ceiling's + 1 in at least 90 % of the draws (round 0). A round resumed from
an interrupted run (its run directory, or the fresh run's, already there) counts only what its
last process did: its costs are left out of the ratios (``resumed``). Rows are written to
``DIR/bench.json`` as each draw ends (a rerun resumes), each naming the commit of the code that
ran it. Round 0 is the set-coverage benchmark's discovery of the same draw: ``--reuse DIR``
takes it from that benchmark's output rather than running it again (its cost is that run's),
once that benchmark has finished the draw; ``--wait-for-reuse`` waits for it, so the loop can run
beside the set coverage.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import shutil
import time
from pathlib import Path

import numpy as np

from tvcid.models.strict_json import write_json
from tvcid.run_record import RunCost

from ..common import code_commit, failure, machine
from .discovery import recordings_cost_at_truth
from .draws import add_draw_options, run_benchmark
from .goals import Goal
from .goals import report as goal_report
from .scenarios import design_of, draw_scenario, record_added_test, write_recordings
from .verdicts import as_well_as_truth

CODE_COMMIT = code_commit()
MACHINE = machine()
#: Rounds of the loop at most (suggested tests added one after the other).
ROUNDS = 2
#: Goals: truth in the set at every round (share of the draws), closed after the rounds (share
#: of the draws whose menu can decide), an --add's kernel steps over a fresh run's (median), set
#: within ceiling + 1.
TRUTH_IN_SET = 1.0
CLOSED = 0.80
ADD_RATIO = 1 / 3
AT_CEILING = 0.90
MIN_DRAWS = 10
#: Controller settings the closure is judged at: drawn over the generator's range for a
#: third setting (Kp, Kd, mu), seeded by the draw.
UNSEEN_SETTINGS = 3


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """What one draw of the loop runs.

    Attributes
    ----------
    rounds : int
        Suggested tests added at most.
    max_steps : int or None
        Chain length of every member's calibration (``None``: the pipeline's, 2000).
    closure_draws : int
        Posterior draws per member the closure simulates.
    fixed : dict or None
        Structural choices given to the discovery (tests cut the search with it).
    """

    rounds: int = ROUNDS
    max_steps: int | None = None
    closure_draws: int = 24
    fixed: dict | None = None


FULL = LoopConfig()
QUICK = LoopConfig(rounds=1, max_steps=150, closure_draws=8)


def unseen_settings(seed, controller_rate, n=UNSEEN_SETTINGS):
    """``n`` controller settings drawn over the scenario generator's range for a free setting
    (Kp U(4, 12), Kd U(0.04, 0.08), mu U(4, 14)) by ``default_rng([seed, 7])``."""
    from tvcid.discovery.prediction.settings import ControllerSetting

    rng = np.random.default_rng([seed, 7])
    return [ControllerSetting(float(rng.uniform(4, 12)), float(rng.uniform(0.04, 0.08)),
                              float(rng.uniform(4, 14)), sample_rate=controller_rate)
            for _ in range(n)]


def round_row(k, summary, out_dir, scenario, config, seed) -> dict:
    """What round ``k`` of a draw leaves: the set, the truth in it, the fit ceiling, closure,
    whether the menu can decide, what the run cost."""
    from tvcid.discovery.prediction.draws import (
        load_set_draws,
        load_set_weights,
        load_unsure_members,
    )
    from tvcid.discovery.prediction.set_prediction import measurement_resolution
    from tvcid.discovery.prediction.closure import set_closure
    from tvcid.discovery.prediction.discrimination import default_candidates
    from tvcid.models.recording import load_recordings
    from tvcid.pipeline import median_sensor_noise

    truth = scenario.structure
    recordings = load_recordings(summary["recordings"])
    members = set_of(summary)
    inside = {s["structure"]: s.get("merged_into") or s["structure"] for s in summary["structures"]
              if s["indistinguishable_from_best"]}
    own = next((s for s in summary["structures"] if s["structure"] == truth.name), None)
    at_truth = recordings_cost_at_truth(recordings, scenario.truth)
    ceiling_row = {"structure": truth.name, "cost_at_truth": at_truth,
                   "truth_structure_cost": None if own is None else own["cost"],
                   "ranking": [{"structure": s["structure"], "cost": s["cost"]} for s in summary["structures"]
                               if s.get("cost") is not None and math.isfinite(s["cost"])]}
    ceiling = as_well_as_truth(ceiling_row)
    rate = max(r.sample_rate for r in recordings)
    noise = median_sensor_noise(summary["sensor_noise"])
    t0 = time.perf_counter()
    controller_rate = next((r.controller_rate for r in scenario.recordings if r.kind == "closed"), None)
    member_draws = load_set_draws(out_dir, n_draws=config.closure_draws, seed=seed)
    weights = load_set_weights(out_dir)
    unsure = load_unsure_members(out_dir)
    closure = set_closure(member_draws, default_candidates(rate),
                          unseen_settings(seed, controller_rate), noise,
                          n_draws=config.closure_draws, seed=seed,
                          resolution=measurement_resolution(recordings), weights=weights,
                          unsure=unsure)
    best = (summary.get("next_test") or {}).get("best")
    return {"round": k, "recordings": len(summary["recordings"]), "set": members,
            "set_size": len(members), "truth_in_set": truth.name in inside,
            "truth_member": inside.get(truth.name), "winner": summary["structures"][0]["structure"],
            "ceiling": ceiling, "ceiling_size": len(ceiling),
            "calibrated": list(member_draws), "weights": weights, "unsure": list(unsure),
            "counted": closure.counted, "not_counted": closure.not_counted,
            "truth_counted": (inside.get(truth.name) is not None
                              and inside[truth.name] not in closure.not_counted),
            "closed": closure.closed, "parting": closure.parting,
            "closed_counting_every_member": closure.closed_counting_every_member,
            "closure": {"tests": closure.tests, "settings": closure.settings},
            "menu_can_decide": bool(closure.closed or closure.parting_tests),
            "suggested": None if best is None else best["name"],
            "cost": RunCost.from_dict(summary).totals(),
            "seconds_discover": summary["timings"].get("discovery"),
            "seconds_mcmc": summary["timings"].get("mcmc"),
            "seconds_closure": time.perf_counter() - t0}


def reuse_finished(reuse, seed) -> bool:
    """Whether ``reuse`` (a set-coverage benchmark's output) holds draw ``seed`` finished: a row
    without an error in its ``bench.json``. A draw it is still running is not."""
    path = Path(reuse) / "bench.json"
    rows = json.loads(path.read_text()).get("rows", []) if path.is_file() else []
    return any(r.get("seed") == seed and "error" not in r for r in rows)


def reuse_round_zero(reuse, seed, draw_dir, run_dir, wait=0.0) -> bool:
    """Copy draw ``seed``'s recordings and its ``tvcid discover`` run from ``reuse`` (a
    set-coverage benchmark's output: ``drawNNN/recordings``, ``drawNNN/discover``) to
    ``draw_dir`` and ``run_dir``, where the loop has not started that draw and ``reuse`` has
    finished it (:func:`reuse_finished`); True if copied. ``wait``: seconds between looks while
    ``reuse`` does not yet hold the draw's row (a set-coverage run beside this one that has not
    reached the draw's end); 0 does not wait.

    The discovery then resumes the copied run (the same recordings by content, the same seed
    and options: its ranking, and chains from their checkpoints), so round 0 costs nothing twice.
    """
    source = Path(reuse) / f"draw{seed:03d}"
    run_dir, draw_dir = Path(run_dir), Path(draw_dir)
    while wait > 0 and not run_dir.exists() and not reuse_finished(reuse, seed):
        time.sleep(wait)
    if (run_dir.exists() or not (source / "discover" / "discovery.json").is_file()
            or not reuse_finished(reuse, seed)):
        return False
    if not draw_dir.exists():
        shutil.copytree(source / "recordings", draw_dir)
    shutil.copytree(source / "discover", run_dir)
    return True


def set_of(summary) -> list:
    """The unmerged members of a run's set."""
    return [s["structure"] for s in summary["structures"]
            if s["indistinguishable_from_best"] and s["merged_into"] is None]


def fresh_comparison(add_summary, fresh_summary, truth_name, resumed) -> dict:
    """A fresh run on an ``--add``'s recordings beside it: its set, the truth in it, its cost,
    and the ratio of the ``--add``'s cost to it per measure (``None`` where either was resumed:
    a resumed run counts only its last process)."""
    add = RunCost.from_dict(add_summary).totals()
    fresh = RunCost.from_dict(fresh_summary).totals()
    ratios = {k: (add[k] / fresh[k] if fresh[k] > 0 and not resumed else None) for k in add}
    return {"set": set_of(fresh_summary),
            "truth_in_set": truth_name in set(fresh_summary["indistinguishable"]), "cost": fresh,
            "add_over_fresh": ratios}


def run_draw(seed, out_dir, quick, config=None, ranges="wide", reuse=None, wait=0.0) -> dict:
    """The draw's discovery, then up to ``config.rounds`` suggested tests added; round 0 copied
    from ``reuse`` where that holds the draw's discovery finished (:func:`reuse_round_zero`,
    ``wait`` as there)."""
    from tvcid.discovery.prediction.discrimination import default_candidates
    from tvcid.pipeline import add_recordings, discover

    config = config or (QUICK if quick else FULL)
    scenario = draw_scenario(seed, ranges=ranges)
    out_dir = Path(out_dir)
    run_dir = out_dir / f"draw{seed:03d}_loop"
    if reuse is not None:
        reuse_round_zero(reuse, seed, out_dir / f"draw{seed:03d}", run_dir, wait)
    paths = write_recordings(scenario, out_dir / f"draw{seed:03d}", reuse=True)
    resumed = (run_dir / "discovery.json").exists()
    t0 = time.perf_counter()
    result = discover(paths, run_dir, fixed=config.fixed, seed=seed, quick=quick,
                      max_steps=config.max_steps, progress=False)
    rounds = [round_row(0, result.summary, run_dir, scenario, config, seed)]
    rounds[-1].update(seconds=time.perf_counter() - t0, resumed=resumed)
    extended = scenario
    for k in range(1, config.rounds + 1):
        suggested = rounds[-1]["suggested"]
        if rounds[-1]["closed"] or suggested is None:
            break
        rate = max(r.rate for r in scenario.recordings)
        menu = {c.name: c for c in default_candidates(rate)}
        extended, new = record_added_test(extended, design_of(menu[suggested], rate),
                                          out_dir / f"draw{seed:03d}_next")
        resumed = str(new) in _added(run_dir)
        t0 = time.perf_counter()
        result = add_recordings([new], run_dir, quick=quick, max_steps=config.max_steps,
                                progress=False)
        rounds.append(round_row(k, result.summary, run_dir, scenario, config, seed))
        rounds[-1].update(seconds=time.perf_counter() - t0)
        fresh_dir = out_dir / f"draw{seed:03d}_fresh{k}"
        resumed = resumed or fresh_dir.exists()
        fresh = discover(result.summary["recordings"], fresh_dir, fixed=config.fixed, seed=seed,
                         quick=quick, max_steps=config.max_steps, progress=False)
        rounds[-1].update(resumed=resumed, fresh=fresh_comparison(
            result.summary, fresh.summary, scenario.structure.name, resumed))
    return {"seed": seed, "structure": scenario.structure.name, "design": scenario.to_dict(),
            "rounds": rounds, "commit": CODE_COMMIT, "machine": MACHINE}


def _added(run_dir) -> list:
    """The recordings an earlier ``--add`` put into the run in ``run_dir`` (none before one)."""
    path = Path(run_dir) / "discovery.json"
    return (json.loads(path.read_text()).get("added") or []) if path.exists() else []


def guarded_draw(seed, out_dir, quick, ranges="wide", reuse=None, wait=0.0) -> dict:
    """:func:`run_draw`, a failure recorded as a row (counted against every goal)."""
    try:
        return run_draw(seed, out_dir, quick, ranges=ranges, reuse=reuse, wait=wait)
    except Exception as exc:  # noqa: BLE001 - one draw's failure is a result, not a crash
        return {"seed": seed, **failure(exc), "ranges": ranges,
                "commit": CODE_COMMIT, "machine": MACHINE}


def _counted_size(round_row) -> int:
    """The members of a round's set the data have not decided against: the set less the
    closure's ``not_counted`` (members the weights decide against, their weight final)."""
    return len(set(round_row["set"]) - set(round_row.get("not_counted") or ()))


def summarise(rows, rounds=ROUNDS) -> dict:
    """Per round (a draw whose loop ended earlier keeps its last round): draws with the truth in
    the set, its member counted, closed, the set within the ceiling + 1, and the set's counted
    members within it; the set sizes and the counted members' against the ceiling's. Over the
    draws: ``truth_in_set_every_round``, ``truth_counted_every_round``, ``menu_can_decide`` and of
    those ``closed_where_menu_can_decide`` (after the last round) and
    ``closed_counting_every_member``; ``add_over_fresh``: per measure
    (``kernel_steps``, ``cpu_seconds``, ``wall_seconds``) the ``median`` and ``max`` of the
    ratios of every ``--add`` run in one piece to its fresh run, over ``adds`` of them."""
    done = [r for r in rows if "error" not in r]
    can = [r for r in done if r["rounds"][0].get("menu_can_decide")]
    ratios = {}
    for key in ("kernel_steps", "cpu_seconds", "wall_seconds"):
        v = [a["fresh"]["add_over_fresh"][key] for r in done for a in r["rounds"][1:]
             if a.get("fresh") and a["fresh"]["add_over_fresh"][key] is not None]
        ratios[key] = {"adds": len(v), "median": float(np.median(v)) if v else None,
                       "max": float(np.max(v)) if v else None}
    over = {"truth_in_set_every_round": sum(all(a["truth_in_set"] for a in r["rounds"])
                                            for r in done),
            "truth_counted_every_round": sum(all(a.get("truth_counted", a["truth_in_set"])
                                                 for a in r["rounds"]) for r in done),
            "menu_can_decide": len(can),
            "closed_where_menu_can_decide": sum(r["rounds"][-1]["closed"] for r in can),
            "closed_counting_every_member": sum(
                r["rounds"][-1].get("closed_counting_every_member", r["rounds"][-1]["closed"])
                for r in can),
            "add_over_fresh": ratios}
    per_round = []
    for k in range(rounds + 1):
        at = [r["rounds"][min(k, len(r["rounds"]) - 1)] for r in done]
        per_round.append({
            "round": k, "draws": len(at),
            "truth_in_set": sum(a["truth_in_set"] for a in at),
            "truth_counted": sum(a.get("truth_counted", a["truth_in_set"]) for a in at),
            "closed": sum(a["closed"] for a in at),
            "within_ceiling_plus_one": sum(a["set_size"] <= a["ceiling_size"] + 1 for a in at),
            "counted_within_ceiling_plus_one": sum(_counted_size(a) <= a["ceiling_size"] + 1
                                                   for a in at),
            "set_sizes": [a["set_size"] for a in at], "ceiling_sizes": [a["ceiling_size"] for a in at],
            "counted_sizes": [_counted_size(a) for a in at],
        })
    return {"draws": len(done), "failed": len(rows) - len(done), "rounds": per_round, **over}


def loop_goals(table, n_total) -> list:
    """The goals of the module's docstring; failed draws count against each; not judged under
    :data:`MIN_DRAWS` draws."""
    judged = n_total >= MIN_DRAWS
    rounds = table["rounds"]
    every = table["truth_counted_every_round"]
    last, first = rounds[-1], rounds[0]
    share = lambda k: k / n_total if n_total else None  # noqa: E731
    can, closed = table["menu_can_decide"], table["closed_where_menu_can_decide"]
    steps = table["add_over_fresh"]["kernel_steps"]
    return [
        Goal("truth in the set, its member counted, at every round",
             share(every) if judged else None,
             low=TRUTH_IN_SET, fmt="{:.0%}", shown=f"{every} of {n_total}",
             target=f"every draw, over >= {MIN_DRAWS} draws"),
        Goal(f"set closed after at most {last['round']} rounds, of the draws whose menu can decide",
             closed / can if judged and can else None, low=CLOSED, fmt="{:.0%}",
             shown=f"{closed} of {can}", target=f">= {CLOSED:.0%} over >= {MIN_DRAWS} draws"),
        Goal("an --add's kernel steps over a fresh run's on the same recordings (median)",
             steps["median"] if judged else None, high=ADD_RATIO, fmt="{:.2f}",
             shown="no --add run in one piece" if steps["median"] is None else
             f"{steps['median']:.2f} over {steps['adds']} adds",
             target=f"<= {ADD_RATIO:.2f} over >= {MIN_DRAWS} draws"),
        Goal("an --add's kernel steps over a fresh run's on the same recordings (largest)",
             steps["max"] if judged else None, high=1.0, fmt="{:.2f}",
             shown="no --add run in one piece" if steps["max"] is None else
             f"{steps['max']:.2f} over {steps['adds']} adds",
             target=f"<= 1 over >= {MIN_DRAWS} draws"),
        Goal("set no larger than the fit ceiling's + 1", share(first["within_ceiling_plus_one"])
             if judged else None, low=AT_CEILING, fmt="{:.0%}",
             shown=f"{first['within_ceiling_plus_one']} of {n_total}",
             target=f">= {AT_CEILING:.0%} over >= {MIN_DRAWS} draws"),
    ]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_draw_options(parser, "one round, 150-step chains, 8 draws per member in the closure, 1 draw",
                     1, "results/bench_loop")
    parser.add_argument("--reuse", metavar="DIR", default=None,
                        help="take each draw's round 0 from the set-coverage benchmark's output "
                             "DIR (python -m tvcid.studies.benchmarks.set_coverage --out DIR, the same "
                             "seeds and --ranges), where it holds the draw's discovery finished")
    parser.add_argument("--wait-for-reuse", action="store_true",
                        help="where --reuse DIR does not yet hold a draw's row (a set-coverage "
                             "run beside this one), wait for it instead of running round 0 here")
    args = parser.parse_args(argv)
    rounds = (QUICK if args.quick else FULL).rounds

    def truth_state(r):
        return ("OUT" if not r["truth_in_set"] else
                "in" if r.get("truth_counted", True) else "in, under the deciding share")

    def describe(row):
        steps = " -> ".join(f"{r['set_size']} (ceiling {r['ceiling_size']}, truth "
                            f"{truth_state(r)}, "
                            f"{'closed' if r['closed'] else 'open'})" for r in row["rounds"])
        return f"draw {row['seed']}: truth {row['structure']}: {steps}"

    def save(path, rows):
        write_json(path, {"quick": args.quick, "rows": rows, "table": summarise(rows, rounds)})

    draw = guarded_draw if args.reuse is None else functools.partial(
        guarded_draw, reuse=args.reuse, wait=60.0 if args.wait_for_reuse else 0.0)
    rows = run_benchmark(args, draw, describe, save)
    table = summarise(rows, rounds)
    print(f"\n{table['draws']} draws ({table['failed']} failed)")
    for r in table["rounds"]:
        print(f"  round {r['round']}: truth in the set {r['truth_in_set']} (counted "
              f"{r['truth_counted']}), closed {r['closed']}, "
              f"set <= ceiling + 1 {r['within_ceiling_plus_one']} (its counted members "
              f"{r['counted_within_ceiling_plus_one']})")
    ratios = ", ".join(f"{k} {v['median']:.2f} [{v['max']:.2f}]"
                       for k, v in table["add_over_fresh"].items() if v["median"] is not None)
    print(f"  menu can decide in {table['menu_can_decide']}, of them closed "
          f"{table['closed_where_menu_can_decide']} (every member counted "
          f"{table['closed_counting_every_member']}); --add over a fresh run, median [largest]: "
          f"{ratios or 'no --add run in one piece'}")
    return goal_report(loop_goals(table, len(rows)))


if __name__ == "__main__":
    from tvcid.discovery.parallel import run_interruptible

    raise SystemExit(run_interruptible(main))
