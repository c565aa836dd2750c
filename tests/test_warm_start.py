"""A warm start continues a limit cycle: a run started from a cycle state (with the play memory
and the delay's history) follows the run it was taken from."""
import dataclasses

import numpy as np
import pytest

from discovery.calibration.fastsim import BatchSimulator, warm_start_state
from models import CONTROLLER_A, M000, M001f, M002, simulate

DT = 5e-4


def _continuation_error(params, ws, seconds=1.5):
    """RMS (rad) of a run from ``ws`` against the 20 s reference run continued past ``ws``."""
    ref = simulate(params.replace(noise_power=0.0), CONTROLLER_A, 22.0, dt=DT, rate=None)
    # the sample the warm start was taken at (the same arithmetic up to 20 s: exact equality)
    i = int(np.flatnonzero((ref.x == ws.x) & (ref.theta == ws.theta))[0])
    n = int(round(seconds / DT))
    sim = BatchSimulator(CONTROLLER_A, seconds, DT, warm_start=ws)
    delta, ok = sim.run([params])
    assert ok[0]
    return float(np.sqrt(np.mean((delta[0, :n] - ref.delta[i:i + n]) ** 2)))


@pytest.mark.parametrize("params", [
    M002(),
    M001f().replace(bandpass_gain=0.0),
    M000().replace(bandpass_gain=0.0, noise_power=0.0),
], ids=["output delay", "before the integrator", "before the first integrator"])
def test_warm_start_with_memory_and_history_continues_the_cycle(params):
    ws = warm_start_state(params, CONTROLLER_A, DT)
    assert ws is not None and ws.history is not None and np.isfinite(ws.memory)
    amplitude = 0.5 * np.ptp(simulate(params, CONTROLLER_A, 20.0, dt=DT).delta[-8000:])
    assert amplitude > 1e-3
    complete = _continuation_error(params, ws)
    partial = _continuation_error(params, dataclasses.replace(ws, memory=np.nan, history=None))
    # measured: 1e-8 to 3e-7 rad complete (under 1e-4 of the amplitude), 2e-6 to 4e-5 rad
    # without the memory and the history (17-2000 times more)
    assert complete < 1e-4 * amplitude
    assert complete < 0.2 * partial
