"""The sensor, and synthetic recordings with a known truth for tests, benchmarks and studies.

:class:`Acquisition` is the sensor model: white noise, a constant offset and quantisation applied
to the simulated ``delta``. :func:`synthetic_recording` simulates a hypothesis with
:func:`tvcid.models.simulate` (no in-loop noise), measures it with a white-noise sensor drawn from a
seeded ``numpy.random.Generator``, writes it with :func:`tvcid.models.recording.save_recording` and reads
it back with :func:`tvcid.models.recording.load_recording` (the only way tvcid reads recordings).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvcid.models import simulate
from tvcid.models.recording import load_recording, recording_from_trajectory, save_recording

__all__ = ["Acquisition", "synthetic_recording"]


@dataclass(frozen=True)
class Acquisition:
    """Sensor: white noise sd (rad), constant offset (rad), quantisation step (rad, 0 = none)."""

    noise_sd: float
    offset: float
    quantisation: float

    def measure(self, delta, rng):
        """``delta`` (rad) as this sensor records it: plus white noise drawn from ``rng`` and the
        offset, then quantised."""
        out = np.asarray(delta) + self.noise_sd * rng.standard_normal(np.size(delta)) + self.offset
        if self.quantisation > 0:
            out = self.quantisation * np.round(out / self.quantisation)
        return out


def synthetic_recording(params, experiment, t_end, noise, seed, path, keep_last=None, dt=None,
                        rate=1000.0):
    """Simulate, add sensor noise, save to ``path`` and return the loaded :class:`Recording`.

    Parameters
    ----------
    params : tvcid.models.ActuatorParams
        The truth (its own ``noise_power`` is ignored: set to 0).
    experiment : ClosedLoop or OpenLoop
    t_end : float
        Simulated duration (s).
    noise : float
        Sensor-noise sd (rad) added to ``delta`` only (not in the loop).
    seed : int
        Seed of the ``numpy.random.Generator`` drawing the noise.
    path : str or Path
        ``NAME.csv``; the sidecar ``NAME.json`` is written beside it.
    keep_last : float or None
        Keep only the last ``keep_last`` seconds (a limit-cycle record without its transient).
    dt : float or None
        Simulation step (s); ``None``: :func:`tvcid.models.simulate.step_for_rate` of ``rate`` and a held
        controller's rate.
    rate : float
        Acquisition rate (Hz).
    """
    truth = params.replace(noise_power=0.0)
    tr = simulate(truth, experiment, t_end, rate=rate, dt=dt)
    columns, meta = recording_from_trajectory(
        tr, seed=seed, extra={"sensor_noise_sd": float(noise), "noise_kind": "sensor, white"}
    )
    rng = np.random.default_rng(seed)
    columns = {k: np.asarray(v, dtype=float).copy() for k, v in columns.items()}
    columns["delta"] = Acquisition(float(noise), 0.0, 0.0).measure(columns["delta"], rng)
    if keep_last is not None:
        sel = columns["t"] >= columns["t"][-1] - keep_last - 1e-9
        columns = {k: v[sel] for k, v in columns.items()}
        columns["t"] = columns["t"] - columns["t"][0]
    path = save_recording(Path(path), columns, meta)
    return load_recording(path)
