"""Benchmark of the limit-cycle prediction: speed, shortcut accuracy, coverage.

Cases are drawn by the shared scenario generator (:func:`tvcid.studies.benchmarks.scenarios.draw_truth`): a truth
with the dead zone on the error and no band-pass loop that oscillates at controllers A and B and at
a third setting (Kp 7.5, Kd 0.075, mu 8), calibrated (dead zone, backlash and delay where present,
and sigma; features likelihood, 16 walkers, 700 steps) on 12 s closed-loop records at A and B made
at dt = 2e-4 with 5e-5 rad sensor noise.

Measured:

* **speed**: a Kp x Kd map (20 x 20 by default, Kp 3-12, Kd 0.02-0.12, mu 12.3) with 200
  posterior draws = 80,000 closed-loop runs, wall time (goal <= 5 min on 2 cores), and the same
  map's runs at full length for reference (a 30 s transient from the hypothesis' own initial
  state, timed on a sample of settings and scaled): the ratio is the shortcut's speed-up;
* **shortcut accuracy**: on ``n_check`` settings of the grid, every draw's amplitude and frequency
  by the shortcut (pilot of the median model 20 s, each draw 3 s transient + 4 s window) against
  full-length runs (30 s transient, same 4 s window): whether they agree on the outcome (cycle,
  rest, diverging), and over the draws settled in both (amplitude steady within 2 % across the
  window; slowly growing oscillations near the stability boundary are counted, not compared)
  per-draw relative differences (median and 99th percentile) and those of the band's quantiles;
* **coverage**: over ``seeds``, whether the 90 % band at the third setting (widened by the
  solver's step-doubling error at the median model) brackets the generating model's cycle
  (amplitude and frequency measured the same way, at the simulator's default step).

Usage: ``python -m tvcid.studies.benchmarks.prediction [--quick] [--seed N] [--jobs J | --dask ADDRESS]``
(``--jobs``, ``--dask``: the coverage cases calibrated at once, after the map); writes
``results/bench_prediction/bench.json`` (with the commit of the code; non-finite numbers as
``null``). The load average is recorded (other jobs inflate times). The speed goal is judged
against the batch kernel's reference measured in the same run (:meth:`tvcid.studies.benchmarks.goals.Goal.speed`),
scaled to the map's runs (300 s per 80,000; ``--quick``'s small map gets its share); the run
ends with that goal, met or NOT met, and exits 0 when it is met, 1 otherwise.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from tvcid.discovery.calibration import Calibration
from tvcid.discovery.executors import executor_from
from tvcid.discovery.prediction import (
    ControllerSetting,
    PredictionConfig,
    cycle_map,
    load_posterior_draws,
    predict_cycle,
    simulate_cycles,
)
from tvcid.models import ClosedLoop, simulate
from tvcid.models.strict_json import write_json
from tvcid.models.structures import Structure, structure_space
from tvcid.models.synthetic import synthetic_recording

from ..common import code_commit
from .draws import add_executor_options
from .goals import Goal, kernel_reference
from .goals import report as goal_report
from .scenarios import draw_truth, oscillates

OUT = Path("results/bench_prediction")
FIT_SETTINGS = ((5.84, 0.062, 12.3), (9.8, 0.06, 4.5))
THIRD = (7.5, 0.075, 8.0)
NOISE = 5e-5
#: The map's speed goal: seconds per this many closed-loop runs (a 20 x 20 map of 200 draws).
GOAL_SECONDS, GOAL_RUNS = 300.0, 80_000


@dataclass(frozen=True)
class Config:
    grid: int = 20
    draws: int = 200
    n_check: int = 8
    seeds: tuple = tuple(range(10))
    fit_steps: int = 700
    full_transient: float = 30.0


QUICK = Config(grid=5, draws=40, n_check=2, seeds=(0,), fit_steps=300)


def draw_prediction_truth(seed):
    """A seeded truth (dead zone on the error, no band-pass loop) that oscillates at both fitted
    settings and at :data:`THIRD`."""
    rng = np.random.default_rng(seed)
    kept, _ = structure_space()
    simple = [s for s in kept if not s.bandpass and s.dead_zone_position.value == "error"]
    loops = [ClosedLoop(*c) for c in FIT_SETTINGS + (THIRD,)]
    while True:
        structure = simple[int(rng.integers(len(simple)))]
        truth = draw_truth(rng, structure)
        if all(oscillates(truth, loop) for loop in loops):
            return truth


def prediction_case(seed, workdir, steps=700, walkers=16):
    """Calibrate a drawn truth on the two fitted settings by ``walkers`` walkers, at most
    ``steps`` steps; returns ``(fit directory, truth)``."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    truth = draw_prediction_truth(seed)
    recs = [synthetic_recording(truth, ClosedLoop(*c), 30.0, NOISE, seed + i,
                                workdir / f"closed{i}.csv", keep_last=12.0, dt=2e-4)
            for i, c in enumerate(FIT_SETTINGS)]
    names = [n for n in ("dead_zone", "backlash", "delay") if getattr(truth, n) > 0]
    cal = Calibration(truth, params=tuple(names) + ("sigma",), likelihood="features",
                      n_walkers=walkers, max_steps=steps, seed=seed, progress=False,
                      backend=workdir / "fit" / "chain.h5")
    cal.fit(recs)
    return workdir / "fit", truth


