"""What ``h6_controller_design``'s predictions are checked against, and how they are summarised.

The bundled records' generating model (the parameters in their sidecars) is run long at the
records' step at every setting the study predicts: its outcome and cycle
(:func:`generating_cycles`), how much its own cycle moves between windows
(:func:`generating_wander`), and the map's agreement with it (:func:`check_map`). The helpers
below turn a prediction into the summary's numbers (band widths, the stability boundary).
"""
from __future__ import annotations

import math

import numpy as np

from tvcid.data import path as bundled_path
from tvcid.discovery.prediction import ControllerSetting, PredictionConfig, simulate_cycles
from tvcid.models import limit_cycle_features, simulate
from tvcid.models.hypotheses import params_from_dict
from tvcid.models.recording import load_recording

DATA = bundled_path()
RECORDINGS = ("m000_closed_A", "m000_closed_B", "m000_open_square", "m000_open_sine")
#: Controller A (paper 002): the vehicle every map and example uses.
SETTING_A = ControllerSetting(kp=5.84, kd=0.062, mu=12.3)


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

    M000's cycle is not periodic (its 9-10 Hz band-pass loop is not locked to it;
    ``docs/models.md#reference-limit-cycles``): where a window falls moves the measured cycle.
    The predictions' band is over the posterior only (every draw starts from the same state), so
    this is the yardstick it is read against.

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


def with_generating(d, g):
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


def prediction_summary(pred):
    """A :class:`tvcid.discovery.prediction.CyclePrediction` as the summary holds it: bands, fractions,
    the describing function of the median model and the setting."""
    d = pred.to_dict()
    return {**_band(d), "fraction_oscillating": d["fraction_oscillating"],
            "fraction_diverging": d["fraction_diverging"],
            "fraction_at_rest": d["fraction_at_rest"],
            "fraction_not_settled": d.get("fraction_not_settled"),
            "solver_error": d.get("solver_error"),
            "describing_function": d["describing_function"], "setting": d["setting"]}


def first_switch(x, diverging):
    """``[x_j, x_j+1]`` where ``diverging`` turns from True to False first, or None."""
    for j in range(len(x) - 1):
        if diverging[j] and not diverging[j + 1]:
            return [float(x[j]), float(x[j + 1])]
    return None


def boundary_of_map(cmap):
    """Where the stability boundary crosses each Kp row of a Kp x Kd map.

    Parameters
    ----------
    cmap : tvcid.discovery.prediction.CycleMap
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
    cmap : tvcid.discovery.prediction.CycleMap
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


def band_widths(s):
    """Median and largest 90 % band width (% of the median) over a map's oscillating settings, and
    the describing function's frequency error against the median simulated frequency."""
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


def line_summary(cmap):
    """A one-key map (a sweep) as lists, non-finite values as None."""
    s = cmap.summary
    return {"key": cmap.keys[0], "values": cmap.values[0].tolist(),
            **{k: [None if not np.isfinite(v) else float(v) for v in s[k]] for k in s}}
