"""Coverage benchmark of the calibration: do the 90 % intervals hold the truth 90 % of the time?

``python -m tvcid.studies.benchmarks.coverage [--quick] [--likelihood features|waveform] [--draws N] [--seed S]
[--jobs J | --dask ADDRESS] [--indices I] [--widening] [--out DIR]``

Hypothesis: with the right structure, :class:`tvcid.discovery.calibration.Calibration` returns 90 %
intervals that contain the truth in 80-97 % of seeded draws per parameter, and the truth's rank
among the posterior samples is uniform (simulation-based calibration). Deciding figure:
``DIR/ranks.png`` (rank histograms per parameter; flat is calibrated, U-shaped is overconfident,
a hump is underconfident) and the coverage table in ``DIR/bench.json``.

Each draw comes from the generator shared with the discovery benchmark, within its ``papers``
ranges (:func:`tvcid.studies.benchmarks.scenarios.draw_scenario`: a truth over every structure, an
experiment design with limit cycles at 1-3 controller settings, open-loop tests or none, 200 Hz or
1 kHz acquisition, noise, sensor offset, quantisation); every third draw is forced onto a structure with a friction
offset and a dead zone on the velocity signal (the ridge the limit cycle leaves between them).
Its recordings are made by the plain-Python reference path and read back as measured
(sidecars without truth). The calibration gets the true structure and the true linear block, and
samples the thresholds, the delay and the friction offset present in the structure, from a
start perturbed by 30 % (log-normal), under priors that are the generator's own ranges widened
by 1.5x (so the truths are draws from a distribution close to the prior). Closed-loop records
enter through the limit-cycle features, open-loop ones through the output error (whose noise sd
is then sampled too); the model-discrepancy inflation is on, as in ``tvcid fit``.

``--likelihood waveform`` measures ``tvcid fit``'s default instead: closed-loop records by their
phase-aligned output error (the noise sd sampled), the transient chosen by its accuracy from a
given 6 s, ``tvcid fit``'s 16 walkers and 4000-step cap and its spread of the start. That
likelihood needs a periodic cycle, so only draws without the band-pass loop (whose cycle wanders)
are run; the others are listed as skipped. Default output ``results/bench_coverage_waveform``.

Written: ``DIR/bench.json`` (config, one row per draw with truths, quantiles, ranks, convergence,
wall time and simulated seconds; coverage and rank histograms per parameter) and
``DIR/ranks.png``. ``--quick`` (CI) runs two short draws with short chains and checks only that
every row is complete and that coverage and ranks are computed from the rows.

``--widening`` measures what the model-discrepancy term costs a right model: the finished draws
whose factor is over 1 are calibrated again without the term (same seed, start and chain
settings) and ``DIR/widening.json`` gives, per draw and parameter, the ratio of the 90 %
intervals' widths with and without it (the goal: at most about 20 %).

The run ends with its goals, one line each (:mod:`tvcid.studies.benchmarks.goals`), and exits 0 when all are met,
1 otherwise: no draw failed; per parameter, the truth inside its 90 % interval in 80-97 % of the
finished draws (not judged on ``--quick``'s short chains); with ``--widening``, every interval
widened by at most 20 %. Every row names the commit of the code that ran it; ``widening.json``
names those of the rows with the term it was compared against. Non-finite numbers are written
as ``null``.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvcid.models.strict_json import write_json

from ..common import code_commit
from .draws import add_executor_options
from .goals import Goal
from .goals import report as goal_report
from .scenarios import (
    BACKLASH_CENTRE,
    DEAD_ZONE_CENTRE,
    draw_scenario,
    ranges_named,
    shortened,
    write_recordings,
)

#: Parameters sampled when the truth's structure has them.
SAMPLED = ("dead_zone", "backlash", "delay", "friction_offset")
#: The generator's ranges of this benchmark's draws (the structure is given, the priors built on
#: the ranges: the papers' rig).
DRAW_RANGES = "papers"
#: How much wider than the generator's ranges the priors are.
PRIOR_WIDENING = 1.5
LEVEL = 0.90
RANK_BINS = 10
#: The hypothesis's range of the share of draws whose truth is inside its 90 % interval.
COVERAGE_GOAL = (0.80, 0.97)


@dataclass(frozen=True)
class Config:
    draws: int = 30
    seed: int = 2000
    walkers: int = 24
    max_steps: int = 1500
    window: float = 10.0
    transient: float = 20.0
    dt: float = 5e-4
    spread: str = "hessian"
    closed_seconds: float | None = None
    open_seconds: float | None = None
    start_scatter: float = 0.3
    likelihood: str = "features"


QUICK = Config(draws=2, walkers=16, max_steps=40, transient=6.0, closed_seconds=16.0, open_seconds=6.0)
#: ``tvcid fit``'s defaults (:mod:`tvcid.commands.fit`): walkers, step cap, transient, spread.
WAVEFORM = Config(walkers=16, max_steps=4000, transient=6.0, spread="axes", likelihood="waveform")
QUICK_WAVEFORM = Config(**{**asdict(QUICK), "likelihood": "waveform", "spread": "axes"})


def runs_with(index, config: Config) -> bool:
    """Whether draw ``index`` is calibrated under ``config`` (the waveform likelihood needs a
    periodic cycle: no band-pass loop; the scenario is drawn only then)."""
    return config.likelihood == "features" or not coverage_scenario(index, config).structure.bandpass


def priors_for(structure):
    """The generator's ranges, widened by ``PRIOR_WIDENING``, for the sampled parameters."""
    from tvcid.discovery.calibration.priors import LogUniform, Uniform

    ranges = ranges_named(DRAW_RANGES)
    w = ranges.threshold_factor * PRIOR_WIDENING
    z = DEAD_ZONE_CENTRE[structure.dead_zone_position.value]
    priors = {"dead_zone": LogUniform(z / w, z * w),
              "delay": LogUniform(ranges.delay[0] / PRIOR_WIDENING, ranges.delay[1] * PRIOR_WIDENING)}
    if structure.backlash:
        priors["backlash"] = LogUniform(BACKLASH_CENTRE / w, BACKLASH_CENTRE * w)
    if structure.friction:
        priors["friction_offset"] = Uniform(-z * w, 0.0)
    return priors


