"""The phase-aligned waveform likelihood of a closed-loop recording (:class:`WaveformTerm`).

The simulated cycle has an arbitrary phase with respect to the recording, so the model is shifted
in time to the data: first by matching an upward mean crossing, then by two Gauss-Newton steps on
the shift that minimise the squared error (the shift is profiled out). The residuals over the
window are independent Gaussians of sd ``sigma``, plus the solver's own error
(:class:`.solver._WaveformSolverError`). A record whose waveform depends on more than the
parameters (a cycle that is not periodic, or one that attracts slowly) is said in an
:class:`IllPosedLikelihoodWarning`; the calibration then compares its features instead.
"""
from __future__ import annotations

import warnings

import numpy as np

from tvcid.models.batch import BatchSimulator
from tvcid.models.cycle_reading import cycle_crossings

from .base import waveform_inflation
from .closed_loop import MIN_AMPLITUDE_RATIO, _ClosedLoopTerm
from .solver import _WaveformSolverError

__all__ = [
    "WaveformTerm",
    "IllPosedLikelihoodWarning",
    "PERIOD_MISMATCH_LIMIT",
    "SETTLING_PERTURBATION",
    "SETTLING_REFERENCE",
]


class IllPosedLikelihoodWarning(UserWarning):
    """The waveform likelihood of a record depends on more than the parameters."""


#: A simulated cycle that differs from itself one period later by more than this many noise sds
#: (rms) is not periodic; its phase-aligned waveform depends on the initial state.
PERIOD_MISMATCH_LIMIT = 3.0
#: Relative size by which :meth:`WaveformTerm.settling_load`'s run starts larger than the record's
#: cycle.
SETTLING_PERTURBATION = 0.2
#: Seconds of the run that finds the warm start of :meth:`WaveformTerm.settling_load`
#: (:func:`tvcid.models.batch.warm_start_state`'s default).
SETTLING_REFERENCE = 20.0


