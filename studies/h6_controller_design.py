"""Study ``h6_controller_design``: a new controller's cycle, how sure we are, and the next test.

Hypothesis (paper 002, section 1): the identification is worth doing because the VLS attitude
loop is designed around it: a lead filter shapes the limit cycle and a notch filter keeps the
bending mode out of the loop, so the designer asks "with this controller, what cycle will I get,
and how sure are we?" and the experimenter "which test should I run next?". A model calibrated on
the bundled records answers both: (1) its posterior, pushed through closed-loop simulations of
every draw (:mod:`discovery.prediction`), maps the cycle's amplitude and frequency with a 90 %
band over Kp x Kd around the tested settings and locates the stability boundary; (2) a lead filter
raises the cycle's frequency and lowers its amplitude; a lightly damped bending mode that makes the
plain PD loop diverge is tamed by a notch at its frequency, at the price of the notch's phase lag
at the cycle's frequency (the wider the notch, the larger the cycle); (3) ranked by expected
information gain, a test that was not run yet teaches more than a repeat of a tested one.

Set-up. M000's own structure (the bundled records are synthetic, M000 with in-loop noise: see
``data/README.md``) is calibrated on all four records (cycles at controllers A and B, open-loop
square and sine): dead zone, backlash, delay and the sensor-noise sd sampled, the features
likelihood in closed loop as ``discover`` and the mismatch tests use it, the in-loop noise power
fixed at the open-loop square record's noise floor (:func:`discovery.spectral.noise_floor`), every
other value M000's (the priors are centred on them: this study is about prediction, not
identification; ``discover`` identifies the structure from nothing). The chain is checkpointed in
``fit/chain.h5`` (a rerun resumes it; quick and full runs share its walkers, so a full run extends
a quick one). The examples, chosen by simulating M000 and checked by the predictions themselves:

* lead ``(1 + s/5)/(1 + s/p)`` at controller A, the pole ``p`` swept from 6 to 60 rad/s;
* bending mode at 60 rad/s, damping 0.02, gain 0.01 (gain picked as the smallest tried, of 0.002,
  0.005, 0.01, that makes M000 at controller A diverge: it does within 10 s); notch at 60 rad/s,
  depth 0.1, its damping swept from 0.02 to 0.5 (at 0.5 the notch's lag at the cycle's 8.2 rad/s
  makes the loop diverge: M000 passes 1 rad after about 50 s).

Every prediction is checked against the generating model (the records' own parameters, from their
sidecars) run for 120 s at the records' step, and against how much that model's own cycle moves
between 4 s windows (M000's cycle is not periodic). The filter examples use a 10 s transient
instead of the default 3 s: each draw restarts from the pilot's actuator and attitude state with
the filter's and the bending mode's states at zero, and behind the narrowest notch 3 s left the
cycle at 4.80 mrad where long runs settle at 3.8 (the prediction now lengthens the transient to
8 time constants of the slowest filter state by itself: 6.7 s there, 3.92 mrad).

What was found (full run, seed 0; ``summary.json``; with :mod:`discovery.prediction` as of
commit f665fa9, whose draws carry their own in-loop noise and whose bands add the solver error):

* the four records pin the sampled parameters to 90 % widths of 0.55 % (dead zone), 1.75 %
  (backlash) and 1.05 % (delay), the truth inside each (600 steps x 12 walkers, N/tau 27: not
  converged by the 50-tau rule). Over the oscillating settings of the map the band is 1.2 %
  (amplitude) and 0.09 % (frequency) wide (medians; at most 35 % and 3 % where Kd >= 0.08 and the
  cycle is 1-2 mrad): mostly the in-loop noise's realisations, not the parameters. At controller
  A, with the lead and with the notch the medians lie 0.02-1.2 % from the generating model's
  120 s runs; the amplitude bands hold its cycle, the frequency bands at A and with the notch do
  not (0.48 % and 0.25 % off): M000's frequency wanders slowly (8.42-8.54 rad/s over 4 s windows
  at A), which draws started together from one state do not spread over in 7 s;
* the prediction flags 66 % of the draws at controller A as "not settled" (amplitude drifting
  over 2 % across the window), and 63 settings of the map; the generating model, settled for
  120 s, drifts that much in every one of its 4 s windows at A. The flag reads M000's irregular
  cycle as a transient;
* over the map the draws' majority outcome (diverging or not) is the generating model's at 397 of
  400 settings (re-run at commit e1fbaeb, where a window that grows is confirmed by a run 20 s
  longer before it counts as diverging; before, 395: at Kp 10.6, Kd 0.099 and Kp 11.1, Kd 0.088
  72-79 % of the draws "diverged" where the generating model holds a 1.5-1.8 mrad cycle). The
  three others lie at Kd 0.046 next to the boundary: the draws report cycles where the
  generating model leaves the 1 rad bound later (slow growth). Where both oscillate the median
  amplitude is 0.56 % off (median; up to 68 % next to the boundary);
* the stability boundary over Kp 3-12 at mu 12.3: the loop diverges below a Kd of 0.041-0.052
  (all draws agree to within a grid step). At controller A's Kp 5.84 the draws switch between Kd
  0.044 and 0.045, the generating model between 0.045 and 0.046 (at 0.045 the draws report a
  0.42 rad cycle where it passes 1 rad after 72 s); between Kd 0.046 and 0.053 the 7 s runs are
  still transient (amplitudes -56 % to +37 % off the generating model's; within 1.4 % from Kd
  0.054 up). Controller A's Kd 0.062 is 35-40 % above the boundary; its cycle grows from 5.45 mrad
  to 27 mrad at Kd 0.05;
* the lead 5/20 rad/s at controller A shrinks the cycle from 5.45 to 0.456 mrad (x0.084) and
  raises its frequency from 8.54 to 11.91 rad/s (x1.40); over the pole 6-60 rad/s the amplitude
  falls from 2.87 to 0.315 mrad and the frequency rises from 8.99 to 12.05 rad/s, the predictions
  within 2 % of the generating model's. The describing function of the median model follows
  the amplitude (its first harmonic 0-28 % above the simulated (max-min)/2) but not the
  frequency: beyond a pole of about 12 rad/s it predicts the frequency falling back (8.19 rad/s
  at 60 against 12.05 simulated, -32 %);
* the bending mode makes the plain PD diverge (every draw, and the generating model); the notch
  at damping 0.1 restores a cycle of 6.93 mrad at 8.20 rad/s (27 % larger than the plain PD's
  without bending). The narrower the notch, the smaller the cycle: 3.8 mrad at damping 0.02,
  12.6 at 0.245, 34 at 0.35 (generating model 28; every draw flagged not settled, near the
  boundary again), divergence at 0.5 (every draw, and the generating model);
* next test: the open-loop sine of 2 mrad at 5 Hz (expected gain 3.0 nats; dead-zone and backlash
  widths x0.16 and x0.15), then the square of 2 mrad at 1 Hz (2.8 nats). Repeats of the bundled
  open-loop tests give 0.57-0.69 nats, every closed-loop candidate at most 0.03 except the lead
  (0.47: its 0.45 mrad cycle is a few backlash widths), repeats of A and B 0.008-0.009. With both
  cycles and two large open-loop tests in hand, another cycle adds almost nothing; small commands
  probe the dead zone and the backlash directly.

Deciding figures: ``map.png`` (median amplitude, band width, median frequency and fraction of
draws diverging over Kp x Kd at mu 12.3, with the stability boundary) and ``filters.png`` (lead
and notch sweeps: median, 90 % band and the describing function of the median model, beside the
plain PD's band, with the generating model's long runs); ``boundary.png`` (the boundary along Kd
at controller A's Kp); ``design.png`` ranks the menu. ``summary.json`` holds every number (also in
the report), ``map.json``/``map.csv``/``maps.npz`` the maps, ``design.json`` the ranking. Quick
run (``--quick``): 26-39 s; full run: 4.5 min with a new chain (calibration 72 s), 3-4.5 min
resuming one (2 cores shared with other jobs).
"""
from __future__ import annotations