def _start(truth, priors, rng, scatter):
    out = {}
    for n, p in priors.items():
        v = getattr(truth, n) * math.exp(scatter * rng.standard_normal())
        out[n] = float(min(max(v, p.low + 0.02 * (p.high - p.low)), p.high - 0.02 * (p.high - p.low)))
    return out


def coverage_scenario(index, config: Config):
    """Draw ``index``'s scenario: every third one on the dead zone / friction offset ridge."""
    from tvcid.models.structures import structure_space

    seed = config.seed + index
    structure = None
    if index % 3 == 2:  # a ridge: dead zone on the velocity signal and a friction offset
        kept, _ = structure_space()
        ridge = [s for s in kept if s.friction and s.dead_zone_position.value == "velocity"]
        structure = ridge[int(np.random.default_rng(seed).integers(len(ridge)))]
    scenario = draw_scenario(seed, structure=structure, ranges=DRAW_RANGES)
    if config.closed_seconds or config.open_seconds:
        scenario = shortened(scenario, closed=config.closed_seconds, open_=config.open_seconds)
    return scenario


def run_draw(index, config: Config, workdir: Path, discrepancy=True) -> dict:
    """Calibrate draw ``index`` on its own recordings; ``discrepancy=False`` without the
    model-discrepancy factor that tempers the likelihood (:func:`widening`)."""
    from tvcid.discovery.calibration import Calibration
    from tvcid.discovery.calibration.runner import ConvergenceWarning
    from tvcid.models.structures import Structure

    seed = config.seed + index
    scenario = coverage_scenario(index, config)
    paths = write_recordings(scenario, workdir / f"draw{index:03d}", reuse=True)
    truth = scenario.truth
    structure = Structure.of_params(truth)
    priors = priors_for(structure)
    names = tuple(n for n in SAMPLED if n in priors)
    if config.likelihood == "waveform" or any(r.kind == "open" for r in scenario.recordings):
        names += ("sigma",)  # the output error's noise level, as a user would sample it
    rng = np.random.default_rng([seed, 1])
    start = _start(truth, priors, rng, config.start_scatter)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        cal = Calibration(truth, params=names, priors=priors, start=start, likelihood=config.likelihood,
                          window=config.window, transient=config.transient, dt=config.dt,
                          n_walkers=config.walkers, max_steps=config.max_steps, seed=seed,
                          spread=config.spread, discrepancy=discrepancy).fit(paths)
    wall = time.perf_counter() - t0
    post, rep = cal.posterior_, cal.report_
    row = {"index": index, "seed": seed, "structure": structure.name,
           "design": [r.__dict__ for r in scenario.recordings],
           "acquisition": scenario.acquisition.__dict__,
           "wall_s": wall, "iterations": rep.iterations, "converged": bool(rep.converged),
           "tau": [float(t) for t in rep.tau], "acceptance": float(rep.acceptance),
           "simulated_seconds": float(cal.log_posterior_.simulated_seconds),
           "parameters": {}, "likelihood": config.likelihood}
    if config.likelihood == "waveform":
        row["transients"] = {k: float(v) for k, v in cal.transients_.items()}
        row["likelihoods"] = dict(cal.likelihoods_)  # closed-loop records may fall back to features
    row["inflation"] = list(cal.inflation_)
    # how the independence move ran (None: not used; share 0 at the end: off)
    row["laplace"] = ({k: cal.laplace_[k] for k in ("share", "adapted_at", "refits", "retries")
                       if k in cal.laplace_} if cal.laplace_ else None)
    row["discrepancy"] = bool(discrepancy)
    row["commit"] = CODE_COMMIT
    for j, n in enumerate(names):
        if n == "sigma":  # a nuisance here; its truth mixes noise and quantisation
            continue
        lo, hi = post.interval(n, LEVEL)
        value = float(getattr(truth, n))
        row["parameters"][n] = {
            "truth": value, "q05": float(lo), "q50": float(np.median(post.samples[:, j])),
            "q95": float(hi), "inside": bool(lo <= value <= hi),
            "rank": float(np.mean(post.samples[:, j] < value)),
            "prior": [priors[n].low, priors[n].high],
            "relative_width": float((hi - lo) / abs(value)) if value else None,
        }
    return row