def measured_cycle(truth, setting, window=4.0, rate=250.0):
    """The generating model's cycle, measured as the prediction measures each draw."""
    tr = simulate(truth, setting.closed_loop(), 30.0, rate=rate)
    return tr.features(window=window)


def shortcut_accuracy(draws, settings, config, full_transient):
    """Per-draw and per-quantile relative differences, shortcut vs full-length runs."""
    from tvcid.discovery.prediction.cycles import CYCLE, _pilot_state

    full_config = replace(config, transient=full_transient, pilot=0.0)
    median = draws.median_params()
    params = draws.param_sets()
    per_draw = {"amplitude": [], "frequency": []}
    per_quantile = {"amplitude": [], "frequency": []}
    outcome_agreement = []
    unsettled = cycles = 0
    t_short = t_full = 0.0
    for s in settings:
        t0 = time.perf_counter()
        theta, thetad, y, yd, x = _pilot_state(median, s, config)
        short = simulate_cycles([p.replace(y0=y, yd0=yd, x0=x) for p in params],
                                [s.closed_loop(theta0=theta, thetad0=thetad)] * len(params),
                                config)
        t_short += time.perf_counter() - t0
        t0 = time.perf_counter()
        full = simulate_cycles(params, [s.closed_loop()] * len(params), full_config)
        t_full += time.perf_counter() - t0
        outcome_agreement.append(float(np.mean(short.outcome == full.outcome)))
        both = (short.outcome == CYCLE) & (full.outcome == CYCLE)
        unsettled += int(np.sum(both & ((np.abs(short.drift) > config.settled_drift)
                                        | (np.abs(full.drift) > config.settled_drift))))
        cycles += int(np.sum(both))
        # near the stability boundary a slowly growing oscillation has no amplitude to compare
        both &= (np.abs(short.drift) <= config.settled_drift) & (
            np.abs(full.drift) <= config.settled_drift)
        for name in ("amplitude", "frequency"):
            a, b = getattr(short, name)[both], getattr(full, name)[both]
            if a.size:
                per_draw[name].extend(np.abs(a / b - 1.0).tolist())
                qa, qb = np.quantile(a, [0.05, 0.5, 0.95]), np.quantile(b, [0.05, 0.5, 0.95])
                per_quantile[name].append(float(np.max(np.abs(qa / qb - 1.0))))
    out = {"settings": len(settings), "outcome_agreement_min": float(np.min(outcome_agreement)),
           "oscillating_draws": cycles, "not_settled_draws": unsettled,
           "seconds_shortcut": t_short, "seconds_full": t_full}
    for name in ("amplitude", "frequency"):
        d = np.asarray(per_draw[name])
        out[name] = {
            "per_draw_median": float(np.median(d)) if d.size else None,
            "per_draw_p99": float(np.quantile(d, 0.99)) if d.size else None,
            "per_draw_max": float(np.max(d)) if d.size else None,
            "quantile_max": float(np.max(per_quantile[name])) if per_quantile[name] else None,
        }
    return out


def coverage_row(s, config: Config, pconfig, out: Path, case=None) -> dict:
    """Coverage case ``s``: whether the 90 % band at :data:`THIRD` brackets the generating
    model's cycle. ``case``: its ``(fit directory, truth)`` if calibrated already, else
    :func:`prediction_case` calibrates it under ``out``."""
    case_dir, case_truth = case or prediction_case(s, out / f"case{s}", config.fit_steps)
    d = load_posterior_draws(case_dir, n_draws=config.draws, seed=s)
    third = ControllerSetting(*THIRD)
    pred = predict_cycle(d, third, pconfig).to_dict()
    f = measured_cycle(case_truth, third)
    row = {"seed": s, "structure": Structure.of_params(case_truth).name,
           "truth_amplitude": f.amplitude, "truth_frequency": f.frequency}
    for name, value in (("amplitude", f.amplitude), ("frequency", f.frequency)):
        q = pred[name]
        row[name] = q
        row[f"{name}_inside"] = bool(q["q05"] is not None and q["q05"] <= value <= q["q95"])
        row[f"{name}_width"] = (None if q["q05"] is None
                                else (q["q95"] - q["q05"]) / q["q50"])
    return row


