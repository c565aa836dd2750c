"""The solver's own error in an output-error likelihood, estimated by step doubling.

With a dead zone, a backlash, square edges or a held controller, RK4 converges at first order near
each switching event. :func:`_step_doubling` simulates a term's model again at half the step;
:class:`_WaveformSolverError` (shared by :class:`.waveform.WaveformTerm` and
:class:`.open_loop.OpenLoopTerm`) divides the step until the record cannot see its error, and adds
what is left to the noise variance sample by sample. The features term corrects its features for
the same change instead (:meth:`.features.FeatureTerm.solver_variance`).
"""
from __future__ import annotations

import math

import numpy as np

from .base import _LOG_2PI, tempered

__all__ = [
    "SOLVER_ERROR_FACTOR",
    "SOLVER_SPREAD_SAMPLES",
    "SOLVER_LOAD_LIMIT",
    "MAX_STEP_REFINEMENT",
]

#: The solver's error as a multiple of the change its step-doubling shows: at first order (RK4
#: near switching events) the coarse step's error is twice that change (Richardson). Waveforms
#: count it as variance; features correct for it (:meth:`.features.FeatureTerm.solver_variance`):
#: counted with the change itself, a drawn truth with a controller held at 200 Hz sits 1.0-1.5 sd
#: off its own data in every feature, all one way.
SOLVER_ERROR_FACTOR = 2.0

#: Samples either side over which a waveform's solver error is spread (its switching events move
#: with the parameters by about a step).
SOLVER_SPREAD_SAMPLES = 2
#: An output-error record's step is divided while its step-doubling change adds more than this to
#: the chi-square over the record (:meth:`_WaveformSolverError._refine_step`), at most this many
#: times over.
SOLVER_LOAD_LIMIT = 10.0
MAX_STEP_REFINEMENT = 8


def _step_doubling(term, evaluate, params, warm_start):
    """``(coarse, fine)``: ``evaluate([params])[0]`` with the term's simulator and with one at
    half its step (``term._halved_simulator``); None when the halved step does not fit the
    output grid."""
    coarse = evaluate([params])[0]
    try:
        fine_sim = term._halved_simulator(params, warm_start)
    except ValueError:
        return None
    kept, term.simulator = term.simulator, fine_sim
    try:
        fine = evaluate([params])[0]
    finally:
        term.simulator = kept
    return coarse, fine