#: The commit of the code this process imported (a row's, not the checkout's when it ends).
CODE_COMMIT = code_commit()


def run_draws(todo, config: Config, workdir: Path, jobs: int, record, discrepancy=True,
              dask=None) -> list:
    """:func:`run_draw` for every index in ``todo``, ``jobs`` at a time in worker processes or on
    the Dask cluster ``dask`` (:func:`tvcid.discovery.executors.executor_from`), ``record(row)`` as
    each finishes. A draw that raises is reported and skipped, not allowed to stop the others (a
    benchmark of an hour must keep what it finished); returns the failed indices."""
    from tvcid.discovery.executors import executor_from

    failed = []
    todo = list(todo)
    if not todo:
        return failed
    n = len(todo)
    # locally, one draw (or --jobs 1 or less) runs in this process: a pool would only add its
    # start-up
    with executor_from(jobs if n > 1 and jobs > 1 else 1, dask) as executor:
        for k, row, exc in executor.completed(run_draw, todo, [config] * n, [workdir] * n,
                                               [discrepancy] * n):
            if exc is not None:  # one draw's failure must not stop the rest
                failed.append(todo[k])
                print(f"draw {todo[k]} FAILED: {exc!r}", flush=True)
            else:
                record(row)
    return failed


def summarise(rows) -> dict:
    """Coverage (truth inside the 90 % interval) and rank histograms per parameter."""
    out = {}
    names = sorted({n for r in rows for n in r["parameters"]})
    for n in names:
        cells = [r["parameters"][n] for r in rows if n in r["parameters"]]
        ranks = np.array([c["rank"] for c in cells])
        hist, _ = np.histogram(ranks, bins=RANK_BINS, range=(0.0, 1.0))
        out[n] = {"draws": len(cells), "coverage": float(np.mean([c["inside"] for c in cells])),
                  "rank_histogram": hist.tolist(),
                  "median_relative_width": float(np.median([c["relative_width"] for c in cells]))}
    factors = np.array([f for r in rows for f in r.get("inflation", [])], dtype=float)
    out["_inflation"] = {
        # the discrepancy term on right models: 1 leaves a record's likelihood as it is
        "records": int(factors.size),
        "fraction_at_1": float(np.mean(factors == 1.0)) if factors.size else None,
        # a factor f widens that record's share of the intervals by at most sqrt(f): <= 20 %
        "fraction_within_20_percent": (float(np.mean(np.sqrt(factors) <= 1.2))
                                       if factors.size else None),
        "median": float(np.median(factors)) if factors.size else None,
        "max": float(np.max(factors)) if factors.size else None,
    }
    out["_all"] = {"draws": len(rows), "converged": int(sum(r["converged"] for r in rows)),
                   "commits": sorted({str(r.get("commit")) for r in rows}),
                   "median_wall_s": float(np.median([r["wall_s"] for r in rows])),
                   "median_simulated_seconds": float(np.median([r["simulated_seconds"] for r in rows]))}
    return out


