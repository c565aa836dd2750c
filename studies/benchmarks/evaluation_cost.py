"""What one evaluated point of a member's posterior costs, record by record, and how far a
simulated cycle's features move with the stretch they are read from.

``python -m tvcid.studies.benchmarks.evaluation_cost [--draws N] [--seed S] [--points P] [--out DIR]``

Each draw (:func:`tvcid.studies.benchmarks.scenarios.draw_scenario`, the generator's ``wide`` ranges,
seeds 5000 on, which no test uses) has its recordings made by the reference simulator and read
back as measured recordings; a member's likelihood is set up on them as ``tvcid discover``'s set
stage sets it up (:class:`tvcid.discovery.calibration.calibration.Calibration`, the features likelihood,
a 10 s window, the truth's structure and its priors), without sampling. Per record the row holds
the kernel steps one point costs (:func:`tvcid.discovery.speed.evaluation_steps`: a cycle's settling
before the window, its window and any run beyond it; an open-loop record's whole length at the
step its edges and solver check chose, and the steps that choice added).

Then ``P`` points about the truth (each sampled parameter moved by a factor
``exp(s N(0, 1))``, ``s = --spread``, 0.003 by default: about a pinned parameter's 90 % interval)
are run over the settling and four windows; per cycle
record the row holds, in the data's sd (largest over the points and the features, and each
feature's largest), how far the features read over the window move when read over the next
window (``next_window_sd``) and over the window's first six periods (``six_periods_sd``): what
reading a settled cycle from fewer periods would change, and how much the reader itself moves
from one stretch of a periodic run to the next.

``DIR/bench.json`` (default ``results/bench_evaluation_cost``) holds the rows, resumed by seed,
each with the commit of the code, and the summary: the kernel steps of a point by record kind and
part, and the medians and largest of those moves.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from tvcid.discovery.calibration import Calibration
from tvcid.discovery.members.member_calibration import member_priors
from tvcid.discovery.speed import evaluation_steps
from tvcid.models.batch import BatchSimulator
from tvcid.models.cycle_reading import cycle_features
from tvcid.models.strict_json import write_json

from ..common import code_commit
from .draws import finished_rows
from .scenarios import draw_scenario, write_recordings

OUT = Path("results/bench_evaluation_cost")
FIRST_SEED = 5000
SPREAD = 0.003
#: Periods of the short stretch the features are also read from.
SHORT_PERIODS = 6
#: Windows each run is simulated over after its settling.
WINDOWS = 4


def points_about(truth, names, n, rng, spread=SPREAD):
    """``n`` parameter sets about ``truth``: each of ``names`` times ``exp(spread N(0, 1))``."""
    out = []
    for _ in range(n):
        moved = {k: getattr(truth, k) * math.exp(spread * rng.standard_normal()) for k in names}
        try:
            out.append(truth.replace(**moved))
        except ValueError:
            out.append(None)
    return out


def measure_draw(seed, out_dir, n_points, spread=SPREAD) -> dict:
    """One draw's row (see the module's docstring)."""
    scenario = draw_scenario(seed, ranges="wide")
    truth, structure = scenario.truth, scenario.structure
    paths = write_recordings(scenario, Path(out_dir) / f"draw{seed}", reuse=True)
    names = [n for n in structure.parameter_names()
             if not (n == "bandpass_saturation" and not math.isfinite(truth.bandpass_saturation))]
    priors = member_priors(truth, structure, names)
    cal = Calibration(truth, params=tuple(names), priors=priors, likelihood="features",
                      window=10.0, seed=seed, global_search=False,
                      n_walkers=max(2 * len(names) + 2, 8)).setup(paths)
    row = {"seed": seed, "structure": structure.name, "design": scenario.to_dict(),
           "commit": code_commit(), "spread": spread, "records": evaluation_steps(cal.terms_)}
    points = [p for p in points_about(truth, names, n_points, np.random.default_rng(seed), spread)
              if p is not None]
    row["reads"] = [reads_of(term, points) for term in cal.terms_
                    if getattr(term, "kind", "") == "features"]
    return row


def reads_of(term, points) -> dict:
    """How far a cycle record's simulated features move with the stretch they are read from
    (see the module's docstring)."""
    span = float(term.tau[-1])
    sim = BatchSimulator(term.experiment, term.transient + WINDOWS * span + 0.01,
                         term.simulator.dt, rate=term.simulator.rate,
                         warm_start=term.simulator.warm_start)
    delta, ok = sim.run(points)
    t = sim.t
    sd = np.sqrt(np.diag(term._data_cov))

    def read(i, a, b):
        sel = (t >= a) & (t <= b)
        f = cycle_features(t[sel], delta[i, sel], term.features)
        return None if f is None else np.asarray(f)

    t0, short = term.transient, SHORT_PERIODS * term.period
    nxt, few = [], []
    for i in np.flatnonzero(ok):
        w = read(i, t0, t0 + span)
        if w is None:
            continue
        for k in range(1, WINDOWS):
            later = read(i, t0 + k * span, t0 + (k + 1) * span)
            if later is not None:
                nxt.append(np.abs(later - w) / sd)
        f = read(i, t0, t0 + short) if short < span else None
        if f is not None:
            few.append(np.abs(f - w) / sd)

    def largest(moves):
        return None if not moves else {"any": float(np.max(moves)), **dict(zip(
            term.features, np.max(moves, axis=0).tolist()))}

    return {"name": term.name, "period": term.period, "window": span,
            "settles": term.record_start is not None, "runs": int(ok.sum()),
            "next_window_sd": largest(nxt),
            "six_periods_sd": largest(few),
            "six_periods_seconds": short if short < span else None}


def summarise(rows) -> dict:
    """Kernel steps of a point by record kind and part (summed over the draws' records), and the
    short read's worst differences."""
    parts = {}
    for r in rows:
        for rec in r["records"]:
            for part, steps in rec["parts"].items():
                key = f"{rec['kind']}:{part}"
                parts[key] = parts.get(key, 0.0) + steps
    total = sum(parts.values()) or 1.0
    reads = [x for r in rows for x in r["reads"]]

    def spread(key, settles):
        values = [x[key]["any"] for x in reads if x[key] is not None and x["settles"] == settles]
        return None if not values else {"median": float(np.median(values)),
                                        "largest": float(np.max(values)), "records": len(values)}

    return {
        "draws": len(rows),
        "steps_by_part": parts,
        "share_by_part": {k: v / total for k, v in parts.items()},
        # cycles started on the recorded cycle's state, and records that settle over their
        # length (their runs start where the record does, and approach their cycle throughout)
        "next_window_sd": spread("next_window_sd", False),
        "six_periods_sd": spread("six_periods_sd", False),
        "next_window_sd_settling": spread("next_window_sd", True),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=12)
    parser.add_argument("--seed", type=int, default=FIRST_SEED)
    parser.add_argument("--points", type=int, default=24)
    parser.add_argument("--spread", type=float, default=SPREAD,
                        help="relative spread of the points about the truth, each parameter")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench.json"
    rows = finished_rows(path, False, args.seed, args.draws)
    done = {r["seed"] for r in rows}
    for seed in range(args.seed, args.seed + args.draws):
        if seed in done:
            continue
        rows.append(measure_draw(seed, out, args.points, args.spread))
        rows.sort(key=lambda r: r["seed"])
        write_json(path, {"quick": False, "rows": rows, "table": summarise(rows)})
        row = next(r for r in rows if r["seed"] == seed)
        for x in row["reads"]:
            print(f"draw {seed} {x['name']}: period {x['period']:.3g} s, next window "
                  f"{x['next_window_sd']}, six periods {x['six_periods_sd']}", flush=True)
    table = summarise(rows)
    write_json(path, {"quick": False, "rows": rows, "table": table})
    for k, v in table.items():
        print(f"{k}: {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
