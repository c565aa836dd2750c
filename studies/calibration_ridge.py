"""Study ``calibration_ridge``: what one limit cycle does and does not pin down, and model choice.

Hypothesis (paper 002): one limit cycle's amplitude and frequency leave the backlash f and
the dead zone zm on a ridge (with the delay Td free) along paper 002's describing-function family;
the waveform, a second controller setting (B) and open-loop tests break it. And on the same data,
the posterior predictive and WAIC/BIC tell the true hypothesis from a wrong one.

Data: synthetic, M002 (truth) with 1e-4 rad Gaussian sensor noise (seeded): closed loop at
controllers A and B (last 10 s of 20/30 s runs, 1 kHz) and two 5 s open-loop bench tests from rest
(square +-5 mrad at 1 Hz, sine 5 mrad at 2 Hz). Posteriors of (backlash, dead_zone, delay) with
sigma fixed at the estimate, under five data sets: A amplitude+frequency (features frequency, H1),
A+B amplitude+frequency, A+B amplitude+frequency + open loop, A waveform, A+B+open-loop waveform.
Model comparison: M002 and M001i, each with (backlash, dead_zone, delay, sigma), waveform on A.

Deciding figures: ``ridge.png`` (samples in (f, zm) over the DF family), ``comparison.png``
(posterior predictive bands of both hypotheses); ``summary.json`` holds corr(ln f, ln zm), marginal
90 % widths, correlation matrices, convergence, WAIC and BIC (non-finite numbers as ``null``).
Ridge chains are run to a step cap and reported as ridges, not tested for convergence.

Run by ``h1_deadzone_backlash`` (outputs under ``results/h1_deadzone_backlash/mcmc_ridge/``), or
alone: ``python -m tvcid.studies.calibration_ridge [--quick] [--seed N] [--out DIR]``.
"""
from __future__ import annotations

import sys
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

from tvcid.discovery.calibration import Calibration, compare
from tvcid.discovery.calibration.ridge import RidgeAnalysis
from tvcid.discovery.calibration.runner import ConvergenceWarning
from tvcid.figures import pyplot
from tvcid.models import CONTROLLER_A, CONTROLLER_B, M002, OpenLoop
from tvcid.models.cycle_reading import robust_amplitude
from tvcid.models.strict_json import write_json
from tvcid.models.synthetic import synthetic_recording

from .common import study_main

NAME = "calibration_ridge"
PARAMS = ("backlash", "dead_zone", "delay")


@dataclass(frozen=True)
class Config:
    noise: float = 1e-4
    walkers: int = 16
    ridge_steps: int = 1500
    max_steps: int = 3000
    compare_steps: int = 1500
    window: float = 10.0
    #: the comparison's fits look for their maximum over the whole prior box too where the local
    #: one misfits (``Calibration(global_search=...)``); off, each chain starts at the local
    #: maximum found from its hypothesis' values (M001i's on seed 0, ``--quick``: the same
    #: maximum, at a fifth of the cost)
    compare_global_search: bool = True
    #: a chain is converged once its steps exceed this many autocorrelation times
    tau_factor: float = 50.0


QUICK = Config(ridge_steps=100, max_steps=300, compare_steps=200, window=5.0, tau_factor=25.0)


def _data(config, seed, out):
    m = M002()
    n = config.noise
    return {
        "A": synthetic_recording(m, CONTROLLER_A, 20.0, n, seed + 1, out / "m002_A.csv", keep_last=10.0),
        "B": synthetic_recording(m, CONTROLLER_B, 30.0, n, seed + 2, out / "m002_B.csv", keep_last=10.0),
        "square": synthetic_recording(m, OpenLoop.square(5e-3, 1.0), 5.0, n, seed + 3, out / "m002_square.csv"),
        "sine": synthetic_recording(m, OpenLoop.sine(5e-3, 2.0), 5.0, n, seed + 4, out / "m002_sine.csv"),
    }