def widening(rows, plain_rows) -> dict:
    """What the discrepancy term does to right models' intervals (the goal: at most about 20 %).

    ``rows``: draws calibrated as the benchmark does (the term on); ``plain_rows``: the same draws
    without it. Per draw and parameter, the ratio of the 90 % intervals' widths (on / off), and
    whether the truth is inside each; overall, the largest ratio and how many are within 1.2.
    """
    on = {r["index"]: r for r in rows}
    per_draw, ratios = [], []
    for plain in sorted(plain_rows, key=lambda r: r["index"]):
        row = on.get(plain["index"])
        if row is None:
            continue
        cells = {}
        for n, c in row["parameters"].items():
            p = plain["parameters"].get(n)
            if p is None:
                continue
            ratio = (c["q95"] - c["q05"]) / (p["q95"] - p["q05"])
            ratios.append(ratio)
            cells[n] = {"ratio": float(ratio), "inside": bool(c["inside"]),
                        "inside_without": bool(p["inside"])}
        per_draw.append({"index": plain["index"], "inflation": row.get("inflation"),
                         "converged": [bool(row["converged"]), bool(plain["converged"])],
                         "parameters": cells})
    r = np.array(ratios, dtype=float)
    return {"draws": per_draw, "intervals": int(r.size),
            "within_20_percent": int(np.sum(r <= 1.2)) if r.size else 0,
            "median_ratio": float(np.median(r)) if r.size else None,
            "max_ratio": float(np.max(r)) if r.size else None}


