"""Ranking structure proposals by simulating them as full models (issue 4, deliverable 4).

Every proposal is converted into a :class:`models.ActuatorParams` and run through the experiment
of every recording with :func:`models.simulate_batch`: the HWIL closed loop of a limit-cycle record
(vehicle and PD controller from the sidecar), or the recorded command replayed open loop. The score
compares the runs with the data on limit-cycle features (amplitude and frequency, MODELS.md
conventions) and on the waveform.
"""
from __future__ import annotations

import math

import numpy as np

from models.features import InsufficientPeriodsError, limit_cycle_features
from models.simulate import DEFAULT_DT, simulate_batch

from .estimator import load_recordings

__all__ = ["rank_by_simulation", "waveform_distance", "simulation_score"]

#: Longest stretch (s) of a recording simulated for the ranking.
MAX_SIMULATED = 30.0


def waveform_distance(recorded, simulated, period_samples=None):
    """Normalised rms difference of two waveforms, the simulated one shifted in time to fit best.

    Parameters
    ----------
    recorded : ndarray
        Samples of the data (a whole number of periods for a limit cycle).
    simulated : ndarray
        Samples of the model at the same rate, at least as long as ``recorded``.
    period_samples : int or None
        For a limit cycle, shifts up to one period are tried (the cycle's phase is arbitrary);
        ``None`` compares sample by sample (open-loop replay).
    """
    recorded = np.asarray(recorded, dtype=float)
    simulated = np.asarray(simulated, dtype=float)
    ref = recorded - recorded.mean() if period_samples else recorded
    norm = float(np.sqrt(np.mean(ref**2))) or 1.0
    if not period_samples:
        n = min(recorded.size, simulated.size)
        return float(np.sqrt(np.mean((recorded[:n] - simulated[:n]) ** 2)) / norm)
    n = recorded.size
    best = math.inf
    for shift in range(0, min(period_samples, simulated.size - n) + 1):
        seg = simulated[shift: shift + n]
        best = min(best, float(np.sqrt(np.mean((ref - (seg - seg.mean())) ** 2))))
    return best / norm


def simulation_score(recording, t, delta):
    """Score of one simulated ``delta(t)`` against one recording (lower is better).

    Closed loop: ``|dA|/A + |dw|/w`` of the limit-cycle features over the last half, plus the
    waveform distance over two recorded periods. Open loop: the waveform distance of the replay.
    Returns ``(score, details)``.
    """
    if not np.all(np.isfinite(delta)):
        return math.inf, {"status": "diverged"}
    if recording.kind == "open":
        sim = np.interp(recording.t, t, delta)
        d = waveform_distance(recording.delta, sim)
        return d, {"waveform": d}
    half = recording.t >= recording.t[0] + 0.5 * (recording.t[-1] - recording.t[0])
    try:
        data = limit_cycle_features(recording.t[half], recording.delta[half])
        sel = t >= t[0] + 0.5 * (t[-1] - t[0])
        model = limit_cycle_features(t[sel], delta[sel])
    except InsufficientPeriodsError as exc:
        return math.inf, {"status": f"no limit cycle: {exc}"}
    rate = 1.0 / (recording.t[1] - recording.t[0])
    period = int(round(2 * math.pi / data.frequency * rate))
    rec_seg = recording.delta[-2 * period:] if 2 * period < recording.delta.size else recording.delta
    sim = np.interp(recording.t, t, delta)
    sim_seg = sim[-(rec_seg.size + period):]
    d_wave = waveform_distance(rec_seg, sim_seg, period)
    d_amp = abs(model.amplitude - data.amplitude) / data.amplitude
    d_freq = abs(model.frequency - data.frequency) / data.frequency
    details = {
        "amplitude": model.amplitude, "frequency": model.frequency,
        "amplitude_error": d_amp, "frequency_error": d_freq, "waveform": d_wave,
    }
    return d_amp + d_freq + d_wave, details


def _simulable(params):
    """Round a delay shorter than half a step to 0 and lengthen one below a step to the step."""
    if 0 < params.delay < DEFAULT_DT:
        return params.replace(delay=0.0 if params.delay < 0.5 * DEFAULT_DT else DEFAULT_DT)
    return params


def rank_by_simulation(candidates, recordings, max_time=MAX_SIMULATED):
    """Simulate every candidate in every recording's experiment; set ``score`` and sort.

    Parameters
    ----------
    candidates : list of Candidate
    recordings : sequence of Recording or paths
    max_time : float
        Longest stretch (s) simulated per recording.

    Returns
    -------
    list of Candidate
        Sorted by ``score`` (mean over recordings), best first; a candidate that is not a valid
        model, diverges or loses the limit cycle scores ``inf`` and says why in ``score_details``.
    """
    recordings = load_recordings(recordings)
    params, valid = [], []
    for cand in candidates:
        try:
            amplitude = 0.5 * float(np.ptp(recordings[0].delta)) or 5e-3
            params.append(_simulable(cand.to_params(x0=amplitude)))
            valid.append(cand)
        except ValueError as exc:
            cand.score = math.inf
            cand.score_details = {"status": f"not a valid model: {exc}"}
    scores = {id(c): [] for c in valid}
    for rec_i, rec in enumerate(recordings):
        if not valid:
            break
        t_end = min(float(rec.t[-1] - rec.t[0]), max_time)
        sl = rec.t <= rec.t[0] + t_end
        if rec.kind == "closed":
            experiment = rec.experiment()
            view = rec
        else:
            from models.experiments import OpenLoop
            from models.recording import Recording

            experiment = OpenLoop.from_samples(rec.t[sl] - rec.t[0], rec.u[sl])
            view = Recording({k: v[sl] for k, v in rec.columns.items()}, rec.meta, rec.path)
        batch = simulate_batch(params, experiment, t_end, rate=None)
        delta = batch.signal("delta")
        for i, cand in enumerate(valid):
            s, details = simulation_score(view, batch.t + rec.t[0], delta[i])
            scores[id(cand)].append(s)
            cand.score_details = {**cand.score_details, f"recording_{rec_i}": details}
    for cand in valid:
        cand.score = float(np.mean(scores[id(cand)])) if scores[id(cand)] else math.inf
    return sorted(candidates, key=lambda c: (c.score is None, c.score))