def run(config, seed, out_dir):
    plt = pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = _data(config, seed, out)
    amp_freq = ("frequency", "H1")
    cases = {
        "A amplitude+frequency": (["A"], "features", amp_freq, config.ridge_steps),
        "A+B amplitude+frequency": (["A", "B"], "features", amp_freq, config.ridge_steps),
        "A+B amp+freq + open loop": (["A", "B", "square", "sine"], "features", amp_freq, config.max_steps),
        "A waveform": (["A"], "waveform", amp_freq, config.max_steps),
        "A+B+open loop waveform": (["A", "B", "square", "sine"], "waveform", amp_freq, config.max_steps),
    }
    posteriors, timings = {}, {}
    warnings.simplefilter("ignore", ConvergenceWarning)
    for label, (keys, lik, feats, steps) in cases.items():
        t0 = time.perf_counter()
        cal = Calibration("M002", params=PARAMS, likelihood=lik, features=feats,
                          window=config.window, n_walkers=config.walkers, max_steps=steps,
                          tau_factor=config.tau_factor, seed=seed).fit([data[k] for k in keys])
        posteriors[label] = cal.posterior_
        timings[label] = time.perf_counter() - t0
        print(f"{label}: {cal.report_.iterations} steps, tau max {max(cal.report_.tau):.0f}, "
              f"converged {cal.report_.converged}, {timings[label]:.0f} s", flush=True)
    truth = {n: float(getattr(M002(), n)) for n in PARAMS}
    ridge = RidgeAnalysis(posteriors, amplitude=robust_amplitude(data["A"].t, data["A"].delta),
                          truths=truth, frequency=data["A"].features().frequency,
                          controller=CONTROLLER_A, params=M002())
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    ridge.plot(ax=ax1)
    ax1.set_title("one cycle's amplitude+frequency: a ridge along the DF family")
    ridge.plot(ax=ax2, zoom=0.06)
    ax2.set_title("zoom: B, open loop and the waveform shrink it")
    fig.tight_layout()
    fig.savefig(out / "ridge.png", dpi=110)
    plt.close(fig)

    # model comparison on controller A, both on the waveform (a record that fell back to its
    # features in one model only would make the likelihoods incomparable)
    fits = {}
    for name in ("M002", "M001i"):
        fits[name] = Calibration(name, params=PARAMS + ("sigma",), window=config.window,
                                 n_walkers=config.walkers, max_steps=config.compare_steps,
                                 seed=seed, features_fallback=False,
                                 global_search=config.compare_global_search).fit([data["A"]])
    comp = compare(fits)
    axes = comp.plot()
    axes[0].figure.tight_layout()
    axes[0].figure.savefig(out / "comparison.png", dpi=110)
    plt.close(axes[0].figure)
    summary = {
        "config": asdict(config),
        "seed": seed,
        "truth": truth,
        "ridge": ridge.to_dict(),
        "timings_s": timings,
        "comparison": comp.to_dict(),
        "comparison_fits": {k: {"converged": f.report_.converged,
                                "map": f.posterior_.map,
                                "predictive_rms": comp.predictive[k].rms_error("m002_A")}
                            for k, f in fits.items()},
    }
    write_json(out / "summary.json", summary, default=float)
    return summary


def describe(summary):
    print(f"{'data':<28} {'corr ln f,ln zm':>15} {'w90 f':>8} {'w90 zm':>8} {'w90 Td':>8} conv  truth in 90 %")
    for r in summary["ridge"]["rows"]:
        w = r["width90_relative"]
        outside = [n for n, ok in r["truth_inside_90"].items() if not ok]
        print(f"{r['label']:<28} {r['corr_log_pair']:15.3f} {w['backlash']:8.3g} "
              f"{w['dead_zone']:8.3g} {w['delay']:8.3g} {r['converged']!s:5} "
              f"{'all' if not outside else 'not ' + ', '.join(outside)}")
    for row in summary["comparison"]["table"]:
        print(f"{row['model']:<6} WAIC {row['waic']:.1f}  BIC {row['bic']:.1f}  "
              f"max loglike {row['max_loglike']:.1f}")


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
