"""Study ``h6_controller_design``: a new controller's cycle, how sure we are, and the next test.

Hypothesis (paper 002, section 1): the VLS attitude loop is designed around the identified
actuator, so the designer asks "with this controller, what cycle will I get, and how sure are
we?" and the experimenter "which test should I run next?". A model calibrated on the bundled
records answers both: (1) its posterior, pushed through closed-loop simulations of every draw
(:mod:`tvcid.discovery.prediction`), maps the cycle's amplitude and frequency with a 90 % band over
Kp x Kd and locates the stability boundary where the generating model's own long runs put it;
(2) a lead filter raises the cycle's frequency and lowers its amplitude, and a lightly damped
bending mode that makes the plain PD loop diverge is tamed by a notch at its frequency, at the
price of the notch's phase lag at the cycle's frequency (the wider the notch, the larger the
cycle); (3) ranked by expected information gain, a test not run yet teaches more than a repeat of
a tested one.

Set-up: M000's structure calibrated on the four bundled records (synthetic, M000 with in-loop
noise: ``data/README.md``) with the features likelihood; dead zone, backlash, delay and the
sensor-noise sd sampled, the in-loop noise power fixed at the open-loop square record's noise
floor (:func:`tvcid.discovery.spectral.noise_floor`), every other value M000's. The examples at
controller A: a lead ``(1 + s/5)/(1 + s/p)``, ``p`` swept from 6 to 60 rad/s; a bending mode at
60 rad/s (damping 0.02, gain 0.01) and a notch at its frequency (depth 0.1), the notch's damping
swept from 0.02 to 0.5. Every prediction is set against the generating model (the records' own
parameters, from their sidecars) run for 120 s at the records' step, and against how much that
model's own cycle moves between 4 s windows (:mod:`tvcid.studies.h6_checks`).

Deciding figures: ``map.png`` (median amplitude, band width, median frequency and fraction of
draws diverging over Kp x Kd at mu 12.3, with the stability boundary and the settings where the
draws' majority outcome is not the generating model's) and ``filters.png`` (lead and notch
sweeps: median, 90 % band and the describing function of the median model, beside the plain PD's
band, with the generating model's long runs); ``boundary.png`` (the boundary along Kd at
controller A's Kp) and ``design.png`` (the ranked menu) beside them.

Run: ``tvcid study h6_controller_design [--quick] [--seed N]`` or
``python -m tvcid.studies.h6_controller_design [--quick] [--seed N] [--out DIR]``. Outputs under
``results/h6_controller_design/``: ``summary.json`` (every number, also in the report),
``map.json``/``map.csv``/``maps.npz`` (the maps), ``design.json`` (the ranking), the figures, and
the chain checkpointed in ``fit/chain.h5`` (a rerun resumes it; quick and full runs share its
walkers, so a full run extends a quick one).
"""
from __future__ import annotations

import sys
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvcid.discovery.calibration import Calibration
from tvcid.discovery.calibration.runner import ConvergenceWarning
from tvcid.discovery.prediction import PredictionConfig, cycle_map, load_posterior_draws, predict_cycle
from tvcid.discovery.prediction.design import load_candidates, rank_experiments
from tvcid.discovery.spectral import noise_floor
from tvcid.models.controllers import BendingMode
from tvcid.models.recording import load_recording
from tvcid.models.strict_json import write_json

from .common import study_main
from .h6_checks import (
    DATA,
    RECORDINGS,
    SETTING_A,
    band_widths,
    boundary_of_map,
    check_map,
    first_switch,
    generating_cycles,
    generating_wander,
    line_summary,
    prediction_summary,
    with_generating,
)
from .h6_figures import plot_boundary, plot_corner, plot_design, plot_filters, plot_map, report_lines

