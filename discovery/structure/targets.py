"""What a simulation is compared with, one recording each: limit-cycle features or output error.

Every target turns a batch of simulated parameter sets into residuals in units of what the
recording can resolve, scaled so that each recording's cost (the sum of its squared residuals) is
their mean: about 1 for the generating model, whatever the experiment design.
Each recording then counts alike, however many samples it holds.

* :class:`CycleTarget` (closed loop): the frequency (unit: ``FREQUENCY_TOLERANCE`` = 0.1 %) and the
  complex harmonics 1..:data:`~tvcid.models.cycle_reading.N_HARMONICS` of ``delta`` with their phases referred to the fundamental's
  (unit: 0.3 % of the fundamental's amplitude), i.e. the cycle's waveform without its arbitrary phase;
  each unit widened by the record's own wander between pieces of ``PERIODS`` periods (a cycle that
  is not periodic, as the band-pass loop's, differs from piece to piece); the simulated cycle's
  features are taken over as many periods as the record's tail holds (``WINDOW_PERIODS`` to
  ``MAX_WINDOW_PERIODS``), so that they too average its wander. A record whose cycle is still
  settling (its size per period follows an exponential approach) is compared as the transient it
  is: the simulation starts at the state of the tail's first periods and its features are taken
  over the same periods as the record's.
  The frequency comes from mean crossings as docs/models.md#conventions measures it; the harmonics are Fourier
  coefficients over whole periods. They need no phase alignment of the simulated cycle with the
  record, and they stay defined for a cycle that is not periodic (the band-pass loop's), where a
  phase-aligned waveform is not. A constant sensor offset only moves the mean, which is not
  compared.
* :class:`OutputTarget` (open loop): the output error of a simulation from rest with the replayed
  command (:meth:`tvcid.models.recording.Recording.experiment`), the constant sensor offset profiled out
  (its least-squares value is the mean residual); unit: the sensor noise estimated from the record
  (:func:`tvcid.models.cycle_reading.white_noise_sd`) with a floor of 0.1 % of its rms.

Each target has a coarse counterpart (:meth:`CycleTarget.coarse`, :meth:`OutputTarget.coarse`):
the same comparison over fewer periods or the record's first part, a fraction of the simulated
seconds. The structure search's differential evolution screens on it; every refinement and the
ranking use the full target (:mod:`.structure_search`).

A run that diverges or stops oscillating gets ``PENALTY`` residuals, never an exception.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import threading

import numpy as np

from tvcid.models.batch import BatchSimulator, output_rate_for
from tvcid.models.cycle_reading import (
    N_HARMONICS,
    crossing_multiple,
    cycle_crossings,
    cycle_of,
    phase_free_harmonics,
    white_noise_sd,
)
from tvcid.models.cycle_settling import period_sizes, settles, stationary_tail
from tvcid.models.cycle_state import RecordedCycleState
from tvcid.models.edge_timing import edge_timing_for

__all__ = [
    "CycleTarget",
    "OutputTarget",
    "make_target",
    "FREQUENCY_TOLERANCE",
    "HARMONIC_TOLERANCE",
    "OUTPUT_TOLERANCE",
    "PENALTY",
]

#: Relative errors that count as one unit of residual.
FREQUENCY_TOLERANCE = 0.001
HARMONIC_TOLERANCE = 0.003
#: Floor of the open-loop output error's unit, relative to the record's rms: the RK4 error of the
#: simulations' step (5e-4 s) against a fine one on a square-wave response (0.04-0.1 %).
OUTPUT_TOLERANCE = 0.001
#: Residual of every component of a run that diverged or does not oscillate.
PENALTY = 1e4
#: A simulated cycle under this fraction of the recorded amplitude does not count as oscillating.
MIN_AMPLITUDE_RATIO = 0.2
#: A closed-loop run whose cost on its record exceeds this is simulated again from a second start.
SECOND_START_COST = 10.0
#: Seconds a closed-loop simulation runs before its features are taken; periods of the record
#: per piece of its wander (:meth:`CycleTarget._wander`).
TRANSIENT = 4.0
PERIODS = 6
#: Periods of the record's cycle the simulated window holds at least and at most: as many as the
#: record's tail (30 % more time is simulated). The record's features average over its whole tail
#: (20-60 periods); a cycle that wanders (a band-pass loop not locked to it, a controller held at
#: 200 Hz) gives a short window's features far from that mean, by where the window falls.
WINDOW_PERIODS = 12
MAX_WINDOW_PERIODS = 24
#: Output rate (Hz) of the closed-loop simulations: 35x the 7th harmonic of a 2 Hz cycle.
SIMULATED_RATE = 500.0
#: A settling record: periods whose first harmonics fix its first period's size,
#: and periods a run gets, beyond ``TRANSIENT``, to reach that size.
SIZE_FIT_PERIODS = 4
SETTLING_LEAD_PERIODS = 8
#: ... and how many periods back a run that starts past that size is extrapolated at most.
MAX_EXTRAPOLATED_PERIODS = 2.0
#: Whole periods each half of a cycle needs before the ranking splits it into two folds.
MIN_HALF_PERIODS = 2
#: Blocks an open-loop record is cut into for the ranking's folds (even blocks, odd blocks).
OUTPUT_BLOCKS = 8
#: A coarse target (:meth:`CycleTarget.coarse`): periods of a cycle's simulated window (a settling
#: record: of its tail's first periods) ...
COARSE_PERIODS = 6
#: ... and the fraction of an open-loop record (its start: a run from rest cannot skip any).
COARSE_OUTPUT_FRACTION = 0.4
_COUNT_LOCK = threading.Lock()


class _Target:
    """What both targets share: simulate a batch, then score the runs."""

    def residuals(self, param_sets):
        delta, ok = self.simulator.run(param_sets)
        return self.residuals_of_runs(delta, ok)

    def residuals_counted(self, param_sets):
        """:meth:`residuals` and the runs simulated beyond one per set (second starts), for the
        cost :class:`.search.Objective` counts."""
        return self.residuals(param_sets), 0

    def halves(self):
        """Two targets on complementary halves of the record (the ranking's two folds).

        They share this target's simulator: a fold changes what is compared, not what is
        simulated.
        """
        return self._half(0), self._half(1)


class CycleTarget(_Target):
    """Frequency and phase-free harmonics of one closed-loop recording.

    Parameters
    ----------
    recording : tvcid.models.recording.Recording
    dt : float
        RK4 step of the simulations (s).
    keep : float
        Fraction of the record (its end) whose features are compared; the start may hold a
        transient.
    """

    kind = "closed"

    def __init__(self, recording, dt):
        self.recording = recording
        self.name = recording.path.stem if recording.path else "recording"
        t_all, d_all = recording.t - recording.t[0], recording.delta
        t, d, ups = stationary_tail(t_all, d_all, str(recording.path or self.name))
        self.tail_start = float(t[0])
        #: the cycle still settles over the tail (:func:`settles`): compared as a transient
        self.settling = settles(t, d, ups)
        # a settling cycle starts at its first two periods' state and is compared after them
        start, ups = (ups[:3], ups[2:]) if self.settling else (ups, ups)
        self.omega = 2 * math.pi * (len(ups) - 1) / (ups[-1] - ups[0])
        w = (t >= ups[0]) & (t < ups[-1])
        self.harmonics = phase_free_harmonics(t[w], d[w], self.omega)
        self.mean = float(np.mean(d[w]))
        self.amplitude = 0.5 * float(np.ptp(d[t >= ups[0] - 0.5 * (ups[1] - ups[0])]))
        self.scale = abs(self.harmonics[0])
        self.period = 2 * math.pi / self.omega
        self.multiple = crossing_multiple(t, d, np.asarray(ups))
        self.dt = float(dt)
        start_omega = 2 * math.pi * (len(start) - 1) / (start[-1] - start[0])
        #: the loop's state on the record's cycle, where every run starts
        self.initial = RecordedCycleState.from_cycle(recording, t, d, start, start_omega,
                                                     N_HARMONICS)
        self.experiment = self.initial.experiment(recording.experiment())
        #: periods of the simulated window: as many as the record's tail holds, within
        #: WINDOW_PERIODS .. MAX_WINDOW_PERIODS (a settling record: all of its tail's)
        if self.settling:
            self.window_periods = len(ups) - 1
            sizes = period_sizes(t, d, ups)
            k = np.arange(min(SIZE_FIT_PERIODS, sizes.size))
            #: the first period's first harmonic (a line through the first few: sensor noise) and
            #: whether the cycle grows: the run's window starts where it passes that size
            self.first_size = float(np.polyval(np.polyfit(k, sizes[k], 1), 0.0))
            self.growing = bool(sizes[-1] >= sizes[0])
            lead = max(TRANSIENT, SETTLING_LEAD_PERIODS * self.period)
            self.t_end = (ups[-1] - ups[0]) + lead + 0.2
        else:
            self.window_periods = int(min(MAX_WINDOW_PERIODS, max(WINDOW_PERIODS, len(ups) - 1)))
            self.t_end = TRANSIENT + self.window_periods * self.period * 1.3 + 0.2
        #: periods of the compared window that are skipped and kept (a fold's half of a
        #: settling record)
        self.segment = (0, self.window_periods)
        self.simulator = BatchSimulator(self.experiment, self.t_end, self.dt,
                                        rate=output_rate_for(self.dt, SIMULATED_RATE))
        self.n_residuals = 1 + 2 * N_HARMONICS
        self.wander = self._wander(t, d, np.asarray(ups))
        floor = np.concatenate([[FREQUENCY_TOLERANCE * self.omega],
                                np.full(2 * N_HARMONICS, HARMONIC_TOLERANCE * self.scale)])
        #: one unit of each residual: the floor, widened by the cycle's own wander
        self.unit = np.sqrt(floor**2 + self.wander**2)
        #: cost the generating model pays for the simulated window's own wander alone (a window
        #: of ``window_periods`` wanders as PERIODS / window_periods times the pieces' variance);
        #: a cost difference of that size is no evidence (:func:`.indistinguishable.margin_floors`)
        self.window_cost = float(np.mean(self.wander**2 * (PERIODS / self.window_periods)
                                         / self.unit**2))
        self._observed = self._features(self.omega, self.harmonics)
        self._tail = (t, d, np.asarray(ups))
        #: runs simulated again from the second start (:meth:`residuals`)
        self.second_starts = 0

    def _half(self, k):
        """The features of the first (k=0) or second (k=1) half of the tail's whole periods.

        A tail of fewer than ``2 * MIN_HALF_PERIODS`` periods is not split (both folds see it
        whole, so it adds no out-of-sample information).
        """
        t, d, ups = self._tail
        n = ups.size - 1
        half = copy.copy(self)
        if n < 2 * MIN_HALF_PERIODS:
            return half
        u = ups[: n // 2 + 1] if k == 0 else ups[n // 2:]
        if self.settling:  # a transient's half is compared with the same half of the run
            half.segment = (0, n // 2) if k == 0 else (n // 2, n - n // 2)
        w = (t >= u[0]) & (t < u[-1])
        omega = 2 * math.pi * (u.size - 1) / (u[-1] - u[0])
        half._observed = self._features(omega, phase_free_harmonics(t[w], d[w], omega))
        return half

    def coarse(self):
        """This target over ``COARSE_PERIODS`` periods: a copy with its own, shorter simulator.

        A periodic cycle's features over 6 periods are those over 12-24 up to the window's
        wander; a settling record is compared over its tail's first ``COARSE_PERIODS`` periods
        (its observed features taken over the same periods). The copy's cost is a screening
        cost: the search's differential evolution ranks its population on it, and least squares
        refines on the full target. A window of ``COARSE_PERIODS`` or fewer is its own coarse
        target.
        """
        if self.window_periods <= COARSE_PERIODS:
            return self
        out = copy.copy(self)
        out.window_periods = COARSE_PERIODS
        out.segment = (0, COARSE_PERIODS)
        if self.settling:
            t, d, ups = self._tail
            u = ups[: COARSE_PERIODS + 1]
            w = (t >= u[0]) & (t < u[-1])
            omega = 2 * math.pi * COARSE_PERIODS / (u[-1] - u[0])
            out._observed = self._features(omega, phase_free_harmonics(t[w], d[w], omega))
            out.t_end = (u[-1] - u[0]) + max(TRANSIENT, SETTLING_LEAD_PERIODS * self.period) + 0.2
        else:
            out.t_end = TRANSIENT + COARSE_PERIODS * self.period * 1.3 + 0.2
        out.simulator = BatchSimulator(self.experiment, out.t_end, self.dt,
                                       rate=output_rate_for(self.dt, SIMULATED_RATE))
        return out

    def _features(self, omega, harmonics):
        return np.concatenate([[omega], harmonics.real, harmonics.imag])

    def _wander(self, t, d, ups):
        """Spread of the features between pieces of ``PERIODS`` periods of the record.

        A periodic cycle gives pieces alike (zero up to noise); the band-pass loop's cycle, not
        locked to its 9-10 Hz oscillation, wanders from piece to piece, and a simulated piece of
        the same length wanders as much, so that spread widens the residual's unit.
        """
        n_pieces = (ups.size - 1) // PERIODS
        if n_pieces < 2:
            return np.zeros(self.n_residuals)
        rows = []
        for j in range(n_pieces):
            a, b = ups[j * PERIODS], ups[(j + 1) * PERIODS]
            sel = (t >= a) & (t < b)
            omega = 2 * math.pi * PERIODS / (b - a)
            rows.append(self._features(omega, phase_free_harmonics(t[sel], d[sel], omega)))
        return np.std(np.asarray(rows), axis=0, ddof=1)

    def initial_conditions(self, params=None):
        """Actuator initial conditions (fields of ActuatorParams) of a simulation of ``params``:
        the record's cycle state's (:meth:`tvcid.models.cycle_state.RecordedCycleState.initial_conditions`;
        with the record's rate ``y = x'`` alone, a model with coexisting cycles can settle on one
        the record does not show).
        """
        return self.initial.initial_conditions(params)

    def residuals(self, param_sets):
        """Residuals of each set from :meth:`initial_conditions`' start, or from the record's
        rate (``y = x'``) where that start's cycle misses the record by over
        ``SECOND_START_COST``.

        A model with coexisting cycles shows the one its (unrecorded) initial conditions select;
        each start alone misses the truth's recorded cycle on some records.
        """
        return self._simulated(param_sets)[2]

    def residuals_counted(self, param_sets):
        """:meth:`residuals` and the runs simulated again from the second start."""
        _, _, res, again = self._simulated(param_sets)
        return res, again

    def _simulated(self, param_sets):
        """Outputs, success flags and residuals of ``param_sets`` (the better of the two starts
        where the first misses), and the runs simulated again from the second start."""
        delta, ok = self.simulator.run(param_sets)
        res = self.residuals_of_runs(delta, ok)
        cost = np.sum(res * res, axis=1)
        redo = [i for i, p in enumerate(param_sets)
                if p is not None and cost[i] > SECOND_START_COST and p.y0 != self.initial.y]
        if redo:
            d2, ok2 = self.simulator.run([param_sets[i].replace(y0=self.initial.y) for i in redo])
            r2 = self.residuals_of_runs(d2, ok2)
            better = np.sum(r2 * r2, axis=1) < cost[redo]
            rows = np.asarray(redo)[better]
            delta[rows], ok[rows], res[rows] = d2[better], ok2[better], r2[better]
        with _COUNT_LOCK:  # concurrent refinements share the target
            self.second_starts += len(redo)
        return delta, ok, res, len(redo)

    def residuals_of_runs(self, delta, ok):
        """Residuals ``(n, n_residuals)`` of simulated outputs ``delta`` (rows) on this target."""
        t = self.simulator.t
        after = t >= TRANSIENT
        out = np.full((delta.shape[0], self.n_residuals), PENALTY)
        for i in np.flatnonzero(ok):
            if self.settling:
                features = self._transient_features(t, delta[i])
                if features is not None:
                    out[i] = (features - self._observed) / self.unit
                continue
            m = delta[i, after]
            if 0.5 * np.ptp(m) < MIN_AMPLITUDE_RATIO * self.amplitude:
                continue
            cyc = cycle_of(t[after], m, self.multiple)
            if cyc is None:
                continue
            omega, harm, _ = cyc
            out[i] = (self._features(omega, harm) - self._observed) / self.unit
        out /= math.sqrt(self.n_residuals)
        return out

    def _transient_features(self, t, x):
        """Features of a run of a settling record over the periods that match the record's.

        The run starts at the record's first periods' state, but the states the record does not
        show (the delay line, the play, the valve's block) start at rest and cost the run a few
        per cent of its size over its first periods. Along a slow approach to a cycle the size
        alone says where the cycle is, so the compared window starts where the run's per-period
        first harmonic passes the record's first (interpolated between the two windows that start
        on either side of it) and holds as many periods as the record's tail: the comparison
        keeps the growth over the tail, its frequency and waveform, and not the run's start.
        ``None`` when the run does not hold them (it stops oscillating or is too short).
        """
        c = cycle_crossings(t, x, float(np.mean(x[t >= t[-1] - self.window_periods * self.period])))
        c = c[:: self.multiple]
        n = self.window_periods
        if c.size < n + 3:
            return None
        sizes = period_sizes(t, x, c)
        if np.max(sizes) < MIN_AMPLITUDE_RATIO * self.first_size:
            return None
        # the run's first period carries the start's transient; a run that starts past the size
        # is extrapolated back from its next two periods (a smooth approach, a period or two)
        passed = sizes[1:] >= self.first_size if self.growing else sizes[1:] <= self.first_size
        last = c.size - 1 - n  # the last window that fits
        j = 1 + int(np.argmax(passed)) if passed.any() else last
        j = min(max(j, 2), last)
        step = sizes[j] - sizes[j - 1]
        w = (self.first_size - sizes[j - 1]) / step if step != 0 else 1.0
        w = min(max(w, -MAX_EXTRAPOLATED_PERIODS), 1.0)
        skip, keep = self.segment
        both = []
        for a in (j - 1, j):
            u = c[a + skip: a + skip + keep + 1]
            sel = (t >= u[0]) & (t < u[-1])
            omega = 2 * math.pi * (u.size - 1) / (u[-1] - u[0])
            both.append(self._features(omega, phase_free_harmonics(t[sel], x[sel], omega)))
        return (1.0 - w) * both[0] + w * both[1]

    def offset(self, param_sets):
        """Mean of the record minus the simulated cycle's mean (a sensor offset), per set."""
        delta, ok, _, _ = self._simulated(param_sets)
        after = self.simulator.t >= TRANSIENT
        return np.where(ok, self.mean - np.nanmean(delta[:, after], axis=1), np.nan)

    def describe(self):
        return {"name": self.name, "kind": "closed", "experiment": self.experiment.to_dict(),
                "frequency": self.omega, "amplitude": self.amplitude,
                "H1": float(abs(self.harmonics[0])), "settling": bool(self.settling),
                "samples": int(self.recording.t.size),
                "sample_rate": float(self.recording.sample_rate)}


class OutputTarget(_Target):
    """Output error of one open-loop recording, sensor offset profiled out.

    A piecewise-constant command known only as samples (a square wave, a step) is simulated once
    with its edges on the solver's grid and read at each parameter set's best edge timing among
    those its samples allow (:class:`tvcid.models.edge_timing.EdgeTiming`, the same
    nuisance the calibration integrates out): no replay's choice is read as a delay.
    """

    kind = "open"
    #: a simulation from rest has no window to wander (:attr:`CycleTarget.window_cost`)
    window_cost = 0.0

    def __init__(self, recording, dt):
        self.recording = recording
        self.name = recording.path.stem if recording.path else "recording"
        self.dt = float(dt)
        experiment = recording.experiment()
        self.timing = edge_timing_for(experiment, recording.t, recording.u, self.dt)
        self.experiment = experiment if self.timing is None else self.timing.experiment
        self.tau = recording.t - recording.t[0]
        self.data = recording.delta
        self.rms = float(np.std(self.data))
        if not self.rms > 0:
            raise ValueError(f"{recording.path or self.name}: the output never moves (constant delta)")
        rate = None if self.timing is not None else output_rate_for(self.dt, float(recording.sample_rate))
        self.simulator = BatchSimulator(self.experiment, float(self.tau[-1]), self.dt, rate=rate)
        self.n_residuals = self.tau.size
        self.noise_sd = white_noise_sd(self.data)
        self.unit = math.hypot(self.noise_sd, OUTPUT_TOLERANCE * self.rms)
        self._var = np.full(self.tau.size, self.unit**2)
        self._mask = slice(None)
        self._norm = 1.0 / (self.unit * math.sqrt(self.tau.size))

    def _half(self, k):
        """The even (k=0) or odd (k=1) of ``OUTPUT_BLOCKS`` consecutive blocks of the record.

        Interleaved blocks, not the first and second half, so that each fold holds responses
        to every part of the command (an early transient, late edges).
        """
        block = np.minimum((OUTPUT_BLOCKS * np.arange(self.tau.size)) // self.tau.size,
                           OUTPUT_BLOCKS - 1)
        half = copy.copy(self)
        half._mask = np.flatnonzero(block % 2 == k)
        half.n_residuals = half._mask.size
        half._norm = 1.0 / (self.unit * math.sqrt(half._mask.size))
        return half

    def coarse(self):
        """This target on the record's first ``COARSE_OUTPUT_FRACTION``: a target of its own on
        the record cut there (the command's samples cut with it). Its cost is a screening cost,
        as :meth:`CycleTarget.coarse`'s."""
        rec = self.recording
        keep = rec.t <= rec.t[0] + COARSE_OUTPUT_FRACTION * (rec.t[-1] - rec.t[0])
        cut = dataclasses.replace(rec, columns={k: np.asarray(v)[keep] for k, v in rec.columns.items()})
        return OutputTarget(cut, self.dt)

    def initial_conditions(self, params=None):
        return None  # from rest (OpenLoop.from_rest)

    def _model(self, delta, ok):
        """The model at the record's samples (at the best edge timing on this target's mask)."""
        model = np.full((delta.shape[0], self.tau.size), np.nan)
        for i in np.flatnonzero(ok):
            if not np.all(np.isfinite(delta[i])):
                continue
            if self.timing is None:
                model[i] = np.interp(self.tau, self.simulator.t, delta[i])
                continue
            var = self._var
            if not isinstance(self._mask, slice):  # a fold: only its samples time the edges
                var = np.full_like(self._var, np.inf)
                var[self._mask] = self._var[self._mask]
            _, _, theta = self.timing.marginal(self.tau, self.data, self.simulator.t, delta[i], var)
            model[i] = self.timing.shifted(theta, self.tau, self.simulator.t, delta[i])[0]
        return model

    def residuals_of_runs(self, delta, ok):
        res = (self.data[None, :] - self._model(delta, ok))[:, self._mask]
        res = res - np.mean(res, axis=1, keepdims=True)
        out = res * self._norm
        out[~np.all(np.isfinite(out), axis=1)] = PENALTY / math.sqrt(out.shape[1])
        return out

    def residuals(self, param_sets):
        return self.residuals_of_runs(*self.simulator.run(param_sets))

    def offset(self, param_sets):
        delta, ok = self.simulator.run(param_sets)
        return np.mean(self.data[None, :] - self._model(delta, ok), axis=1)

    def noise(self, params):
        """RMS of the output error at ``params`` (rad): the sensor noise if the model is right."""
        delta, ok = self.simulator.run([params])
        return float(np.std(self.data - self._model(delta, ok)[0]))

    def describe(self):
        exp = self.experiment
        return {"name": self.name, "kind": "open", "samples": int(self.tau.size),
                "duration": float(self.tau[-1]), "sample_rate": float(self.recording.sample_rate),
                "command": exp.waveform if self.timing is None
                else f"piecewise constant from samples ({exp.t_samples.size} edges, their timing "
                     f"fitted within the {'phase and half period' if self.timing.dim == 2 else 'shift'}"
                     " the samples allow)"}


def make_target(recording, dt):
    """The target of one recording by its kind."""
    if recording.kind == "closed":
        return CycleTarget(recording, dt)
    return OutputTarget(recording, dt)

