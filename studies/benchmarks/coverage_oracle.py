"""Is a coverage miss the data's own noise, or the method? An exact-edge oracle on a draw's open-loop records.

``python -m tvcid.studies.benchmarks.coverage_oracle INDEX [--renoise K] [--out DIR]``  (5-15 minutes a draw)
``python -m tvcid.studies.benchmarks.coverage_oracle INDEX [INDEX ...] --replay-only``

Hypothesis: when the coverage benchmark (:mod:`tvcid.studies.benchmarks.coverage`) puts a truth outside its
90 % interval because an open-loop record prefers another point, either the likelihood term is
biased (the command's replay from 200 Hz samples, its edge-timing nuisance, the solver's step) or
that record's noise realisation happens to favour the other point. An oracle separates the two:
it knows the square's exact edges (the generator's analytic command) and simulates 10x finer than
the fit (:data:`ORACLE_DT`), so it has neither the replay nor the solver error. Deciding numbers,
per open-loop record of draw ``INDEX``:

* ``term_gain``: how much the calibration's own term (:class:`tvcid.discovery.calibration.likelihood.
  OpenLoopTerm`, at the benchmark's step and refinement) improves on the truth's log-likelihood by moving
  the sampled parameters (Nelder-Mead from the truth), and where to;
* ``oracle_gain``: the same for the oracle on the same data;
* ``renoised_gains``: the oracle's gain on ``K`` fresh noise realisations of the same truth and
  command (acquisition as the generator's: noise, offset, quantisation), and the share of them at
  least as large as the record's own (a small share: the record's noise is a tail one);
* ``reference_vs_kernel``: the largest difference between the plain-Python reference path (which
  made the data) and the kernel on the noise-free response;
* ``replay_chi_square``: what replaying the command from its samples adds to the chi-square at
  the truth, noise-free at the oracle's step, against the analytic command: read by its chords
  (``chords``) and as :meth:`tvcid.models.recording.Recording.experiment` replays it (``replayed``).
  ``--replay-only`` prints just this for several draws (seconds each): a sine's chords lower its
  fundamental, which at 200 Hz and 2.6 Hz adds 90 (draw 17). For a square it is the replayed
  edges' chi-square before the term integrates their timing out (thousands at 200 Hz; compare
  ``term_gain`` with ``oracle_gain`` there instead).

Per closed-loop record (the features likelihood), the step ladder: the model's features at the
truth at the benchmark's step and at 1/2, 1/4 and 1/8 of it, each as the features term builds it
(its own step-doubling correction included), in sd of the observed features. A cycle whose period
locks to the step's grid keeps the same features at a step and its half, so the step-doubling
check sees no error there while a finer pair moves (``ladder``; draw 2's second record).

A term gain far above the oracle's points at the method; an oracle gain as large as the term's,
and common among re-noised records, at the noise. Chi-square/2 with as many degrees of freedom as
parameters moved is the reference for a smooth likelihood (mean k/2).

Written: ``DIR/draw<INDEX>.json``; data reuse ``results/bench_coverage/data`` (the benchmark's).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tvcid.models.strict_json import write_json

#: Step (s) of the oracle's simulations: 10x finer than the features' 5e-4 s and the data's
#: generator step (:data:`tvcid.studies.benchmarks.scenarios.DATA_DT`) apart by the same factor.
ORACLE_DT = 5e-5
#: Relative size of the Nelder-Mead start simplex around the truth.
SIMPLEX = 0.03


def _maximise(cost, n):
    """``(gain, relative move)``: the drop of ``cost`` from the truth (relative move 0)."""
    from scipy.optimize import minimize

    at_truth = cost(np.zeros(n))
    res = minimize(cost, np.zeros(n), method="Nelder-Mead",
                   options={"xatol": 1e-5, "fatol": 1e-3,
                            "initial_simplex": np.vstack([np.zeros(n), SIMPLEX * np.eye(n)])})
    return float(at_truth - res.fun), res.x


def oracle_check(index, renoise=6, workdir=Path("results/bench_coverage/data")):
    """The numbers of the module docstring for every open-loop record of draw ``index``."""
    from tvcid.discovery.calibration.likelihood import OpenLoopTerm
    from tvcid.models import SimulationDiverged, simulate
    from tvcid.models.recording import load_recording
    from tvcid.models.reference import simulate_reference
    from tvcid.models.structures import Structure

    from .coverage import SAMPLED, Config, coverage_scenario, priors_for
    from .scenarios import DATA_DT, write_recordings

    config = Config()
    scenario = coverage_scenario(index, config)
    truth, acq = scenario.truth, scenario.acquisition
    names = [n for n in SAMPLED if n in priors_for(Structure.of_params(truth))]
    x0 = np.array([getattr(truth, n) for n in names])

    def at(z):
        return truth.replace(**dict(zip(names, x0 * (1.0 + np.asarray(z)))))

    paths = write_recordings(scenario, Path(workdir) / f"draw{index:03d}", reuse=True)
    rows = []
    for i, (design, path) in enumerate(zip(scenario.recordings, paths)):
        if design.kind != "open":
            continue
        rec = load_recording(path)
        sigma = acq.noise_sd
        exp = design.experiment()
        term = OpenLoopTerm(rec, None, None, config.dt).setup(truth)  # as the benchmark builds it

        def term_cost(z):
            ll = term.loglike([at(z)], [sigma])[0]
            return -float(ll) if np.isfinite(ll) else np.inf

        def oracle_cost(z, data):
            try:
                tr = simulate(at(z), exp, float(rec.t[-1]), dt=ORACLE_DT, rate=design.rate)
            except (ValueError, ArithmeticError, SimulationDiverged):
                return np.inf
            r = data - np.interp(rec.t, tr.t, tr.delta)
            r = r - r.mean()  # the sensor offset, profiled as the term does
            return 0.5 * float(np.sum(r * r)) / sigma**2

        term_gain, term_move = _maximise(term_cost, len(names))
        oracle_gain, oracle_move = _maximise(lambda z: oracle_cost(z, rec.delta), len(names))
        clean = simulate_reference(truth, exp, design.duration, dt=DATA_DT, rate=design.rate)
        kernel = simulate(truth, exp, design.duration, dt=DATA_DT, rate=design.rate)
        renoised = []
        for k in range(renoise):
            rng = np.random.default_rng([scenario.seed, i, 7919, k])
            data = acq.measure(clean.delta, rng)
            renoised.append(_maximise(lambda z: oracle_cost(z, data[: rec.t.size]), len(names))[0])
        rows.append({
            "recording": path.name, "design": design.__dict__, "parameters": names,
            "term_step": term.sim_dt,
            "term_gain": term_gain, "term_move_relative": dict(zip(names, term_move.tolist())),
            "oracle_gain": oracle_gain,
            "oracle_move_relative": dict(zip(names, oracle_move.tolist())),
            "renoised_gains": renoised,
            "share_renoised_at_least_as_large": float(np.mean(np.array(renoised) >= oracle_gain))
            if renoised else None,
            "chi2_half_mean": len(names) / 2,
            "reference_vs_kernel": float(np.max(np.abs(clean.delta - kernel.delta))),
            "replay_chi_square": replay_chi_square(truth, design, rec, sigma),
        })
    ladders = [step_ladder(truth, names, path, config) for design, path in
               zip(scenario.recordings, paths) if design.kind == "closed"]
    return {"index": index, "seed": scenario.seed, "structure": Structure.of_params(truth).name,
            "truth": {n: float(getattr(truth, n)) for n in names}, "noise_sd": acq.noise_sd,
            "records": rows, "closed_loop": ladders}


def replay_chi_square(truth, design, recording, sigma) -> dict:
    """Chi-square at the truth that the command's replay adds (module docstring), noise-free."""
    from tvcid.models import OpenLoop, simulate

    t = recording.t - recording.t[0]
    end = float(t[-1])

    def response(exp):
        tr = simulate(truth, exp, end, dt=ORACLE_DT)
        return np.interp(t, tr.t, tr.delta)

    exact = response(design.experiment())
    out = {}
    for name, exp in (("chords", OpenLoop.from_samples(t, recording.u)),
                      ("replayed", recording.experiment())):
        r = response(exp) - exact
        r = r - r.mean()
        out[name] = float(np.sum(r * r)) / sigma**2
    return out


