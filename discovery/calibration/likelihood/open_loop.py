"""The output-error likelihood of an open-loop recording (:class:`OpenLoopTerm`).

Open-loop recordings are compared sample by sample with no shift (the command sets the phase),
simulated from rest with the recorded command, the sensor's constant offset profiled out. A
piecewise-constant command known only as samples has its edge timing integrated out
(:mod:`tvcid.models.edge_timing`); the edges are simulated on the step's grid or where they are,
whichever is closer to a fine simulation (:meth:`OpenLoopTerm.edge_loads`).
"""
from __future__ import annotations

import math

import numpy as np

from tvcid.models.batch import BatchSimulator, output_rate_for
from tvcid.models.cycle_reading import white_noise_sd

from .base import LikelihoodTerm, waveform_inflation
from .solver import _WaveformSolverError

__all__ = ["OpenLoopTerm", "EDGE_CHECK_REFINEMENT"]

#: How much finer than the step the reference of :meth:`OpenLoopTerm.edge_loads` runs.
EDGE_CHECK_REFINEMENT = 8


class OpenLoopTerm(_WaveformSolverError, LikelihoodTerm):
    """Output error of an open-loop recording, simulated from rest with the recorded command.

    The sensor's constant offset is profiled out of the residuals (their mean removed), as a
    measured record carries one (HWIL: ~1.5e-4 rad). A piecewise-constant command known only as
    samples (a square wave, a step) has an edge timing the samples leave open within up to a
    sample; it is integrated out under a uniform prior (:class:`tvcid.models.edge_timing.EdgeTiming`), so
    that neither a replay's choice nor its error is read as a delay.
    """

    kind = "waveform"

    def __init__(self, recording, window, transient, dt, name=None):
        if recording.kind != "open":
            raise ValueError(f"{name or recording.path}: not an open-loop recording")
        self.recording = recording
        self.name = name or (recording.path.stem if recording.path else "recording")
        t0 = recording.t[0]
        self.tau = recording.t - t0
        self.data = recording.delta
        self.dt = float(dt)
        # the sidecar's analytic command when it reproduces u (sharp square edges), else u replayed
        self._recorded_experiment = recording.experiment()
        #: simulated edges on the step grid, then shifted (:mod:`tvcid.models.edge_timing`); cleared by
        #: :meth:`setup` when the response does not settle between edges
        self.edges_on_grid = True
        self.edge_loads_ = None
        self.edge_load = 0.0  # the chi-square of the edges' placement at the present step
        #: the timing the edges are simulated at when off the grid (None: the centre)
        self.edge_theta = None
        self._time_edges(self.dt)
        self.n = self.tau.size
        self.sigma_hat = white_noise_sd(self.data)
        self.data_rate = float(recording.sample_rate)
        self.inflation = 1.0  # model-discrepancy factor (tempering; Calibration sets it at the MAP)
        self.warm_start = None
        self.simulator = None

    offset_profiled = True

    def _time_edges(self, dt):
        """The edge timing and the simulated experiment, edges on the grid of step ``dt``."""
        from tvcid.models.edge_timing import edge_timing_for

        exp = self._recorded_experiment
        self.timing = edge_timing_for(exp, self.recording.t, self.recording.u, dt,
                                      on_grid=self.edges_on_grid)
        if self.timing is not None and not self.edges_on_grid and self.edge_theta is not None:
            self.timing.simulate_at(self.edge_theta, dt)
        self.experiment = exp if self.timing is None else self.timing.experiment

    def _rate(self, dt):
        # the timing's shifts read the response between samples: keep every step
        return None if self.timing is not None else output_rate_for(dt, self.data_rate)

    def setup(self, start_params, warm_start=True):
        """The simulator at the coarsest step whose error the record cannot see
        (:meth:`_refine_step`; a record with 1e-4 rad of noise sampled at 200 Hz keeps the step
        it was given). At each step tried, a sampled piecewise command's edges are simulated on
        the step's grid or where they are, whichever is closer to a fine simulation of them
        (:meth:`edge_loads`), and that way's load counts with the step-doubling one: the grid's
        shift error does not shrink when only the solver's step is halved, so step doubling alone
        cannot see it."""
        self.start_params = start_params
        self._build_for(start_params)
        self._refine_step(start_params, warm_start, self._build)
        return self

    def _build_for(self, params):
        """``self._build``: the simulator at a step, edges placed as :meth:`edge_loads` finds
        best at ``params``."""
        def build(dt):
            self.edges_on_grid = True
            self._time_edges(dt)
            self.simulator = BatchSimulator(self.experiment, float(self.tau[-1]), dt,
                                            rate=self._rate(dt))
            self.edge_load = 0.0
            if self.timing is None:
                return
            loads = self.edge_loads_ = self.edge_loads(params, dt)
            if loads["centre_at_timing"] < loads["grid_at_timing"]:
                self.edges_on_grid = False
                self._recentre_edges(params, dt)
            # the grid's load read at the centre: its linear read between steps at the record's
            # timing is not counted (docs/limits.md)
            self.edge_load = loads["grid"] if self.edges_on_grid else loads["centre_at_timing"]

        self._build = build

    def waveform_solver_variance(self, params, warm_start=True):
        """Step doubling (:class:`_WaveformSolverError`); the load is the larger of its own and
        the edges' (:meth:`setup`), which measures the whole error against a fine simulation,
        the solver's at this step included."""
        var = super().waveform_solver_variance(params, warm_start)
        self.solver_load = max(self.solver_load, self.edge_load)
        return var

    def refine_at(self, params):
        """The step check again at ``params`` (the maximum a posteriori), the edges placed and
        recentred there."""
        self._build_for(params)
        return super().refine_at(params)

    def _recentre_edges(self, params, dt):
        """Simulate the edges where the record puts them at ``params`` (two passes: the
        optimum's shift from the centre is itself read off a shifted copy)."""
        for _ in range(2):
            self._time_edges(dt)
            self.simulator = BatchSimulator(self.experiment, float(self.tau[-1]), dt,
                                            rate=self._rate(dt))
            delta, ok = self.simulator.run([params])
            if not ok[0] or not np.all(np.isfinite(delta[0])):
                return
            var = np.full(self.n, self.sigma_hat**2)
            _, _, theta = self.timing.marginal(self.tau, self.data, self.simulator.t, delta[0], var)
            self.edge_theta = np.asarray(theta, dtype=float)
        self._time_edges(dt)
        self.simulator = BatchSimulator(self.experiment, float(self.tau[-1]), dt,
                                        rate=self._rate(dt))

    def edge_loads(self, params, dt) -> dict:
        """Chi-square each way of simulating the edges at step ``dt`` adds against a finer
        simulation of them (record's samples, offset removed, over the noise ``sigma_hat``):
        ``grid`` (the centre edges rounded to the grid, the response shifted) and ``centre``
        (the edges simulated where they are, off the grid: RK4 first order there).

        Read twice. ``grid`` and ``centre``: at the centre timing, against the centre edges at
        ``dt / EDGE_CHECK_REFINEMENT``, the step check's load when the grid is kept.
        ``grid_at_timing`` and ``centre_at_timing``: at the record's most probable timing at
        ``params``, which the likelihood reads (and where :meth:`_recentre_edges` puts the
        edges), against those edges on the finer grid shifted by under ``dt / 16``; they choose
        the way: at the centre alone a 200 Hz square's edges fall on the grid, where both ways
        are one simulation and cannot be told apart.
        """
        from tvcid.models.edge_timing import EdgeTiming

        end = float(self.tau[-1])
        failed = {"grid": 0.0, "centre": math.inf, "grid_at_timing": 0.0,
                  "centre_at_timing": math.inf}

        def simulated(timing, step):
            sim = BatchSimulator(timing.experiment, end, step)
            delta, ok = sim.run([params])
            return (sim.t, delta[0]) if ok[0] and np.all(np.isfinite(delta[0])) else None

        def load(out, ref):
            d = out - ref
            d = d - np.mean(d)
            return float(np.sum(d * d)) / self.sigma_hat**2

        zero = np.zeros(self.timing.dim)
        outputs = {}
        for name, step, on_grid in (("grid", dt, True), ("centre", dt, False),
                                    ("fine", dt / EDGE_CHECK_REFINEMENT, False)):
            timing = EdgeTiming(self.recording.t, self.recording.u, step, on_grid=on_grid)
            run = simulated(timing, step)
            if run is None:
                return failed
            outputs[name] = timing.shifted(zero, self.tau, *run)[0]
            if name == "grid":
                grid_timing, grid_run = timing, run
        loads = {name: load(outputs[name], outputs["fine"]) for name in ("grid", "centre")}
        var = np.full(self.n, self.sigma_hat**2)
        _, _, theta = grid_timing.marginal(self.tau, self.data, *grid_run, var)
        at = {"grid": grid_timing.shifted(theta, self.tau, *grid_run)[0]}
        for name, step, on_grid in (("centre", dt, False),
                                    ("fine", dt / EDGE_CHECK_REFINEMENT, True)):
            timing = EdgeTiming(self.recording.t, self.recording.u, step, on_grid=False)
            try:
                timing.simulate_at(theta, step, on_grid=on_grid)
            except ValueError:  # edges closer than the step at that timing
                return failed
            run = simulated(timing, step)
            if run is None:
                return failed
            at[name] = timing.shifted(theta, self.tau, *run)[0]
        for name in ("grid", "centre"):
            loads[name + "_at_timing"] = load(at[name], at["fine"])
        return loads

    def _solver_outputs(self, param_sets):
        return self._at_samples(param_sets)

    def _halved_simulator(self, params, warm_start):
        half = self.simulator.dt / 2
        return BatchSimulator(self.experiment, float(self.tau[-1]), half, rate=self._rate(half))

    def _at_samples(self, param_sets):
        """The simulated output at the record's samples, edges as simulated."""
        delta, ok = self.simulator.run(param_sets)
        out = np.full((len(param_sets), self.n), np.nan)
        for i in np.flatnonzero(ok):
            out[i] = np.interp(self.tau, self.simulator.t, delta[i])
        return out

    def _profiled(self, param_sets, sigma=None):
        """``(model, log_volume)``: the model at the record's samples at each set's most probable
        edge timing (offset not removed) and the log of the timing's integral (zeros without a
        timing nuisance)."""
        n_sets = len(param_sets)
        if self.timing is None:
            return self._at_samples(param_sets), np.zeros(n_sets)
        delta, ok = self.simulator.run(param_sets)
        sig = np.full(n_sets, self.sigma_hat) if sigma is None else np.broadcast_to(
            np.asarray(sigma, dtype=float), (n_sets,))
        var = self.sample_sd(sig) ** 2
        out = np.full((n_sets, self.n), np.nan)
        log_volume = np.zeros(n_sets)
        for i in np.flatnonzero(ok):
            if not np.all(np.isfinite(delta[i])):
                continue
            res, log_volume[i], _ = self.timing.marginal(self.tau, self.data, self.simulator.t,
                                                         delta[i], var[i])
            out[i] = self.data - res  # offset removed: the mean residual goes into the model
        return out, log_volume

    def predict(self, param_sets, sigma=None):
        """The model at the record's samples (edge timing at its most probable value)."""
        return self._profiled(param_sets, sigma)[0]

    def residuals(self, param_sets, sigma=None):
        """Data - model, with a constant sensor offset profiled out (one number against
        thousands of samples); NaN rows for invalid runs."""
        res = self.data[None, :] - self.predict(param_sets, sigma)
        return res - np.mean(res, axis=1, keepdims=True)

    def discrepancy(self, params, sigma) -> float:
        """:func:`waveform_inflation` of the residuals at ``params`` (solver error scaled out)."""
        return waveform_inflation(self.scaled_residuals(self.residuals([params], [sigma])[0], sigma),
                                  sigma)

    def loglike(self, param_sets, sigma, pointwise=False):
        """Gaussian output error; with a timing nuisance, its log integral spread evenly over
        the samples when ``pointwise``."""
        model, log_volume = self._profiled(param_sets, sigma)
        res = self.data[None, :] - model
        res = res - np.mean(res, axis=1, keepdims=True)
        ll = self._gaussian_loglike(res, sigma, pointwise)
        return ll + (log_volume[:, None] / self.n if pointwise else log_volume)

    def describe(self):
        return {"name": self.name, "kind": "open", "samples": int(self.n),
                "duration": float(self.tau[-1]), "sigma_hat": self.sigma_hat,
                "command": {"samples": "recorded samples",
                            "piecewise": "recorded samples, piecewise constant (edges rebuilt)"}.get(
                                self.experiment.waveform, "sidecar " + self.experiment.waveform)}
