"""What the two closed-loop terms share: the compared window of a limit-cycle recording, its
phase and period, and the simulator that runs each parameter set from a warm start
(:class:`_ClosedLoopTerm`, the base of :class:`.waveform.WaveformTerm` and
:class:`.features.FeatureTerm`).
"""
from __future__ import annotations

import math

import numpy as np

from tvcid.models.batch import (
    CONTINUATION_RADIUS,
    BatchSimulator,
    Continuation,
    output_rate_for,
    warm_start_state,
)
from tvcid.models.cycle_reading import cycle_crossings, white_noise_sd
from tvcid.models.cycle_state import RecordedCycleState

from .base import LikelihoodTerm

__all__ = ["MIN_AMPLITUDE_RATIO"]

#: A simulated cycle smaller than this fraction of the recorded one counts as not oscillating.
MIN_AMPLITUDE_RATIO = 0.2


def _data_window(recording, window):
    """Times from the window's start, the window's samples, and the window's start (s from the
    record's first sample)."""
    t, d = recording.t, recording.delta
    if window is not None:
        sel = t >= t[-1] - window
        t, d = t[sel], d[sel]
    return t - t[0], d, float(t[0] - recording.t[0])


class _ClosedLoopTerm(LikelihoodTerm):
    """Shared set-up of a closed-loop recording: window, data phase, simulator.

    Every run starts on the record's cycle: the warm start's reference run, and every run where
    that reference run does not oscillate, start from the loop's state on the recorded cycle
    (:class:`tvcid.models.cycle_state.RecordedCycleState`, the vehicle included), as the structure
    search's do. From the vehicle at rest, a model whose cycle coexists with a stable rest
    settles at rest and its likelihood is -inf however well its cycle fits.
    """

    def __init__(self, recording, window, transient, dt, name=None):
        if recording.kind != "closed":
            raise ValueError(f"{name or recording.path}: not a closed-loop recording")
        self.recording = recording
        self.name = name or (recording.path.stem if recording.path else "recording")
        self.source = str(recording.path) if recording.path else self.name  # for error messages
        #: model-discrepancy factor, the likelihood tempered by it (set at the MAP by Calibration)
        self.inflation = 1.0
        self.window = window
        self.transient = float(transient)
        self.dt = float(dt)
        self.tau, self.data, start = _data_window(recording, window)
        span = self.tau[-1]
        if self.tau.size < 10:
            raise ValueError(f"{self.source}: the window holds {self.tau.size} samples")
        self.sigma_hat = white_noise_sd(self.data)
        self.level = float(np.mean(self.data))
        self.amplitude = 0.5 * float(np.max(self.data) - np.min(self.data))
        ups = cycle_crossings(self.tau, self.data, self.level)
        if ups.size < 3:
            raise ValueError(
                f"{self.source}: the recording shows no limit cycle over its last {span:.3g} s "
                f"({max(ups.size - 1, 0)} whole periods; at least two are needed)"
            )
        k = np.arange(ups.size)
        slope, intercept = np.polyfit(k, ups, 1)
        self.period = float(slope)
        self.phase0 = float(intercept % slope)  # first crossing time in the window
        #: the loop's state on the recorded cycle, where runs start
        self.cycle_state = RecordedCycleState.from_cycle(
            recording, self.tau + start, self.data, ups + start, 2 * math.pi / self.period)
        self.experiment = self.cycle_state.experiment(recording.experiment())
        self.data_rate = float(recording.sample_rate)
        self.n = self.tau.size
        self.sim_t_end = self._run_end()
        self.simulator = None
        #: :class:`tvcid.models.batch.Continuation` of the runs, or ``None`` (every run from the shared
        #: start)
        self.continuation = None

    def _run_end(self) -> float:
        """Length (s) of a run: the transient, the window, and two and a half periods beyond it
        (the waveform's phase alignment reads past the window's end)."""
        return self.transient + float(self.tau[-1]) + 2.5 * self.period + 0.2

    @property
    def cycle_rms(self) -> float:
        """RMS of the recorded cycle about its mean, sensor noise removed (rad)."""
        return math.sqrt(max(float(np.var(self.data)) - self.sigma_hat**2, 0.0))

    @property
    def start_rms(self) -> float:
        """The size (rad) warm starts are scaled to: the recorded cycle's."""
        return self.cycle_rms

    def on_cycle(self, params):
        """``params`` with the actuator's initial conditions on the recorded cycle."""
        return params.replace(**self.cycle_state.initial_conditions(params))

    def warm_start_of(self, params, dt, t_ref=20.0, rms_target=None):
        """:func:`tvcid.models.batch.warm_start_state` of ``params`` from the recorded cycle's state,
        scaled to ``rms_target`` (default: the recorded cycle's size)."""
        return warm_start_state(self.on_cycle(params), self.experiment, dt, t_ref=t_ref,
                                rms_target=self.start_rms if rms_target is None else rms_target)

    def setup(self, start_params, warm_start=True):
        self._build_simulator(start_params, warm_start, self.dt)
        return self

    def _build_simulator(self, start_params, warm_start, dt):
        ws = self.warm_start_of(start_params, dt) if warm_start else None
        self.warm_start = ws
        self.simulator = BatchSimulator(
            self.experiment, self.sim_t_end, dt,
            rate=output_rate_for(dt, self.data_rate), warm_start=ws,
        )

    def set_transient(self, transient):
        """Simulate ``transient`` seconds before the compared window from now on (the simulator
        rebuilt at its present step, with its warm start). Returns ``self``."""
        self.transient = float(transient)
        self.sim_t_end = self._run_end()
        old = self.simulator
        if old is not None:
            self.simulator = BatchSimulator(self.experiment, self.sim_t_end, old.dt,
                                            rate=old.rate, warm_start=old.warm_start)
        return self

    def continue_runs(self, radius=CONTINUATION_RADIUS):
        """Start each run from the end state of the stored run nearest its parameters, when one
        is within ``radius`` (relative, every field): a walker's proposal continues its walker's
        cycle (:class:`tvcid.models.batch.Continuation`). Returns ``self``."""
        self.continuation = Continuation(radius=radius)
        return self

    def simulate(self, param_sets):
        if self.simulator.warm_start is None:  # no reference cycle: each run from the record's
            param_sets = [p if p is None else self.on_cycle(p) for p in param_sets]
        if self.continuation is None:
            return self.simulator.run(param_sets)
        starts = [self.continuation.nearest(p) for p in param_sets]
        delta, ok, states = self.simulator.run(param_sets, starts=starts, with_states=True)
        for p, state in zip(param_sets, states):
            self.continuation.add(p, state)
        return delta, ok

    def _halved_simulator(self, params, warm_start):
        """The simulator at half the step (ValueError when it does not fit the output grid)."""
        half = self.simulator.dt / 2
        ws = self.warm_start_of(params, half) if warm_start else None
        return BatchSimulator(self.experiment, self.sim_t_end, half,
                              rate=output_rate_for(half, self.data_rate), warm_start=ws)

    def describe(self):
        return {
            "name": self.name,
            "kind": "closed",
            "experiment": self.experiment.to_dict(),
            "window": float(self.tau[-1]),
            "samples": int(self.n),
            "sigma_hat": self.sigma_hat,
            "period": self.period,
            "transient": self.transient,
            "warm_start": self.warm_start is not None,
        }