def replay_table(indices, workdir=Path("results/bench_coverage/data")):
    """``replay_chi_square`` of every open-loop record of the draws ``indices``."""
    from tvcid.models.recording import load_recording

    from .coverage import Config, coverage_scenario
    from .scenarios import write_recordings

    rows = []
    for index in indices:
        scenario = coverage_scenario(index, Config())
        paths = write_recordings(scenario, Path(workdir) / f"draw{index:03d}", reuse=True)
        for design, path in zip(scenario.recordings, paths):
            if design.kind == "open":
                rows.append({"index": index, "recording": path.name, "waveform": design.waveform,
                             "frequency": design.frequency, "amplitude": design.amplitude,
                             "rate": design.rate, "noise_sd": scenario.acquisition.noise_sd,
                             **replay_chi_square(scenario.truth, design, load_recording(path),
                                                 scenario.acquisition.noise_sd)})
    return rows


def step_ladder(truth, names, path, config, levels=4):
    """The features term of one closed-loop record at the truth, at the benchmark's step and
    ``levels - 1`` halvings of it: features, their step-doubling change and the whitened
    residuals (sd of the observed features)."""
    from tvcid.discovery.calibration import Calibration
    from tvcid.models.structures import Structure

    from .coverage import priors_for

    priors = priors_for(Structure.of_params(truth))
    ladder = []
    for j in range(levels):
        dt = config.dt / 2**j
        cal = Calibration(truth, params=tuple(names), priors=priors, likelihood="features",
                          window=config.window, transient=config.transient, dt=dt, seed=0,
                          spread=config.spread).setup([path])
        term = cal.terms_[0]
        d = term.describe()
        z = term.whitened_residuals([truth], np.array([term.sigma_hat]))[0]
        ladder.append({"dt": term.simulator.dt, "model": term.model_features([truth])[0].tolist(),
                       "step_doubling_sd": d["solver_sd"], "whitened_at_truth": z.tolist()})
    return {"recording": Path(path).name, "features": list(d["features"]),
            "observed": d["observed"], "sd": d["sd"], "ladder": ladder}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("index", type=int, nargs="+", help="the coverage benchmark's draw index "
                        "(several with --replay-only)")
    parser.add_argument("--replay-only", action="store_true",
                        help="only the chi-square the command's replay adds at the truth")
    parser.add_argument("--renoise", type=int, default=6, help="fresh noise realisations (default 6)")
    parser.add_argument("--out", default="results/coverage_oracle", help="output directory")
    args = parser.parse_args(argv)
    if min(args.index) < 0 or args.renoise < 0:
        parser.error("INDEX and --renoise must be non-negative")
    if len(args.index) > 1 and not args.replay_only:
        parser.error("several draws only with --replay-only")
    if args.replay_only:
        for r in replay_table(args.index):
            print(f"draw {r['index']} {r['recording']} {r['waveform']} {r['frequency']:.2f} Hz "
                  f"{1e3 * r['amplitude']:.1f} mrad at {r['rate']:.0f} Hz, noise {r['noise_sd']:.1e}: "
                  f"chi-square at the truth, chords {r['chords']:.3g}, replayed {r['replayed']:.2g}")
        return 0
    args.index = args.index[0]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = oracle_check(args.index, args.renoise)
    if not result["records"]:
        print(f"draw {args.index} has no open-loop record: closed-loop step ladders only")
    for r in result["records"]:
        print(f"{r['recording']}: term gain {r['term_gain']:.2f} nats, oracle {r['oracle_gain']:.2f} "
              f"(moves {', '.join(f'{n} {v:+.3f}' for n, v in r['oracle_move_relative'].items())}); "
              f"re-noised {', '.join(f'{g:.2f}' for g in r['renoised_gains'])} "
              f"(chi-square/2 mean {r['chi2_half_mean']:.1f}); reference vs kernel "
              f"{r['reference_vs_kernel']:.2g} rad; replay chi-square {r['replay_chi_square']}")
    for c in result["closed_loop"]:
        steps = "; ".join(f"{r['dt']:.3g} s: " + " ".join(f"{v:+.2f}" for v in r["whitened_at_truth"])
                          for r in c["ladder"])
        print(f"{c['recording']} ({', '.join(c['features'])}) at the truth, in sd: {steps}")
    path = out / f"draw{args.index:03d}.json"
    write_json(path, result, default=float)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