NAME = "h6_controller_design"
PARAMS = ("dead_zone", "backlash", "delay", "sigma")
#: The experiment menu; ``tested`` marks repeats of a bundled record (the ranking ignores it).
MENU = (
    {"name": "repeat closed loop A", "kind": "closed", "kp": 5.84, "kd": 0.062, "mu": 12.3,
     "tested": True},
    {"name": "repeat closed loop B", "kind": "closed", "kp": 9.8, "kd": 0.06, "mu": 4.5,
     "tested": True},
    {"name": "closed loop Kp 7.5 Kd 0.075 mu 8", "kind": "closed", "kp": 7.5, "kd": 0.075,
     "mu": 8.0},
    {"name": "closed loop Kp 5.84 Kd 0.05 mu 12.3", "kind": "closed", "kp": 5.84, "kd": 0.05,
     "mu": 12.3},
    {"name": "closed loop A + lead 5/20 rad/s", "kind": "closed", "kp": 5.84, "kd": 0.062,
     "mu": 12.3, "lead_zero": 5.0, "lead_pole": 20.0},
    {"name": "repeat open-loop square 20 mrad 1 Hz", "kind": "open", "waveform": "square",
     "amplitude": 0.02, "frequency": 1.0, "duration": 8.0, "tested": True},
    {"name": "repeat open-loop sine 20 mrad 2 Hz", "kind": "open", "waveform": "sine",
     "amplitude": 0.02, "frequency": 2.0, "duration": 8.0, "tested": True},
    {"name": "open-loop square 2 mrad 1 Hz", "kind": "open", "waveform": "square",
     "amplitude": 0.002, "frequency": 1.0, "duration": 8.0},
    {"name": "open-loop square 5 mrad 2 Hz", "kind": "open", "waveform": "square",
     "amplitude": 0.005, "frequency": 2.0, "duration": 8.0},
    {"name": "open-loop sine 2 mrad 5 Hz", "kind": "open", "waveform": "sine",
     "amplitude": 0.002, "frequency": 5.0, "duration": 8.0},
)


@dataclass(frozen=True)
class Config:
    """Sizes of the calibration, the maps and the ranking (grids as ``(low, high, n)``)."""

    walkers: int = 12
    steps: int = 600
    draws: int = 200
    kp: tuple = (3.0, 12.0, 20)
    kd: tuple = (0.02, 0.12, 20)
    kd_boundary: tuple = (0.035, 0.06, 26)
    lead_zero: float = 5.0
    lead_example_pole: float = 20.0
    lead_poles: tuple = (6.0, 60.0, 12)
    #: bending mode (frequency rad/s, damping, gain): the smallest gain of 0.002, 0.005 and 0.01
    #: that makes M000 at controller A diverge (it does within 10 s)
    bending: tuple = (60.0, 0.02, 0.01)
    notch_depth: float = 0.1
    notch_example_damping: float = 0.1
    notch_dampings: tuple = (0.02, 0.5, 10)
    design_draws: int = 200
    design_truths: int = 24
    truth_seconds: float = 120.0
    #: transient (s) of the filter examples: each draw restarts with the filter's and the bending
    #: mode's states at zero, which the default 3 s do not settle behind the narrowest notch
    filter_transient: float = 10.0


QUICK = Config(steps=20, draws=20, kp=(3.0, 12.0, 5), kd=(0.02, 0.12, 4),
               kd_boundary=(0.03, 0.065, 6), lead_poles=(6.0, 60.0, 4),
               notch_dampings=(0.02, 0.5, 4), design_draws=16, design_truths=4)


def _linear(spec):
    lo, hi, n = spec
    return np.linspace(lo, hi, int(n))


def _geometric(spec):
    lo, hi, n = spec
    return np.geomspace(lo, hi, int(n))