class _WaveformSolverError:
    """Step-doubling estimate of the solver's error in an output-error likelihood.

    With a dead zone, a backlash, square edges or a held controller, RK4 converges at first order
    near each switching event; over thousands of samples of a 1e-5-1e-4 rad sensor, the step's
    error (a drawn truth's open-loop square at dt = 5e-4 against data at 2e-4) biases the
    posterior away from the truth by more than its width. The model's waveform at the start
    parameters is simulated again at half the step; the squared change, times
    ``SOLVER_ERROR_FACTOR ** 2`` (first-order Richardson), spread over
    ``SOLVER_SPREAD_SAMPLES`` either side (a running maximum), joins the noise variance sample by
    sample, as :meth:`.features.FeatureTerm.solver_variance` does for the features. A right model
    with a step that resolves it keeps its likelihood (the change is far below the noise).
    """

    solver_var = None
    #: chi-square the step's error adds over the record, at the estimated noise (set by
    #: :meth:`waveform_solver_variance`)
    solver_load = 0.0

    def _solver_outputs(self, param_sets):
        """What the step-doubling compares: the model at the record's samples."""
        return self.predict(param_sets)

    def waveform_solver_variance(self, params, warm_start=True):
        pair = _step_doubling(self, self._solver_outputs, params, warm_start)
        if pair is None:
            self.solver_load = 0.0
            return np.zeros(self.n)
        change = pair[0] - pair[1]
        if self.offset_profiled:
            change = change - np.nanmean(change)
        change = np.where(np.isfinite(change), change, 0.0)
        self.solver_load = float(np.sum(change * change)) / self.sigma_hat**2
        return self._spread_solver_error(SOLVER_ERROR_FACTOR * (pair[0] - pair[1]))

    def _refine_step(self, params, warm_start, build, dt=None):
        """Build the simulator (``build(dt)``) at the coarsest step whose error the record
        cannot see, and the solver variance at that step.

        The step is divided (down to ``dt / MAX_STEP_REFINEMENT``) while the step-doubling change
        at ``params`` adds more than ``SOLVER_LOAD_LIMIT`` to the record's chi-square
        (:attr:`solver_load`). Near switching events RK4 converges at first order, and the error,
        though under the noise sample by sample, is one-signed over thousands of samples, so the
        parameters can absorb it (a shifted delay cancels a phase error) where a variance cannot
        (``tests/test_command_replay.py``).
        The load falls as the step squared, so the next divisor is the one that squared law puts
        under the limit.
        A divided step that does not fit the output grid reports no change and is kept.
        The load is measured at ``params``, from step ``dt`` (default the term's ``dt``) down;
        :meth:`refine_at` repeats it at the maximum a posteriori.
        """
        self._build = build
        self._warm = warm_start
        base = self.dt
        divisor = 1 if dt is None else max(1, int(round(base / dt)))
        while True:
            build(base / divisor)
            self.solver_var = None
            self.solver_var = self.waveform_solver_variance(params, warm_start)
            if self.solver_load <= SOLVER_LOAD_LIMIT or divisor >= MAX_STEP_REFINEMENT:
                return
            wanted = math.ceil(divisor * math.sqrt(self.solver_load / SOLVER_LOAD_LIMIT) - 1e-9)
            divisor = min(MAX_STEP_REFINEMENT, max(divisor + 1, wanted))

    def refine_at(self, params):
        """The step check of :meth:`setup` again at ``params`` (the maximum a posteriori), from
        the present step down (never coarser), and the solver variance measured there.

        The load moves with the parameters (``tests/test_command_replay.py``), so a check at the
        start alone can keep a step the maximum a posteriori needs halved."""
        self._refine_step(params, self._warm, self._build, dt=self.simulator.dt)
        return self

    @property
    def sim_dt(self) -> float:
        """The step the simulations use (s): ``dt``, or finer (:meth:`_refine_step`)."""
        return self.simulator.dt

    def _spread_solver_error(self, d):
        """Per-sample variance of the solver's error ``d``, spread over its neighbours."""
        if self.offset_profiled:
            d = d - np.nanmean(d)
        var = np.where(np.isfinite(d), d * d, 0.0)
        k = SOLVER_SPREAD_SAMPLES
        padded = np.pad(var, k, mode="edge")
        return np.max(np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1), axis=1)

    def sample_sd(self, sigma, inflated=True):
        """``(n_sets, n_samples)`` sd of each sample: noise and solver error, inflated (unless
        ``inflated`` is false)."""
        sigma = np.asarray(sigma, dtype=float)[:, None]
        var = sigma * sigma
        if self.solver_var is not None:
            var = var + self.solver_var[None, :]
        return np.sqrt(var * self.inflation) if inflated else np.sqrt(var)

    def scaled_residuals(self, residuals, sigma):
        """Residuals rescaled so that noise of sd ``sigma`` plus the solver's estimated error
        reads as noise of sd ``sigma`` (for the discrepancy inflation and the checks)."""
        if self.solver_var is None:
            return residuals
        return residuals * sigma / np.sqrt(sigma * sigma + self.solver_var)

    def _gaussian_loglike(self, res, sigma, pointwise):
        """Log-likelihood of residual rows under noise and solver error (per sample), tempered:
        divided by the discrepancy inflation (:func:`tempered`)."""
        sd = self.sample_sd(sigma, inflated=False)
        ll = tempered(-0.5 * (res / sd) ** 2 - np.log(sd) - 0.5 * _LOG_2PI, self.inflation)
        ll = np.where(np.isfinite(ll), ll, -np.inf)
        return ll if pointwise else ll.sum(axis=1)
