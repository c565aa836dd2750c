"""Simulating proposals against recordings: the shared ground of the ranking and of the
simulation stage of the threshold scan.

A recording's experiment is rebuilt from its sidecar (the HWIL closed loop) or by replaying its
command open loop; :func:`tvcid.models.simulate_batch` runs many parameter sets at once.
"""
from __future__ import annotations

import math
import weakref

import numpy as np

from tvcid.models.cycle_reading import InsufficientPeriodsError, limit_cycle_features
from tvcid.models.recording import Recording
from tvcid.models.simulate import DEFAULT_DT, simulate_batch

from .library import command_jumps

__all__ = [
    "MAX_SIMULATED",
    "replay_experiment",
    "waveform_distance",
    "simulation_score",
    "simulable",
    "score_on_recordings",
]

#: Longest stretch (s) of a recording simulated for a score.
MAX_SIMULATED = 30.0


def replay_experiment(recording, t_end=None):
    """An ``OpenLoop`` replaying a recording's command, with square edges kept sharp.

    ``OpenLoop.from_samples`` interpolates linearly between samples, which would smear a square
    command's edge over one sample and shift it by half a sample; across a jump
    (:func:`tvcid.discovery.sindy.library.command_jumps`) the previous value is held up to the next
    sample instead, as :func:`tvcid.discovery.sindy.library.delayed_command` reconstructs it. A
    command without jumps is read by a cubic spline (:func:`tvcid.models.commands.command_from_samples`).
    """
    from tvcid.models.experiments import OpenLoop

    exact = recording.experiment()
    if exact.waveform != "samples":  # the sidecar's own command reproduces u
        return exact
    t = recording.t - recording.t[0]
    u = recording.u
    if t_end is not None:
        keep = t <= t_end + 1e-12
        t, u = t[keep], u[keep]
    jumps = np.flatnonzero(command_jumps(u))
    if not jumps.size and u.size >= 4:  # smooth: a spline, not chords (tvcid.models.commands)
        return OpenLoop.from_samples(t, u, interpolation="cubic")
    if jumps.size:
        eps = 1e-7 * (t[1] - t[0])
        t = np.insert(t, jumps + 1, t[jumps + 1] - eps)
        u = np.insert(u, jumps + 1, u[jumps])
    return OpenLoop.from_samples(t, u)


#: Replays of open-loop recordings by recording and length: the same experiment object is
#: simulated again and again in the simulation stage, so its stage command is built once
#: (:func:`tvcid.models.simulate._stage_command` memoises it on the experiment).
_REPLAYS = weakref.WeakKeyDictionary()


def _replayed(rec, t_end, keep):
    """``(experiment, view)`` of an open-loop recording cut at ``t_end``, cached per recording."""
    by_end = _REPLAYS.setdefault(rec, {})
    key = round(float(t_end), 9)
    if key not in by_end:
        view = Recording({k: v[keep] for k, v in rec.columns.items()}, rec.meta, rec.path)
        by_end[key] = (replay_experiment(rec, t_end), view)
    return by_end[key]


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
    shifts = min(period_samples, simulated.size - n) + 1
    if shifts < 1:
        raise ValueError("the simulated waveform is shorter than the recorded one")
    # ||ref - (seg - mean seg)||^2 for every shift, from running sums and one correlation
    sim = simulated[: shifts + n - 1]
    csum = np.concatenate([[0.0], np.cumsum(sim)])
    csq = np.concatenate([[0.0], np.cumsum(sim**2)])
    seg_sum = csum[n: n + shifts] - csum[:shifts]
    seg_sq = csq[n: n + shifts] - csq[:shifts]
    cross = np.correlate(sim, ref, mode="valid")[:shifts]
    err = np.sum(ref**2) + seg_sq - seg_sum**2 / n - 2.0 * cross
    return float(np.sqrt(max(float(np.min(err)), 0.0) / n)) / norm


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
    try:
        data = _recorded_features(recording)
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


_FEATURE_CACHE = {}


def _recorded_features(recording):
    """Limit-cycle features of a recording's last half (cached: the scans score it many times)."""
    key = (id(recording), recording.t.size, float(recording.t[-1]))
    cached = _FEATURE_CACHE.get(key)
    if cached is None or cached[0] is not recording:
        half = recording.t >= recording.t[0] + 0.5 * (recording.t[-1] - recording.t[0])
        cached = (recording, limit_cycle_features(recording.t[half], recording.delta[half]))
        if len(_FEATURE_CACHE) > 64:
            _FEATURE_CACHE.clear()
        _FEATURE_CACHE[key] = cached
    return cached[1]


def simulable(params):
    """Round a delay shorter than half a step to 0 and lengthen one below a step to the step."""
    if 0 < params.delay < DEFAULT_DT:
        return params.replace(delay=0.0 if params.delay < 0.5 * DEFAULT_DT else DEFAULT_DT)
    return params


def score_on_recordings(param_sets, recordings, max_time=MAX_SIMULATED):
    """Simulate every parameter set in every recording's experiment.

    Returns
    -------
    scores : ndarray, shape (n_sets, n_recordings)
        :func:`simulation_score` of each set on each recording (``inf`` when a run diverges).
    details : list of list of dict
        ``details[i][j]`` for set ``i`` on recording ``j``.
    """
    param_sets = [simulable(p) for p in param_sets]
    scores = np.full((len(param_sets), len(recordings)), math.inf)
    details = [[{} for _ in recordings] for _ in param_sets]
    for j, rec in enumerate(recordings):
        t_end = min(float(rec.t[-1] - rec.t[0]), max_time)
        sl = rec.t <= rec.t[0] + t_end + 1e-12
        if rec.kind == "closed":
            experiment, view = rec.experiment(), rec
        else:
            experiment, view = _replayed(rec, t_end, sl)
        batch = simulate_batch(param_sets, experiment, t_end, rate=None)
        delta = batch.signal("delta")
        for i in range(len(param_sets)):
            scores[i, j], details[i][j] = simulation_score(view, batch.t + rec.t[0], delta[i])
    return scores, details