def calibrate(config, seed, out_dir):
    """Calibrate M000 on the four bundled records (the model the designer of paper 002, section 1,
    needs), checkpointing the chain in ``out_dir/fit/chain.h5`` (a rerun resumes it).

    Parameters
    ----------
    config : Config
        ``walkers`` and ``steps`` (the chain's step cap, resumed steps included).
    seed : int
        Seed of the sampler (its walkers' start and moves).
    out_dir : Path

    Returns
    -------
    cal : tvcid.discovery.calibration.Calibration
        The fitted calibration (``posterior_``, ``report_``).
    info : dict
        The fit's set-up, convergence and every parameter's median, 90 % interval, width and
        truth (from the records' sidecars).
    """
    files = [DATA / f"{name}.csv" for name in RECORDINGS]
    # in-loop noise at the floor of the open-loop square record (h5_noise: within 20 % there)
    floor = noise_floor(load_recording(files[2]))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        cal = Calibration("M000", params=PARAMS, fixed={"noise_power": floor.power,
                                                         "noise_band": floor.noise_band},
                          likelihood="features", n_walkers=config.walkers,
                          max_steps=config.steps, seed=seed,
                          backend=out_dir / "fit" / "chain.h5").fit(files)
    post = cal.posterior_.summary()
    params = {}
    for n, p in post["parameters"].items():
        params[n] = {**{k: p[k] for k in ("q05", "q50", "q95", "truth")},
                     "width90_pct": 100 * (p["q95"] - p["q05"]) / p["q50"],
                     "truth_inside_90": (None if p["truth"] is None
                                         else bool(p["q05"] <= p["truth"] <= p["q95"]))}
    info = {"recordings": list(RECORDINGS), "params": list(PARAMS),
            "noise_power_fixed": floor.power, "noise_band_fixed": floor.noise_band,
            "iterations": post["iterations"], "new_steps": cal.report_.new_steps,
            "walkers": config.walkers,
            "converged": post["converged"], "n_over_tau": post["n_over_tau"],
            "acceptance": post["acceptance"], "inflation": post["inflation"],
            "at_prior_bound": post["at_prior_bound"], "parameters": params,
            "seconds": time.perf_counter() - t0}
    return cal, info


