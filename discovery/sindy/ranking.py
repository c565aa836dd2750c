"""Ranking structure proposals by simulating them as full models.

Every proposal is converted into a :class:`tvcid.models.ActuatorParams` and run through the experiment of
every recording with :func:`tvcid.models.simulate_batch`: the HWIL closed loop of a limit-cycle record
(vehicle and PD controller from the sidecar), or the recorded command replayed open loop. The score
compares the runs with the data on limit-cycle features (amplitude and frequency,
``docs/models.md#conventions``) and on the waveform
(:func:`tvcid.discovery.sindy.simulation.simulation_score`).
"""
from __future__ import annotations

import math

import numpy as np

from tvcid.models.recording import load_recordings

from .simulation import MAX_SIMULATED, score_on_recordings

__all__ = ["rank_by_simulation"]


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
    amplitude = 0.5 * float(np.ptp(recordings[0].delta)) or 5e-3
    for cand in candidates:
        try:
            # a closed-loop run needs a displaced start, about one cycle amplitude
            params.append(cand.to_params(x0=amplitude))
            valid.append(cand)
        except ValueError as exc:
            cand.score = math.inf
            cand.score_details = {"status": f"not a valid model: {exc}"}
    if valid:
        scores, details = score_on_recordings(params, recordings, max_time)
        for i, cand in enumerate(valid):
            cand.score = float(np.mean(scores[i]))
            cand.score_details = {f"recording_{j}": d for j, d in enumerate(details[i])}
    return sorted(candidates, key=lambda c: (c.score is None, c.score))