def run(config: Config, seed: int, out: Path, jobs: int = 1, dask=None) -> dict:
    """The benchmark; the coverage cases other than ``seed``'s ``jobs`` at a time in worker
    processes, or on the Dask cluster ``dask`` (:func:`tvcid.discovery.executors.executor_from`)."""
    out.mkdir(parents=True, exist_ok=True)
    pconfig = PredictionConfig()
    reference = kernel_reference()
    t0 = time.perf_counter()
    directory, truth = prediction_case(seed, out / f"case{seed}", config.fit_steps)
    fit_seconds = time.perf_counter() - t0
    draws = load_posterior_draws(directory, n_draws=config.draws, seed=seed)
    base = ControllerSetting(5.84, 0.062, 12.3)
    grid = {"kp": np.linspace(3.0, 12.0, config.grid), "kd": np.linspace(0.02, 0.12, config.grid)}
    t0 = time.perf_counter()
    cmap = cycle_map(draws, base, grid, pconfig, describing=True, progress=False)
    map_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    cycle_map(draws, base, grid, pconfig, describing=False, progress=False)
    map_seconds_no_df = time.perf_counter() - t0
    rng = np.random.default_rng(seed)
    points = [(float(rng.choice(grid["kp"])), float(rng.choice(grid["kd"])))
              for _ in range(config.n_check)]
    accuracy = shortcut_accuracy(draws, [base.replace(kp=kp, kd=kd) for kp, kd in points],
                                 pconfig, config.full_transient)
    # full-length cost of the whole map, scaled from the checked settings
    full_map_seconds = accuracy["seconds_full"] / len(points) * config.grid**2
    # the other cases calibrated meanwhile (after the timed map: they do not slow it down); no
    # cluster started for none, no pool for one
    others = [s for s in config.seeds if s != seed]
    n = len(others)
    with executor_from(jobs if n > 1 and jobs > 1 else 1, dask if n else None) as executor:
        rows = executor.map(coverage_row, others, [config] * n, [pconfig] * n, [out] * n)
        coverage = [coverage_row(s, config, pconfig, out, (directory, truth)) if s == seed
                    else next(rows) for s in config.seeds]
    summary = {
        "config": asdict(config),
        "prediction_config": asdict(pconfig),
        "seed": seed,
        "commit": code_commit(),
        "kernel_seconds_per_simulated_second": reference,
        "load_average": os.getloadavg(),
        "cpu_count": os.cpu_count(),
        "fit_seconds": fit_seconds,
        "map": {"shape": list(cmap.shape), "draws": len(draws),
                "runs": int(np.prod(cmap.shape)) * len(draws), "seconds": map_seconds,
                "seconds_without_df": map_seconds_no_df,
                "full_length_seconds_estimate": full_map_seconds,
                "speedup_vs_full_length": full_map_seconds / map_seconds_no_df,
                "goal_seconds": GOAL_SECONDS, "fraction_diverging_settings":
                float(np.mean(cmap.summary["fraction_diverging"] > 0.5))},
        "shortcut_accuracy": accuracy,
        "coverage": {"rows": coverage,
                     "amplitude_inside": sum(r["amplitude_inside"] for r in coverage),
                     "frequency_inside": sum(r["frequency_inside"] for r in coverage),
                     "cases": len(coverage)},
    }
    write_json(out / "bench.json", summary, default=float)
    return summary


def prediction_goals(summary) -> list:
    """The map's speed goal, scaled to its runs, judged against the same run's kernel reference."""
    m = summary["map"]
    return [Goal.speed(f"Kp x Kd map of {m['runs']:,} runs wall time", m["seconds"],
                       summary["kernel_seconds_per_simulated_second"],
                       m["goal_seconds"] * m["runs"] / GOAL_RUNS)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small map, one case (CI)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the speed case")
    parser.add_argument("--out", default=str(OUT), help="output directory")
    add_executor_options(parser, "coverage cases calibrated at once, one process each, after the "
                                 "timed map (default 1)")
    args = parser.parse_args(argv)
    s = run(QUICK if args.quick else Config(), args.seed, Path(args.out), args.jobs, args.dask)
    m, a, c = s["map"], s["shortcut_accuracy"], s["coverage"]
    print(f"map {m['shape'][0]}x{m['shape'][1]} x {m['draws']} draws = {m['runs']} runs: "
          f"{m['seconds']:.1f} s ({m['seconds_without_df']:.1f} s without the DF); full-length "
          f"runs would take ~{m['full_length_seconds_estimate']:.0f} s "
          f"({m['speedup_vs_full_length']:.1f}x)")
    print(f"shortcut vs full length on {a['settings']} settings: amplitude per draw median "
          f"{a['amplitude']['per_draw_median']:.2e}, p99 {a['amplitude']['per_draw_p99']:.2e}; "
          f"band quantiles within {a['amplitude']['quantile_max']:.2e} (amplitude), "
          f"{a['frequency']['quantile_max']:.2e} (frequency); outcomes agree on >= "
          f"{a['outcome_agreement_min']:.0%} of draws; {a['not_settled_draws']} of "
          f"{a['oscillating_draws']} oscillating draws not settled (not compared)")
    print(f"coverage at the third setting: amplitude {c['amplitude_inside']}/{c['cases']}, "
          f"frequency {c['frequency_inside']}/{c['cases']}")
    print(f"wrote {Path(args.out) / 'bench.json'}")
    return goal_report(prediction_goals(s))


if __name__ == "__main__":
    sys.exit(main())