class WaveformTerm(_WaveformSolverError, _ClosedLoopTerm):
    """Phase-aligned output error of one closed-loop recording over its last ``window`` s.

    :meth:`setup` checks that the start parameters' simulated cycle is periodic and warns
    (:class:`IllPosedLikelihoodWarning`) when it is not: a quasi-periodic cycle (M000's band-pass
    loop) makes the likelihood a function of the initial state and the transient, and the
    features likelihood is the one to use.

    A constant sensor offset is profiled out (the mean residual, one number against thousands of
    samples), as the open-loop term and the features (which compare no mean) do; kept, an
    offset would read as the right model's misfit.
    """

    kind = "waveform"
    offset_profiled = True

    def setup(self, start_params, warm_start=True):
        """The simulator at the coarsest step whose error the record cannot see
        (:meth:`_refine_step`), and a check that the start's simulated cycle is periodic."""
        # the warm start stays the start's when refine_at re-checks the step elsewhere
        self._refine_step(start_params, warm_start,
                          lambda dt: self._build_simulator(start_params, warm_start, dt))
        self.period_mismatch = self.period_mismatch_of(start_params)
        if not self.periodic:
            warnings.warn(IllPosedLikelihoodWarning(
                f"{self.not_periodic()}. Use likelihood='features'."), stacklevel=2)
        return self

    @property
    def periodic(self) -> bool:
        """The start's simulated cycle repeats itself within ``PERIOD_MISMATCH_LIMIT`` noise sds
        (after :meth:`setup`; a cycle that does not oscillate counts as periodic here)."""
        return not self.period_mismatch > PERIOD_MISMATCH_LIMIT * self.sigma_hat

    def not_periodic(self) -> str:
        """Why the waveform is ill-posed for a cycle that is not periodic (after :meth:`setup`)."""
        return (f"{self.name}: the simulated cycle of the start parameters is not periodic (one "
                f"period later it differs by {self.period_mismatch:.3g} rad rms, "
                f"{self.period_mismatch / self.sigma_hat:.0f}x the noise sd {self.sigma_hat:.3g} "
                "rad); the waveform likelihood then depends on the initial state and the "
                "transient as much as on the parameters")

    def settling_load(self, params, short, long, perturbation=SETTLING_PERTURBATION):
        """How far ``params``' cycle, started ``perturbation`` (relative) larger than the record's,
        still moves between transients ``short`` and ``long`` (s): half the sum of squares of the
        difference of the two aligned windows, their means removed, in units of the record's
        noise variance (nats at the noise); NaN when a window does not oscillate.

        A measure of how fast the cycle attracts at the waveform's resolution. Where it attracts
        slowly, a recording of it, made some unknown time after its start, may still be settling,
        and runs started on a cycle of the record's size carry their start's imprint, both of
        which a waveform comparison would read as parameters.
        """
        ws = self.warm_start_of(params, self.simulator.dt, t_ref=SETTLING_REFERENCE,
                                rms_target=(1.0 + perturbation) * self.cycle_rms)
        sim = BatchSimulator(self.experiment, self._settling_run(long),
                             self.simulator.dt, rate=self.simulator.rate, warm_start=ws)
        delta, ok = sim.run([params if ws is not None else self.on_cycle(params)])
        if not ok[0]:
            return float("nan")
        models = [self.align(delta[0], t=sim.t, transient=seconds) for seconds in (short, long)]
        if models[0] is None or models[1] is None:
            return float("nan")
        e = models[1] - models[0]
        e = e - np.mean(e)
        return 0.5 * float(np.sum(e * e)) / self.sigma_hat**2

    def _settling_run(self, long):
        """Length (s) of :meth:`settling_load`'s run after its warm start."""
        return long + float(self.tau[-1]) + 2.5 * self.period + 0.2

    def settling_seconds(self, long):
        """Seconds :meth:`settling_load` simulates (its warm start's reference run included)."""
        return SETTLING_REFERENCE + self._settling_run(long)

    def period_mismatch_of(self, params):
        """RMS difference (rad) of ``params``' simulated cycle and itself one period later,
        after the transient; 0 for a periodic cycle, NaN when it does not oscillate."""
        delta, ok = self.simulate([params])
        if not ok[0]:
            return float("nan")
        t = self.simulator.t
        after = t >= self.transient
        tm, m = t[after], delta[0, after]
        c = cycle_crossings(tm, m, float(np.mean(m)))
        if c.size < 3:
            return float("nan")
        period = (c[-1] - c[0]) / (c.size - 1)
        later = tm + period <= tm[-1]
        shifted = np.interp(tm[later] + period, tm, m)
        return float(np.sqrt(np.mean((shifted - m[later]) ** 2)))

    def align(self, delta_row, t=None, transient=None):
        """Model on the data's window, shifted to it; ``None`` if it does not oscillate.
        ``t``, ``transient``: another run's times and transient (default the term's)."""
        t = self.simulator.t if t is None else t
        transient = self.transient if transient is None else float(transient)
        after = t >= transient
        tm, m = t[after], delta_row[after]
        if not np.all(np.isfinite(m)):
            return None
        amp = 0.5 * float(np.max(m) - np.min(m))
        if amp < MIN_AMPLITUDE_RATIO * self.amplitude:
            return None
        c = cycle_crossings(tm, m, float(np.mean(m)))
        c = c[c >= transient + self.phase0]
        if c.size == 0:
            return None
        s = c[0] - self.phase0
        h = t[1] - t[0]
        dm = np.gradient(m, h)
        tau, d = self.tau, self.data
        for _ in range(2):
            mi = np.interp(tau + s, tm, m)
            gi = np.interp(tau + s, tm, dm)
            den = float(np.sum(gi * gi))  # no BLAS: its threads stall after numba's prange
            if den <= 0:
                break
            r = d - mi
            step = float(np.sum((r - np.mean(r)) * gi)) / den  # the offset is no phase error
            s = s + float(np.clip(step, -0.25 * self.period, 0.25 * self.period))
        s = max(s, transient)
        if tau[-1] + s > tm[-1]:
            return None
        return np.interp(tau + s, tm, m)

    def residuals(self, param_sets):
        """``(n_sets, n_samples)`` residuals data - model, the constant sensor offset profiled
        out; NaN rows for invalid runs."""
        delta, ok = self.simulate(param_sets)
        res = np.full((len(param_sets), self.n), np.nan)
        for i in np.flatnonzero(ok):
            m = self.align(delta[i])
            if m is not None:
                r = self.data - m
                res[i] = r - np.mean(r)
        return res

    def loglike(self, param_sets, sigma, pointwise=False):
        return self._gaussian_loglike(self.residuals(param_sets), sigma, pointwise)

    def predict(self, param_sets):
        """Aligned model waveforms on the data's window, plus the profiled sensor offset (NaN
        rows for invalid runs)."""
        return self.data[None, :] - self.residuals(param_sets)

    def discrepancy(self, params, sigma) -> float:
        """:func:`waveform_inflation` of the residuals at ``params`` (solver error scaled out)."""
        return waveform_inflation(self.scaled_residuals(self.residuals([params])[0], sigma), sigma)