import json
import math
import sys
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from discovery.calibration import Calibration
from discovery.calibration.runner import ConvergenceWarning
from discovery.prediction import (
    ControllerSetting,
    PredictionConfig,
    cycle_map,
    load_posterior_draws,
    predict_cycle,
    simulate_cycles,
)
from discovery.prediction.design import load_candidates, rank_experiments
from discovery.spectral import noise_floor
from models import limit_cycle_features, simulate
from models.controllers import BendingMode
from models.hypotheses import params_from_dict
from models.recording import load_recording
from tvcid.figures import pyplot

from .common import study_main

NAME = "h6_controller_design"
DATA = Path(__file__).resolve().parents[1] / "data"
RECORDINGS = ("m000_closed_A", "m000_closed_B", "m000_open_square", "m000_open_sine")
PARAMS = ("dead_zone", "backlash", "delay", "sigma")
#: Controller A (paper 002): the vehicle every map and example uses.
SETTING_A = ControllerSetting(kp=5.84, kd=0.062, mu=12.3)
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
    bending: tuple = (60.0, 0.02, 0.01)
    notch_depth: float = 0.1
    notch_example_damping: float = 0.1
    notch_dampings: tuple = (0.02, 0.5, 10)
    design_draws: int = 200
    design_truths: int = 24
    truth_seconds: float = 120.0
    filter_transient: float = 10.0