def plot_ranks(summary, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in summary if not n.startswith("_")]
    fig, axes = plt.subplots(1, len(names), figsize=(3.2 * len(names), 2.8), squeeze=False)
    for ax, n in zip(axes[0], names):
        h = summary[n]["rank_histogram"]
        ax.bar(np.arange(RANK_BINS) / RANK_BINS, h, width=1 / RANK_BINS, align="edge", color="0.6")
        ax.axhline(summary[n]["draws"] / RANK_BINS, color="k", lw=0.8, ls="--")
        ax.set_title(f"{n}\ncoverage {summary[n]['coverage']:.0%} of {summary[n]['draws']}")
        ax.set_xlabel("rank of the truth")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_indices(text: str) -> set:
    """Draw indices from ``'10,14-29'`` (ranges inclusive)."""
    out = set()
    for part in text.split(","):
        lo, _, hi = part.strip().partition("-")
        try:
            out.update(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            raise ValueError(f"draw indices {text!r}: {part!r} is not N or N-M") from None
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="two short draws (CI)")
    parser.add_argument("--likelihood", choices=("features", "waveform"), default="features",
                        help="closed-loop records by their limit-cycle features (default) or, as "
                             "tvcid fit does by default, their phase-aligned waveform (draws "
                             "without the band-pass loop only)")
    parser.add_argument("--draws", type=int, default=None, help="number of draws (default 30, quick 2)")
    parser.add_argument("--seed", type=int, default=None, help="seed of the first draw (default 2000)")
    parser.add_argument("--max-steps", type=int, default=None, help="MCMC step cap per draw")
    add_executor_options(parser, "draws calibrated at once, one process each (default 1)")
    parser.add_argument("--indices", default=None,
                        help="run only these draws of the config, e.g. '10,14-29' (to share a "
                             "benchmark between machines or runs; the table covers the rows done)")
    parser.add_argument("--widening", action="store_true",
                        help="calibrate the finished draws whose discrepancy factor is over 1 (or "
                             "--indices) again without the discrepancy term and write "
                             "DIR/widening.json: how much the term widens each 90 %% interval")
    parser.add_argument("--out", default=None,
                        help="output directory (default results/bench_coverage, or "
                             "results/bench_coverage_waveform)")
    args = parser.parse_args(argv)
    if args.likelihood == "waveform":
        config = QUICK_WAVEFORM if args.quick else WAVEFORM
    else:
        config = QUICK if args.quick else Config()
    overrides = {k: v for k, v in (("draws", args.draws), ("seed", args.seed),
                                   ("max_steps", args.max_steps)) if v is not None}
    config = Config(**{**asdict(config), **overrides})
    out = Path(args.out or ("results/bench_coverage" if config.likelihood == "features"
                            else "results/bench_coverage_waveform"))
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench.json"
    rows = []
    if path.exists():  # resume: keep finished draws of the same config
        old = json.loads(path.read_text())
        if old.get("config") == asdict(config):
            rows = old["rows"]
    if args.widening:
        return _widening_main(args, config, out, rows)
    done = {r["index"] for r in rows}
    todo = [i for i in range(config.draws) if i not in done]
    if args.indices:
        try:
            wanted = parse_indices(args.indices)
        except ValueError as err:
            parser.error(str(err))
        if not wanted <= set(range(config.draws)):
            parser.error(f"--indices {args.indices}: draws outside 0-{config.draws - 1}")
        todo = [i for i in todo if i in wanted]
    skipped = [i for i in todo if not runs_with(i, config)]
    if skipped:
        print(f"skipped (band-pass loop: no periodic cycle for the waveform likelihood): draws "
              f"{', '.join(map(str, skipped))}", flush=True)
    todo = [i for i in todo if i not in skipped]

    def record(row):
        rows.append(row)
        rows.sort(key=lambda r: r["index"])
        cells = ", ".join(f"{n} {'in ' if c['inside'] else 'OUT'} rank {c['rank']:.2f}"
                          for n, c in row["parameters"].items())
        print(f"draw {row['index']} ({row['structure']}): {cells}; {row['iterations']} steps, "
              f"{row['wall_s']:.0f} s", flush=True)
        write_json(path, {"config": asdict(config), "rows": rows, "summary": summarise(rows)})

    failed = run_draws(todo, config, out / "data", args.jobs, record, dask=args.dask)
    summary = summarise(rows)
    write_json(path, {"config": asdict(config), "rows": rows, "summary": summary})
    plot_ranks(summary, out / "ranks.png")
    for n, s in summary.items():
        if not n.startswith("_"):
            print(f"{n:16s} coverage {s['coverage']:.0%} of {s['draws']}  ranks {s['rank_histogram']}")
    print(f"wrote {path}, {out / 'ranks.png'}")
    if failed:
        print(f"FAILED draws (not in the table): {', '.join(map(str, sorted(failed)))}")
    return goal_report([failed_goal(failed)] + ([] if args.quick else coverage_goals(summary)))