def run(config: Config, seed: int, out_dir: Path) -> dict:
    """Run the study: calibrate, map, filter examples, experiment ranking, figures.

    Answers paper 002's (section 1) designer ("with this controller, what cycle will I get, and
    how sure are we?") and experimenter ("which test should I run next?") on the bundled records.

    Parameters
    ----------
    config : Config
    seed : int
        Seed of the sampler, of the draws' selection and of the ranking's synthetic records and
        hypothetical truths.
    out_dir : Path
        Where ``summary.json``, the maps, the ranking and the figures are written (and the chain,
        ``fit/chain.h5``, checkpointed).

    Returns
    -------
    dict
        The summary (also ``out_dir/summary.json``).
    """
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    timings = {}
    cal, fit = calibrate(config, seed, out_dir)
    timings["calibration"] = fit["seconds"]
    draws = load_posterior_draws(out_dir / "fit", n_draws=config.draws, seed=seed)
    pconfig = PredictionConfig()

    # 1. Kp x Kd map at controller A's vehicle
    t0 = time.perf_counter()
    cmap = cycle_map(draws, SETTING_A, {"kp": _linear(config.kp), "kd": _linear(config.kd)},
                     pconfig, describing=True)
    write_json(out_dir / "map.json", cmap.to_dict(), indent=1)
    cmap.to_csv(out_dir / "map.csv")
    timings["map"] = time.perf_counter() - t0
    # the same grid for the generating model (long runs): where the draws' majority outcome
    # disagrees with it, the prediction's 7 s runs misread the loop
    t0 = time.perf_counter()
    map_check = check_map(cmap, config.truth_seconds)
    timings["map_check"] = time.perf_counter() - t0

    # the boundary at controller A's Kp, finer and with the draws' spread
    t0 = time.perf_counter()
    kd_map = cycle_map(draws, SETTING_A, {"kd": _linear(config.kd_boundary)}, pconfig,
                       describing=False)
    kd_values, div = kd_map.values[0], kd_map.summary["fraction_diverging"]
    # the fraction diverging at a Kd is the share of draws whose own critical Kd lies above it:
    # points strictly between 5 % and 95 % would resolve the draws' spread of the boundary
    critical = {"grid_interval": first_switch(kd_values, div > 0.5)}
    critical["draws_split"] = int(np.sum((div > 0.05) & (div < 0.95)))
    kd_truth = generating_cycles([SETTING_A.replace(kd=float(k)) for k in kd_values],
                                 config.truth_seconds)
    critical["generating_grid_interval"] = first_switch(
        kd_values, np.array([g["outcome"] == "diverged" for g in kd_truth]))
    timings["boundary"] = time.perf_counter() - t0

    # 2. the plain PD, a lead, a bending mode with and without a notch, at controller A. Every
    # draw restarts from the pilot's actuator and attitude state with the filter's and the
    # bending mode's states at zero: 3 s do not settle a lightly damped mode behind a narrow
    # notch (notch damping 0.02: 4.80 mrad after 3 s, 3.8 after 10 s and in a 120 s run)
    t0 = time.perf_counter()
    fconfig = PredictionConfig(transient=config.filter_transient)
    plain = predict_cycle(draws, SETTING_A, fconfig)
    lead_setting = SETTING_A.replace(lead_zero=config.lead_zero,
                                     lead_pole=config.lead_example_pole)
    lead = predict_cycle(draws, lead_setting, fconfig)
    lead_map = cycle_map(draws, lead_setting, {"lead_pole": _geometric(config.lead_poles)},
                         fconfig, describing=True)
    bending = BendingMode(*config.bending)
    bent = predict_cycle(draws, SETTING_A.replace(bending=bending), fconfig)
    notch_setting = SETTING_A.replace(bending=bending, notch_frequency=bending.frequency,
                                      notch_damping=config.notch_example_damping,
                                      notch_depth=config.notch_depth)
    notched = predict_cycle(draws, notch_setting, fconfig)
    notch_map = cycle_map(draws, notch_setting,
                          {"notch_damping": _geometric(config.notch_dampings)}, fconfig,
                          describing=True)
    examples = {"plain_pd": (plain, SETTING_A), "lead": (lead, lead_setting),
                "pd_with_bending": (bent, SETTING_A.replace(bending=bending)),
                "notch": (notched, notch_setting)}
    gen = generating_cycles([st for _, st in examples.values()], config.truth_seconds)
    settings = {k: st for k, (_, st) in examples.items()}
    examples = {k: with_generating(prediction_summary(pred), g)
                for (k, (pred, _)), g in zip(examples.items(), gen)}
    for k, d in examples.items():
        d["generating_wander"] = (generating_wander(settings[k], config.truth_seconds)
                                  if d["generating"]["outcome"] == "cycle" else None)
    lead_truth = generating_cycles([lead_setting.replace(lead_pole=float(v))
                                    for v in lead_map.values[0]], config.truth_seconds)
    notch_truth = generating_cycles([notch_setting.replace(notch_damping=float(v))
                                     for v in notch_map.values[0]], config.truth_seconds)
    timings["filters"] = time.perf_counter() - t0

    # 3. which test next
    t0 = time.perf_counter()
    design_draws = load_posterior_draws(out_dir / "fit", n_draws=config.design_draws, seed=seed)
    menu = [{k: v for k, v in c.items() if k != "tested"} for c in MENU]
    ranking = rank_experiments(design_draws, load_candidates(menu), seed=seed,
                               n_truths=config.design_truths)
    tested = {c["name"] for c in MENU if c.get("tested")}
    for row in ranking.rows:
        row["tested"] = row["name"] in tested
    write_json(out_dir / "design.json", ranking.to_dict(), indent=1)
    timings["design"] = time.perf_counter() - t0

    np.savez(out_dir / "maps.npz", kp=cmap.values[0], kd=cmap.values[1],
             **{f"map_{k}": v for k, v in cmap.summary.items()},
             kd_boundary=kd_values, kd_boundary_fraction_diverging=div,
             lead_poles=lead_map.values[0], **{f"lead_{k}": v for k, v in lead_map.summary.items()},
             notch_dampings=notch_map.values[0],
             **{f"notch_{k}": v for k, v in notch_map.summary.items()})

    s = cmap.summary
    plain_d, lead_d = examples["plain_pd"], examples["lead"]
    summary = {
        "study": NAME, "config": asdict(config), "seed": seed,
        "fit": fit,
        "draws": len(draws),
        "prediction_config": asdict(pconfig),
        "filter_prediction_config": asdict(fconfig),
        "map": {
            "shape": list(cmap.shape), "mu": SETTING_A.mu,
            "kp": cmap.values[0].tolist(), "kd": cmap.values[1].tolist(),
            "cells_diverging": int(np.sum(s["fraction_diverging"] > 0.5)),
            "cells_oscillating": int(np.sum(s["fraction_oscillating"] > 0.5)),
            "cells_at_rest": int(np.sum((s["fraction_diverging"] <= 0.5)
                                        & (s["fraction_oscillating"] <= 0.5))),
            "cells_split": int(np.sum((s["fraction_diverging"] > 0.05)
                                      & (s["fraction_diverging"] < 0.95))),
            "cells_not_settled": (int(np.sum(s["fraction_not_settled"] > 0.5))
                                  if "fraction_not_settled" in s else None),
            "boundary": boundary_of_map(cmap),
            "band_widths": band_widths(s),
            "generating_check": map_check,
        },
        "boundary_at_A": {"kp": SETTING_A.kp, "kd": kd_values.tolist(),
                          "fraction_diverging": div.tolist(),
                          "critical_kd": critical, "generating": kd_truth,
                          "amplitude_q50": [None if not np.isfinite(v) else float(v)
                                            for v in kd_map.summary["amplitude_q50"]],
                          "amplitude_error_pct_vs_generating": [
                              None if g["amplitude"] is None or not np.isfinite(v)
                              else float(100 * (v / g["amplitude"] - 1))
                              for v, g in zip(kd_map.summary["amplitude_q50"], kd_truth)]},
        "plain_pd": plain_d,
        "lead": {
            "zero": config.lead_zero, "example_pole": config.lead_example_pole,
            "example": lead_d,
            "frequency_ratio": lead_d["frequency"]["q50"] / plain_d["frequency"]["q50"]
            if lead_d["frequency"]["q50"] and plain_d["frequency"]["q50"] else None,
            "amplitude_ratio": lead_d["amplitude"]["q50"] / plain_d["amplitude"]["q50"]
            if lead_d["amplitude"]["q50"] and plain_d["amplitude"]["q50"] else None,
            "sweep": line_summary(lead_map), "sweep_generating": lead_truth,
        },
        "notch": {
            "bending": bending.to_dict(), "depth": config.notch_depth,
            "example_damping": config.notch_example_damping,
            "pd_with_bending": examples["pd_with_bending"],
            "example": examples["notch"],
            "sweep": line_summary(notch_map), "sweep_generating": notch_truth,
        },
        "design": {
            "params": list(ranking.params),
            "draws": len(design_draws), "truths": config.design_truths,
            "ranking": ranking.rows,
            "best": ranking.best["name"],
            "best_is_repeat": ranking.best["tested"],
            "best_repeat": next(r["name"] for r in ranking.rows if r["tested"]),
        },
        "timings": timings,
    }
    plot_filters(summary, out_dir / "filters.png", lead_map, notch_map)
    plot_boundary(summary, out_dir / "boundary.png")
    plot_map(cmap, map_check["disagreements"], len(draws), out_dir / "map.png")
    plot_design(ranking, out_dir / "design.png")
    plot_corner(cal, out_dir / "corner.png")
    timings["total"] = time.perf_counter() - t_start
    write_json(out_dir / "summary.json", summary, default=float)
    return summary


def describe(summary):
    print("\n".join(report_lines(summary)))


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