QUICK = Config(steps=40, draws=20, kp=(3.0, 12.0, 5), kd=(0.02, 0.12, 4),
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
    cal : discovery.calibration.Calibration
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


def generating_model():
    """The parameters the bundled records were made with (their sidecars carry them)."""
    meta = load_recording(DATA / f"{RECORDINGS[0]}.csv").meta
    return params_from_dict(meta["hypothesis"], meta["parameters"]), float(meta["dt"])


def _num(v):
    return None if not np.isfinite(v) else float(v)


def generating_cycles(settings, seconds):
    """The generating model's own outcome and cycle at each setting.

    One long run per setting from the records' initial state at the records' step, its last
    8 s measured as the predictions measure each draw: the check of the predictions, whose
    runs are 7 s long from the median model's cycle (near the stability boundary the loop's
    growth is slow, and only a long run tells a large cycle from a divergence). A run diverges
    when it leaves the 1 rad bound within ``seconds``; a slower growth reads as a (large) cycle.

    Parameters
    ----------
    settings : sequence of ControllerSetting
    seconds : float
        Length of each run (s).

    Returns
    -------
    list of dict
        Per setting ``outcome`` (``"cycle"``, ``"rest"`` or ``"diverged"``), ``amplitude``
        ((max-min)/2 of delta, rad) and ``frequency`` (rad/s), None unless a cycle.
    """
    truth, dt = generating_model()
    window = 8.0
    # diverged = left the 1 rad bound: M000's cycle at high Kd is irregular enough (halves of an
    # 8 s window 1.1 and 1.46 mrad at Kp 10.1, Kd 0.104) to trip any growth threshold
    cfg = PredictionConfig(transient=seconds - window, window=window, pilot=0.0, dt=dt,
                           max_growth=math.inf)
    o = simulate_cycles([truth] * len(settings), [st.closed_loop() for st in settings], cfg)
    return [{"outcome": str(o.outcome[i]), "amplitude": _num(o.amplitude[i]),
             "frequency": _num(o.frequency[i])} for i in range(len(settings))]


def generating_wander(setting, seconds, window=4.0, start=20.0):
    """Spread of the generating model's cycle over consecutive ``window``-second windows.

    M000's cycle is not periodic (its 9-10 Hz band-pass loop is not locked to it; README, "Known
    limits"): where a window falls moves the measured cycle. The predictions' band is over the
    posterior only (every draw starts from the same state), so this is the yardstick it is read
    against.

    Parameters
    ----------
    setting : ControllerSetting
    seconds : float
        Length of the run (s).
    window : float
        Length of each measured window (s), as the predictions' window.
    start : float
        First window's start (s), after the start-up transient.

    Returns
    -------
    dict
        ``windows``, ``window``, the median absolute amplitude drift between each window's halves
        and the fraction of windows whose drift exceeds the prediction's ``settled_drift``, and,
        for ``amplitude`` and ``frequency``, the ``min``, ``max``, ``sd`` and ``range_pct`` (range
        over the median, %) over the windows.
    """
    truth, dt = generating_model()
    tr = simulate(truth, setting.closed_loop(), seconds, dt=dt, rate=250.0)
    amp, freq, drift = [], [], []
    for t0 in np.arange(start, seconds - window + 1e-9, window):
        keep = (tr.t >= t0) & (tr.t < t0 + window)
        f = limit_cycle_features(tr.t[keep], tr.delta[keep], n_harmonics=1)
        amp.append(f.amplitude)
        freq.append(f.frequency)
        drift.append(abs(f.amplitude_drift))
    # the prediction calls a draw "not settled" beyond this drift; how often does the
    # generating model itself, long settled, exceed it?
    limit = PredictionConfig().settled_drift
    out = {"windows": len(amp), "window": window,
           "drift_median": float(np.median(drift)),
           "fraction_windows_over_settled_drift": float(np.mean(np.array(drift) > limit)),
           "settled_drift": limit}
    for name, v in (("amplitude", np.array(amp)), ("frequency", np.array(freq))):
        out[name] = {"min": float(v.min()), "max": float(v.max()), "sd": float(v.std()),
                     "range_pct": float(100 * (v.max() - v.min()) / np.median(v))}
    return out


def _inside(band, value):
    if value is None or band["q50"] is None:
        return None
    return bool(band["q05"] <= value <= band["q95"])


def _with_generating(d, g):
    """A prediction's summary with the generating model's cycle and whether the band holds it."""
    return {**d, "generating": g,
            "generating_inside_band": {n: _inside(d[n], g[n]) for n in ("amplitude", "frequency")},
            "median_error_pct": {n: (None if g[n] is None or d[n]["q50"] is None
                                     else 100 * (d[n]["q50"] / g[n] - 1))
                                 for n in ("amplitude", "frequency")}}


def _band(d):
    """Median and 90 % band of a prediction's amplitude and frequency, with its relative width."""
    out = {}
    for name in ("amplitude", "frequency"):
        q = d[name]
        width = None if q["q50"] is None else 100 * (q["q95"] - q["q05"]) / q["q50"]
        out[name] = {**q, "width90_pct": width}
    return out


def _prediction(pred):
    d = pred.to_dict()
    return {**_band(d), "fraction_oscillating": d["fraction_oscillating"],
            "fraction_diverging": d["fraction_diverging"],
            "fraction_at_rest": d["fraction_at_rest"],
            "fraction_not_settled": d.get("fraction_not_settled"),
            "solver_error": d.get("solver_error"),
            "describing_function": d["describing_function"], "setting": d["setting"]}


def _switch(x, diverging):
    """``[x_j, x_j+1]`` where ``diverging`` turns from True to False first, or None."""
    for j in range(len(x) - 1):
        if diverging[j] and not diverging[j + 1]:
            return [float(x[j]), float(x[j + 1])]
    return None


def boundary_of_map(cmap):
    """Where the stability boundary crosses each Kp row of a Kp x Kd map.

    Parameters
    ----------
    cmap : discovery.prediction.CycleMap
        Keys ``("kp", "kd")``.

    Returns
    -------
    list of dict
        Per Kp, ``kd_intervals``: every ``[kd_j, kd_j+1]`` between which the majority of draws
        turns from diverging to not (or back).
    """
    s = cmap.summary
    kp, kd = cmap.values
    rows = []
    for i, k in enumerate(kp):
        div = s["fraction_diverging"][i]
        switch = [j for j in range(len(kd) - 1) if (div[j] > 0.5) != (div[j + 1] > 0.5)]
        rows.append({"kp": float(k), "kd_intervals": [[float(kd[j]), float(kd[j + 1])]
                                                      for j in switch]})
    return rows


def check_map(cmap, seconds):
    """The generating model's outcome at every setting of a Kp x Kd map, against the draws'.

    Parameters
    ----------
    cmap : discovery.prediction.CycleMap
        Keys ``("kp", "kd")``.
    seconds : float
        Length of each of the generating model's runs (s).

    Returns
    -------
    dict
        ``agreement`` (fraction of settings where the draws' majority outcome, diverging or
        not, is the generating model's), ``disagreements`` (those settings with the draws'
        fraction diverging and the generating model's outcome and amplitude), and the median and
        largest ``amplitude_error_pct`` of the median over the draws against the generating
        model's cycle where both oscillate.
    """
    kp, kd = cmap.values
    points = [(float(a), float(b)) for a in kp for b in kd]
    gen = generating_cycles([cmap.base.replace(kp=a, kd=b) for a, b in points], seconds)
    div = np.ravel(cmap.summary["fraction_diverging"])
    amp = np.ravel(cmap.summary["amplitude_q50"])
    disagree, errors = [], []
    for (a, b), g, f, q in zip(points, gen, div, amp):
        if (f > 0.5) != (g["outcome"] == "diverged"):
            disagree.append({"kp": a, "kd": b, "fraction_diverging": float(f),
                             "generating_outcome": g["outcome"],
                             "generating_amplitude": g["amplitude"]})
        elif g["amplitude"] is not None and np.isfinite(q):
            errors.append(100 * (q / g["amplitude"] - 1))
    errors = np.abs(errors)
    return {"agreement": 1 - len(disagree) / len(points), "disagreements": disagree,
            "amplitude_error_pct": {"median": float(np.median(errors)) if errors.size else None,
                                    "max": float(np.max(errors)) if errors.size else None}}


def _width_stats(s):
    out = {}
    osc = s["fraction_oscillating"] > 0.5
    for name in ("amplitude", "frequency"):
        with np.errstate(invalid="ignore", divide="ignore"):
            w = 100 * (s[f"{name}_q95"] - s[f"{name}_q05"]) / s[f"{name}_q50"]
        w = w[osc & np.isfinite(w)]
        out[name] = {"median_pct": float(np.median(w)) if w.size else None,
                     "max_pct": float(np.max(w)) if w.size else None}
    with np.errstate(invalid="ignore", divide="ignore"):
        df = 100 * np.abs(s["df_frequency"] / s["frequency_q50"] - 1)
    df = df[osc & np.isfinite(df)]
    out["df_frequency_error"] = {"median_pct": float(np.median(df)) if df.size else None,
                                 "max_pct": float(np.max(df)) if df.size else None}
    return out


def _line(cmap):
    s = cmap.summary
    return {"key": cmap.keys[0], "values": cmap.values[0].tolist(),
            **{k: [None if not np.isfinite(v) else float(v) for v in s[k]] for k in s}}


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
    (out_dir / "map.json").write_text(json.dumps(cmap.to_dict(), indent=1) + "\n")
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
    critical = {"grid_interval": _switch(kd_values, div > 0.5)}
    critical["draws_split"] = int(np.sum((div > 0.05) & (div < 0.95)))
    kd_truth = generating_cycles([SETTING_A.replace(kd=float(k)) for k in kd_values],
                                 config.truth_seconds)
    critical["generating_grid_interval"] = _switch(
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
    examples = {k: _with_generating(_prediction(pred), g)
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
    (out_dir / "design.json").write_text(json.dumps(ranking.to_dict(), indent=1) + "\n")
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
            "band_widths": _width_stats(s),
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
            "sweep": _line(lead_map), "sweep_generating": lead_truth,
        },
        "notch": {
            "bending": bending.to_dict(), "depth": config.notch_depth,
            "example_damping": config.notch_example_damping,
            "pd_with_bending": examples["pd_with_bending"],
            "example": examples["notch"],
            "sweep": _line(notch_map), "sweep_generating": notch_truth,
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
    plt = pyplot()
    axes = cmap.plot()
    fig = axes[0].figure
    for ax in axes:
        ax.plot([SETTING_A.kd], [SETTING_A.kp], "w*", ms=12, mec="k")
        for cell in map_check["disagreements"]:
            ax.plot(cell["kd"], cell["kp"], "x", color="c", ms=9, mew=2)
    fig.suptitle(f"M000 calibrated on the bundled records: {len(draws)} draws, mu {SETTING_A.mu}"
                 "\nstar: controller A; black line: half the draws diverge; cyan x: the draws' "
                 "majority outcome differs from the generating model's", fontsize=10)
    fig.savefig(out_dir / "map.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(8, 0.55 * len(ranking.rows) + 1.8), constrained_layout=True)
    ranking.plot(ax)
    ax.set_title("expected 90 % width after / before each test (best first)")
    fig.savefig(out_dir / "design.png", dpi=110)
    plt.close(fig)
    fig = cal.posterior_.plot_corner()
    fig.savefig(out_dir / "corner.png", dpi=90)
    plt.close(fig)
    timings["total"] = time.perf_counter() - t_start
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    return summary


def _generating_markers(ax, x, rows, name, scale):
    """The generating model's cycles (long runs) as crosses; its divergences as red bars."""
    xs = [v for v, g in zip(x, rows) if g[name] is not None]
    ys = [g[name] * scale for g in rows if g[name] is not None]
    ax.plot(xs, ys, "kx", ms=7, label="generating model (long run)")
    for v, g in zip(x, rows):
        if g["outcome"] == "diverged":
            ax.axvline(v, color="r", lw=3, alpha=0.3)


def _log_ticks(ax, ticks):
    from matplotlib.ticker import NullFormatter

    ax.set_xscale("log")
    ax.set_xticks(ticks)
    ax.set_xticklabels([f"{t:g}" for t in ticks])
    ax.xaxis.set_minor_formatter(NullFormatter())


def plot_filters(summary, path, lead_map, notch_map):
    """Lead and notch sweeps (band, median, DF, generating model) beside the plain PD's band."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), constrained_layout=True)
    plain = summary["plain_pd"]
    lead_map.plot(axes=axes[0])
    notch_map.plot(axes=axes[1])
    sweeps = ((axes[0], lead_map.values[0], summary["lead"]["sweep_generating"],
               f"lead (1 + s/{summary['lead']['zero']:g})/(1 + s/p) at controller A",
               "lead pole p (rad/s)", (6, 10, 20, 40, 60)),
              (axes[1], notch_map.values[0], summary["notch"]["sweep_generating"],
               "bending {frequency:g} rad/s, damping {damping:g}, gain {gain:g} + notch at its "
               "frequency".format(**summary["notch"]["bending"]),
               "notch damping (its width)", (0.02, 0.05, 0.1, 0.2, 0.5)))
    for row, x, gen, title, xlabel, ticks in sweeps:
        for ax, name, scale in ((row[0], "amplitude", 1e3), (row[1], "frequency", 1.0)):
            q = plain[name]
            if q["q50"] is not None:
                ax.axhspan(q["q05"] * scale, q["q95"] * scale, color="0.6", alpha=0.4)
                ax.axhline(q["q50"] * scale, color="0.3", lw=1, ls=":",
                           label="plain PD (no filter, no bending)")
            _generating_markers(ax, x, gen, name, scale)
            _log_ticks(ax, [t for t in ticks if x[0] <= t <= x[-1]])
            ax.set_xlabel(xlabel)
            ax.set_title(title, fontsize=9)
            ax.legend(fontsize=7)
    from matplotlib.ticker import ScalarFormatter

    axes[1][0].set_yscale("log")
    axes[1][0].yaxis.set_major_formatter(ScalarFormatter())
    axes[1][0].yaxis.set_minor_formatter(ScalarFormatter())
    for row, sweep in ((axes[0], summary["lead"]), (axes[1], summary["notch"])):
        # the map's line plot marks divergence at 0 rad/s; keep the cycles' range in view
        f = [v for v in sweep["sweep"]["frequency_q50"] + sweep["sweep"]["df_frequency"]
             if v is not None]
        f += [g["frequency"] for g in sweep["sweep_generating"] if g["frequency"] is not None]
        f.append(plain["frequency"]["q50"] or f[0])
        row[1].set_ylim(0.97 * min(f), 1.03 * max(f))
    bent = summary["notch"]["pd_with_bending"]
    axes[1][0].text(0.02, 0.97, "PD with the bending mode, no notch: "
                    f"{100 * bent['fraction_diverging']:.0f} % of draws diverge "
                    f"(generating model: {bent['generating']['outcome']})",
                    transform=axes[1][0].transAxes, fontsize=8, va="top")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_boundary(summary, path):
    """Fraction of draws diverging and the cycle's amplitude along Kd at controller A's Kp."""
    plt = pyplot()
    b = summary["boundary_at_A"]
    kd = np.array(b["kd"])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    ax1.plot(kd, b["fraction_diverging"], "o-", ms=4, label="posterior draws")
    ax1.plot(kd, [1.0 if g["outcome"] == "diverged" else 0.0 for g in b["generating"]], "kx",
             ms=7, label="generating model (long run)")
    ax1.set_ylabel("fraction diverging")
    amp = np.array([np.nan if v is None else v for v in b["amplitude_q50"]], dtype=float)
    ax2.semilogy(kd, 1e3 * amp, "o-", ms=4, label="median over the draws")
    ax2.semilogy(kd, [np.nan if g["amplitude"] is None else 1e3 * g["amplitude"]
                      for g in b["generating"]], "kx", ms=7, label="generating model (long run)")
    ax2.set_ylabel("amplitude of delta (mrad)")
    for ax in (ax1, ax2):
        ax.axvline(SETTING_A.kd, color="0.5", ls=":", label="controller A")
        ax.set_xlabel(f"Kd (s), Kp {b['kp']}, mu {SETTING_A.mu}")
        ax.legend(fontsize=8)
    fig.suptitle("stability boundary at controller A's gain")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt_q(q, scale=1.0, digits=4):
    if q["q50"] is None:
        return "none oscillates"
    return (f"{q['q50'] * scale:.{digits}g} [{q['q05'] * scale:.{digits}g}, "
            f"{q['q95'] * scale:.{digits}g}]")


def _df(d):
    df = d["describing_function"]
    if not df or df.get("amplitude") is None:
        return (df or {}).get("note", "—")
    return f"{df['amplitude'] * 1e3:.3g} mrad (first harmonic) at {df['frequency']:.3g} rad/s"


def _gen(d):
    g, w = d["generating"], d.get("generating_wander")
    if g["amplitude"] is None:
        return g["outcome"]
    out = f"{g['amplitude'] * 1e3:.4g} mrad at {g['frequency']:.4g} rad/s"
    if w:
        a, f = w["amplitude"], w["frequency"]
        out += (f" (its {w['window']:g} s windows: {a['min'] * 1e3:.4g}-{a['max'] * 1e3:.4g} mrad, "
                f"{f['min']:.4g}-{f['max']:.4g} rad/s; "
                f"{100 * w['fraction_windows_over_settled_drift']:.0f} % of them would read as "
                "not settled)")
    return out


def report_lines(summary) -> list:
    """Markdown of the study's numbers for ``results/report.md`` (figures are embedded there).

    Parameters
    ----------
    summary : dict
        What :func:`run` returned (or ``summary.json``).

    Returns
    -------
    list of str
        Lines: the fit's table, the map's counts, band widths and boundary, the examples at
        controller A beside the describing function and the generating model, the ranking.
    """
    fit, m = summary["fit"], summary["map"]
    lines = [f"Fit: M000 on {', '.join(fit['recordings'])}, {fit['iterations']} steps x "
             f"{fit['walkers']} walkers (converged: {fit['converged']}, N/tau "
             f"{fit['n_over_tau']:.1f}), in-loop noise power fixed at "
             f"{fit['noise_power_fixed']:.3g} "
             "rad^2/Hz (floor of the square record).", "",
             "| parameter | median | 90 % interval | width % | truth | inside |",
             "|---|---|---|---|---|---|"]
    for n, p in fit["parameters"].items():
        lines.append(f"| {n} | {p['q50']:.5g} | [{p['q05']:.5g}, {p['q95']:.5g}] | "
                     f"{p['width90_pct']:.2f} | "
                     f"{p['truth'] if p['truth'] is not None else '—'} | "
                     f"{p['truth_inside_90'] if p['truth_inside_90'] is not None else '—'} |")
    bw = m["band_widths"]
    crit = summary["boundary_at_A"]["critical_kd"]
    lines += ["", f"Map ({m['shape'][0]} Kp x {m['shape'][1]} Kd, {summary['draws']} draws, "
              f"mu {m['mu']}): {m['cells_oscillating']} settings oscillate, "
              f"{m['cells_diverging']} diverge, {m['cells_at_rest']} rest; {m['cells_split']} "
              "settings split the draws (5-95 % diverging)"
              + (f"; at {m['cells_not_settled']} most draws have not settled on a cycle (amplitude "
                 "still drifting across the window)" if m.get("cells_not_settled") else "")
              + ". 90 % band width where the loop "
              f"oscillates: amplitude median {bw['amplitude']['median_pct']:.2g} %, max "
              f"{bw['amplitude']['max_pct']:.2g} %; frequency median "
              f"{bw['frequency']['median_pct']:.2g} %, max {bw['frequency']['max_pct']:.2g} %. "
              "DF of the median model vs the median simulated frequency: median "
              f"{bw['df_frequency_error']['median_pct']:.2g} %, max "
              f"{bw['df_frequency_error']['max_pct']:.2g} %.", "",
              f"Against the generating model's {summary['config']['truth_seconds']:g} s runs at "
              f"every setting: the draws' majority outcome agrees at "
              f"{100 * m['generating_check']['agreement']:.1f} % of them"
              + "".join(f"; not at Kp {c['kp']:.3g}, Kd {c['kd']:.3g} ("
                        f"{100 * c['fraction_diverging']:.0f} % of draws diverge, the generating "
                        f"model: {c['generating_outcome']})"
                        for c in m["generating_check"]["disagreements"])
              + "; where both oscillate the median amplitude is off by "
              f"{m['generating_check']['amplitude_error_pct']['median']:.2g} % (median), "
              f"{m['generating_check']['amplitude_error_pct']['max']:.2g} % (max).", "",
              "Stability boundary (Kd interval where the majority of draws stops diverging): "
              + "; ".join(f"Kp {r['kp']:.3g}: " + (", ".join(f"{a:.3g}-{b:.3g}"
                                                            for a, b in r['kd_intervals'])
                                                  or "none in the grid")
                          for r in m["boundary"]) + ".", "",
              f"At controller A's Kp {summary['boundary_at_A']['kp']}: the draws diverge below a "
              "critical Kd between "
              + (f"{crit['grid_interval'][0]:.4g} and {crit['grid_interval'][1]:.4g}"
                 if crit["grid_interval"] is not None else "— (not found in the scan)")
              + f" ({crit['draws_split']} scan points split the draws between diverging and not), "
              "the generating model (long runs) between "
              + (f"{crit['generating_grid_interval'][0]:.4g} and "
                 f"{crit['generating_grid_interval'][1]:.4g}"
                 if crit["generating_grid_interval"] is not None else "— (not found in the scan)")
              + f"; controller A has Kd {SETTING_A.kd}.", "",
              "| controller A, mu 12.3 | amplitude (mrad), median [90 %] | frequency (rad/s) | "
              "oscillate | diverge | DF of the median model | generating model (long run) |",
              "|---|---|---|---|---|---|---|"]
    lead, notch = summary["lead"], summary["notch"]
    for label, d in (("plain PD", summary["plain_pd"]),
                     (f"lead {lead['zero']:g}/{lead['example_pole']:g} rad/s", lead["example"]),
                     ("PD + bending", notch["pd_with_bending"]),
                     (f"PD + bending + notch (damping {notch['example_damping']:g}, depth "
                      f"{notch['depth']:g})", notch["example"])):
        lines.append(f"| {label} | {_fmt_q(d['amplitude'], 1e3)} | {_fmt_q(d['frequency'])} | "
                     f"{100 * d['fraction_oscillating']:.0f} %"
                     + (f" ({100 * d['fraction_not_settled']:.0f} % not settled)"
                        if d.get("fraction_not_settled") else "") + " | "
                     f"{100 * d['fraction_diverging']:.0f} % | {_df(d)} | {_gen(d)} |")
    des = summary["design"]
    lines += ["", f"Next experiment ({des['draws']} draws, {des['truths']} hypothetical truths; "
              f"parameters {', '.join(des['params'])}): best **{des['best']}**"
              f"{' (a repeat)' if des['best_is_repeat'] else ' (not a repeat of a tested one)'}.",
              "", "| candidate | tested? | information gain (nats) | "
              + " | ".join(f"{p} width after/before" for p in des["params"]) + " |",
              "|---|---|---|" + "---|" * len(des["params"])]
    for r in des["ranking"]:
        lines.append(f"| {r['name']} | {'yes' if r['tested'] else 'no'} | "
                     f"{r['information_gain']:.3g} | "
                     + " | ".join(f"{r['shrinkage'][p]:.3f}" for p in des["params"]) + " |")
    t = summary["timings"]
    lines += ["", "Time: " + ", ".join(f"{k} {v:.0f} s" for k, v in t.items()) + ".", ""]
    return lines


def describe(summary):
    print("\n".join(report_lines(summary)))


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