def failed_goal(failed):
    """Every draw run finished (a failed draw is left out of the table)."""
    return Goal.at_most("draws that failed", len(failed), 0, fmt="{:d}",
                        shown=", ".join(map(str, sorted(failed))) if failed else "none",
                        target="none")


def coverage_goals(summary) -> list:
    """Per parameter: the truth inside its 90 % interval in ``COVERAGE_GOAL`` of the draws
    (:func:`summarise`'s ``summary``; judged on full runs, not on ``--quick``'s two draws)."""
    goals = []
    for n, s in summary.items():
        if n.startswith("_"):
            continue
        hits = round(s["coverage"] * s["draws"])
        goals.append(Goal(f"{n} truth inside its 90 % interval", s["coverage"],
                          low=COVERAGE_GOAL[0], high=COVERAGE_GOAL[1],
                          shown=f"{hits} of {s['draws']} = {100 * s['coverage']:.0f} %",
                          target=f"{100 * COVERAGE_GOAL[0]:.0f}-{100 * COVERAGE_GOAL[1]:.0f} %"))
    return goals


def widening_goal(result):
    """The widening goal: the discrepancy term widens a right model's 90 % intervals by at most
    20 %."""
    return Goal.count("90 % intervals the discrepancy term widens by at most 20 %",
                      result["within_20_percent"], result["intervals"])


def _widening_main(args, config, out, rows) -> int:
    """``--widening``: the finished draws again without the discrepancy term (resumable)."""
    if not rows:
        print(f"no finished draws of this config in {out / 'bench.json'}: run the benchmark first")
        return 1
    wanted = (parse_indices(args.indices) if args.indices
              else {r["index"] for r in rows if max(r.get("inflation") or [1.0]) > 1.0})
    path = out / "widening.json"
    plain = json.loads(path.read_text())["plain_rows"] if path.exists() else []
    plain = [r for r in plain if r.get("config") == asdict(config)]
    todo = sorted(wanted - {r["index"] for r in plain} & {r["index"] for r in rows})

    def record(row):
        row["config"] = asdict(config)
        plain.append(row)
        result = widening(rows, plain)
        write_widening(path, plain, result, rows)
        cells = ", ".join(f"{n} x{c['ratio']:.2f}" for d in result["draws"]
                          if d["index"] == row["index"] for n, c in d["parameters"].items())
        print(f"draw {row['index']} without the term: widths with it {cells}", flush=True)

    failed = run_draws(todo, config, out / "data", args.jobs, record, discrepancy=False,
                       dask=args.dask)
    result = widening(rows, plain)
    write_widening(path, plain, result, rows)
    print(f"{result['within_20_percent']} of {result['intervals']} intervals widened by at most "
          f"20 % (median x{result['median_ratio']}, max x{result['max_ratio']}); wrote {path}")
    if failed:
        print(f"FAILED draws (not in the table): {', '.join(map(str, sorted(failed)))}")
    return goal_report([failed_goal(failed), widening_goal(result)])


def write_widening(path, plain, result, rows):
    """``widening.json``: the rows without the term, the comparison, and the commits of the
    rows with the term it was made against (by draw index)."""
    paired = {d["index"] for d in result["draws"]}
    write_json(path, {"plain_rows": plain, "widening": result,
                      "with_term_commits": {str(r["index"]): r.get("commit") for r in rows
                                            if r["index"] in paired}})


if __name__ == "__main__":
    from tvcid.discovery.parallel import (
        run_interruptible,  # Ctrl-C, SIGTERM: workers stopped, one line, 130
    )

    sys.exit(run_interruptible(main))
