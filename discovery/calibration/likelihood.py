"""Likelihood terms of one recording each, and the vectorised log posterior they add up to.

Two likelihoods (issue 5, item 1):

* ``waveform``: phase-aligned output error. The simulated cycle has an arbitrary phase with respect
  to the recording, so the model is shifted in time to the data: first by matching an upward mean
  crossing, then by two Gauss-Newton steps on the shift that minimise the squared error (the shift
  is profiled out). The residuals over the window are independent Gaussians of sd ``sigma``.
  Open-loop recordings are compared sample by sample with no shift (the command sets the phase).
* ``features``: limit-cycle features (frequency and the amplitudes of chosen harmonics, odd by
  default) as a Gaussian. Their covariance is propagated from the sensor noise by re-noising the
  recording (``n_mc`` seeded draws at the noise level estimated from it) and scales as
  ``(sigma/sigma_hat)^2`` when ``sigma`` is sampled. Amplitude as ``(max-min)/2`` is available as
  ``"amplitude"`` but is biased upwards by the noise extremes; ``"H1"`` (first-harmonic amplitude)
  is the unbiased amplitude and the default.

A diverging, invalid or non-oscillating simulation gets ``-inf``, never an exception.
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from models.batch import (
    CONTINUATION_RADIUS,
    BatchSimulator,
    Continuation,
    output_rate_for,
    warm_start_state,
)
from models.features import (
    InsufficientPeriodsError,
    crossing_hysteresis,
    limit_cycle_features,
    upward_mean_crossings,
)

__all__ = [
    "estimate_noise",
    "cycle_features",
    "WaveformTerm",
    "IllPosedLikelihoodWarning",
    "FeatureTerm",
    "make_term",
    "LIKELIHOODS",
    "DEFAULT_FEATURES",
]

LIKELIHOODS = ("waveform", "features")
DEFAULT_FEATURES = ("frequency", "H1", "H3", "H5", "H7")
_LOG_2PI = math.log(2 * math.pi)

#: Tail probability beyond which the misfit at the maximum a posteriori counts as model
#: discrepancy (and inflates the likelihood's covariance).
DISCREPANCY_P = 0.05


def residual_statistics(residuals, sigma):
    """``(n, variance ratio, lag-1 autocorrelation)`` of the finite residuals, mean removed;
    the ratio is ``mean r^2 / sigma^2`` (NaN for fewer than two residuals)."""
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    n = r.size
    if n < 2:
        return n, math.nan, math.nan
    r = r - np.mean(r)
    ss = float(np.sum(r * r))
    rho = float(np.sum(r[1:] * r[:-1])) / ss if ss > 0 else 0.0
    return n, ss / n / float(sigma) ** 2, rho


def waveform_inflation(residuals, sigma) -> float:
    """Discrepancy factor of an output-error likelihood (its log-likelihood is divided by it,
    :func:`tempered`).

    At the maximum a posteriori a right model leaves the sensor's white noise; a wrong or slightly
    wrong one (or a solver whose step error shows at switching events) leaves a structured misfit,
    larger than the noise and correlated over many samples, which a white-noise likelihood reads
    as thousands of independent confirmations (needle posteriors). The factor is the product of
    the misfit's excess over the noise, ``mean r^2 / sigma^2``, and the residuals' integrated
    autocorrelation time ``tau`` (samples per independent one; emcee's estimator with Sokal's
    window, c = 5): a generalised-Bayes tempering by what the residuals really hold. Each factor
    counts only beyond what a white residual gives by chance (``3 sqrt(2/n)`` for the variance
    ratio, ``10 / sqrt(n)`` for ``tau``; 0 false alarms in 20 white records of 4000 samples), so
    a right model keeps 1.
    """
    from emcee.autocorr import integrated_time

    n, ratio, _ = residual_statistics(residuals, sigma)
    if n < 10 or not sigma > 0 or not ratio > 0:
        return 1.0
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    tau = float(integrated_time(r - np.mean(r), c=5, tol=0, quiet=True)[0])
    excess = ratio if ratio > 1.0 + 3.0 * math.sqrt(2.0 / n) else 1.0
    samples_per_independent = min(tau, float(n)) if tau > 1.0 + 10.0 / math.sqrt(n) else 1.0
    return float(excess * samples_per_independent)


def tempered(loglike, inflation):
    """A generalised-Bayes (tempered) log-likelihood: ``loglike / inflation``.

    For a fixed noise sd this is the same as inflating the noise variance by ``inflation``; where
    the noise sd is sampled it is not: an inflated variance ``sigma^2 f`` is undone by a sampled
    ``sigma`` that shrinks by ``sqrt(f)`` (its maximum is at ``sigma^2 f = RSS / n``), so the
    physical parameters kept their width, the reported noise sd was ``sqrt(f)`` too small, and the
    features terms that follow the sampled sd (``FeatureTerm.noise_from_sigma``) were narrowed by
    ``f``. Coverage draw 18 (an open-loop factor of 1.36) had its intervals 4-7 % narrower with the
    term than without it, and its chain did not converge in 1500 steps (the noise sd's tau 41
    against 5-6, its walkers started at the untempered maximum); tempered, it converged in 130
    steps (tau 2.1-2.3) with both truths inside. ``sigma`` keeps its maximum at the sensor noise
    and the factor widens the physical parameters' posterior.
    """
    return loglike / float(inflation)


def features_inflation(whitened) -> float:
    """Discrepancy factor of a features likelihood (its log-likelihood is divided by it,
    :func:`tempered`).

    ``1 + (chi2 - q) / k`` for the ``k`` whitened residuals at the maximum a posteriori, where
    ``q`` is the ``1 - DISCREPANCY_P`` quantile of a chi-square with ``k`` degrees of freedom; 1
    when ``chi2 <= q``. Only the misfit beyond what sensor noise makes in all but
    ``DISCREPANCY_P`` of records counts, so the factor starts from 1 at the test's threshold
    instead of jumping to ``q / k`` (2.2 for five features), and tends to ``chi2 / k`` for a large
    misfit. The jump made the test's false alarms on right models (one record in twenty by
    construction) cost up to 1.5x in interval width: coverage draw 13, the truth's own structure
    with a tail noise realisation (chi-square 14.8 at the truth, 13.3 at the maximum), was inflated
    2.66x, its backlash's interval 24 % wider; now 1.44x (12 % wider).
    """
    from scipy.stats import chi2 as chi2_dist

    z = np.asarray(whitened, dtype=float)
    if not np.all(np.isfinite(z)):
        return 1.0
    k, chi2 = z.size, float(np.sum(z * z))
    q = float(chi2_dist.ppf(1.0 - DISCREPANCY_P, k))
    return 1.0 + (chi2 - q) / k if chi2 > q else 1.0

#: A trend of the features across the window's pieces counts as a cycle still settling beyond
#: this many noise-only standard errors of its slope ...
SETTLING_SLOPE_SD = 3.0
#: ... and this fraction of the pieces' spread (a wander has no steady direction) ...
SETTLING_R2 = 0.8
#: ... and the settled features are then unknown by this many times the drift over the window.
SETTLING_WINDOWS = 2.0

#: A record counts as still settling when, over its whole length, an exponential approach
#: explains its pieces' frequency or size this much better than a constant (chi-square gain in
#: units of the fit's own residual variance where that exceeds the noise): an F of 50, p ~ 1e-5 at
#: 12 pieces; at 25, two settled records whose pieces scatter beyond their noise (coverage draws
#: 1 and 13) were taken as settling ...
SETTLING_FIT_GAIN = 100.0
#: ... from at least this many pieces (three parameters and three degrees of freedom).
SETTLING_MIN_PIECES = 6


def settling_gain(centres, values, noise_var) -> float:
    """How much better ``a + b exp((c_last - c) / T)`` fits a record's piece features than a
    constant: the chi-square gain at the best time constant ``T`` of a grid, in units of the
    fit's residual variance where that exceeds the noise (a two-mode settling is not one
    exponential). 0 with fewer than :data:`SETTLING_MIN_PIECES` pieces.

    ``centres`` (s, increasing), ``values`` (the pieces' feature), ``noise_var`` (each piece's
    feature variance under sensor noise).
    """
    c = np.asarray(centres, dtype=float)
    f = np.asarray(values, dtype=float)
    w = 1.0 / np.maximum(np.asarray(noise_var, dtype=float), 1e-300)
    n = c.size
    if n < SETTLING_MIN_PIECES or not np.all(np.isfinite(f)):
        return 0.0
    chi_constant = float(np.sum(w * (f - np.sum(w * f) / np.sum(w)) ** 2))
    best = math.inf
    for T in np.geomspace(0.25 * (c[1] - c[0]), c[-1] - c[0], 200):
        X = np.stack([np.ones(n), np.exp((c[-1] - c) / T)], axis=1)
        A = X.T @ (X * w[:, None])
        if np.linalg.cond(A) > 1e12:
            continue
        beta = np.linalg.solve(A, X.T @ (w * f))
        best = min(best, float(np.sum(w * (f - X @ beta) ** 2)))
    if not math.isfinite(best):
        return 0.0
    return (chi_constant - best) / max(1.0, best / (n - 3))


#: The solver's error as a multiple of the change its step-doubling shows: at first order (RK4
#: near switching events) the coarse step's error is twice that change (Richardson). Waveforms
#: count it as variance (with the change itself, a drawn truth with a controller held at 200 Hz
#: sat 1.0-1.5 sd off its own data in every feature, all one way); features correct for it
#: (:meth:`FeatureTerm.solver_variance`).
SOLVER_ERROR_FACTOR = 2.0

#: Samples either side over which a waveform's solver error is spread (its switching events move
#: with the parameters by about a step).
SOLVER_SPREAD_SAMPLES = 2
#: An open-loop record's step is halved while its step-doubling change adds more than this to
#: the chi-square over the record (:meth:`OpenLoopTerm.setup`), at most this many times over.
SOLVER_LOAD_LIMIT = 10.0
MAX_STEP_REFINEMENT = 8
#: How much finer than the step the reference of :meth:`OpenLoopTerm.edge_loads` runs.
EDGE_CHECK_REFINEMENT = 8


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
    error (a drawn truth's open-loop square at dt = 5e-4 against data at 2e-4) biased the
    posterior away from the truth by more than its width. The model's waveform at the start
    parameters is simulated again at half the step; the squared change, times
    ``SOLVER_ERROR_FACTOR ** 2`` (first-order Richardson), spread over
    ``SOLVER_SPREAD_SAMPLES`` either side (a running maximum), joins the noise variance sample by
    sample, as :meth:`FeatureTerm.solver_variance` does for the features. A right model with a
    step that resolves it keeps its likelihood (the change is far below the noise).
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

        The step is halved (down to ``dt / MAX_STEP_REFINEMENT``) while the step-doubling change
        at ``params`` adds more than ``SOLVER_LOAD_LIMIT`` to the record's chi-square
        (:attr:`solver_load`). Near switching events RK4 converges at first order, and the error,
        though under the noise sample by sample, is one-signed over thousands of samples, so the
        parameters can absorb it (a shifted delay cancels a phase error) where a variance cannot:
        coverage draw 10 (two 1 kHz squares, noise 1.3e-5 rad) had loads of 590 and 1130 at
        5e-4 s, the posterior's dead zone and backlash 5 % and 58 % above the truth, which beat
        it by 48 nats at 5e-4 s and lost by 65 at 1e-4 s; the ridge case (seed 0, limit cycle at
        B, 1e-4 rad noise) had a load of 33 at 5e-4 s (0.2 at 2.5e-4 s) and its posterior beat the
        truth by 21 nats, the dead zone and the delay just outside their 90 % intervals.
        A halved step that does not fit the output grid reports no change and is kept.
        The load is measured at ``params``, from step ``dt`` (default the term's ``dt``) down;
        :meth:`refine_at` repeats it at the maximum a posteriori.
        """
        self._build = build
        self._warm = warm_start
        dt = self.dt if dt is None else dt
        while True:
            build(dt)
            self.solver_var = None
            self.solver_var = self.waveform_solver_variance(params, warm_start)
            if self.solver_load <= SOLVER_LOAD_LIMIT or dt <= self.dt / MAX_STEP_REFINEMENT:
                return
            dt /= 2

    def refine_at(self, params):
        """The step check of :meth:`setup` again at ``params`` (the maximum a posteriori), from
        the present step down (never coarser), and the solver variance measured there.

        The load moves with the parameters: before the friction offset's jump was located inside
        the step, the ridge case's cycle at B had a load of 33 at the truth and under 10 at its
        start 20 % away, so a check at the start alone kept 5e-4 s and the posterior beat the truth
        by 21 nats."""
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


#: A simulated cycle smaller than this fraction of the recorded one counts as not oscillating.
MIN_AMPLITUDE_RATIO = 0.2


def estimate_noise(delta) -> float:
    """Sensor-noise sd from the second differences (robust MAD; exact for white noise)."""
    d2 = np.diff(np.asarray(delta, dtype=float), 2)
    mad = np.median(np.abs(d2 - np.median(d2)))
    return float(1.4826 * mad / math.sqrt(6.0))


def _crossings(t, x, level):
    """Linear-interpolated upward crossings of ``level`` by a noise-free ``x``."""
    i = np.flatnonzero((x[:-1] < level) & (x[1:] >= level))
    return t[i] + (level - x[i]) / (x[i + 1] - x[i]) * (t[i + 1] - t[i])


def cycle_features(t, x, names=DEFAULT_FEATURES):
    """Features of a noise-free cycle, by :func:`models.features.limit_cycle_features`'s rules.

    Frequency from the mean period between the first and last upward mean crossing, harmonic
    amplitudes ``Hk`` over the whole periods between them, ``amplitude = (max - min)/2``. Vectorised
    (no per-sample Python loop), for simulated cycles; returns ``None`` under two whole periods.
    """
    level = float(np.mean(x))
    c = _crossings(t, x, level)
    if c.size < 3:
        return None
    period = (c[-1] - c[0]) / (c.size - 1)
    w0 = 2 * math.pi / period
    sel = (t >= c[0]) & (t < c[-1])
    ts, xs = t[sel], x[sel]
    dt = float(np.mean(np.diff(t)))
    ks = [int(n[1:]) for n in names if n.startswith("H")]
    harm = {}
    if ks:
        k = np.asarray(ks)
        basis = np.exp(-1j * np.outer(k, w0 * (ts - ts[0])))
        coeffs = 2.0 / (ts.size * dt) * np.sum(basis * (xs - xs.mean())[None, :], axis=1) * dt
        harm = {f"H{kk}": float(a) for kk, a in zip(ks, np.abs(coeffs))}
    out = []
    for n in names:
        if n == "frequency":
            out.append(w0)
        elif n == "amplitude":
            out.append(0.5 * float(np.max(x) - np.min(x)))
        else:
            out.append(harm[n])
    return np.asarray(out)


def _check_feature_names(names):
    names = tuple(names)
    if not names:
        raise ValueError("features likelihood needs at least one feature")
    for n in names:
        if n in ("frequency", "amplitude"):
            continue
        if n.startswith("H") and n[1:].isdigit() and int(n[1:]) >= 1:
            continue
        raise ValueError(f"unknown feature {n!r}; use frequency, amplitude or Hk (k >= 1)")
    return names


def _data_window(recording, window):
    t, d = recording.t, recording.delta
    if window is not None:
        sel = t >= t[-1] - window
        t, d = t[sel], d[sel]
    return t - t[0], d


class _ClosedLoopTerm:
    """Shared set-up of a closed-loop recording: window, data phase, simulator."""

    def __init__(self, recording, window, transient, dt, name=None):
        if recording.kind != "closed":
            raise ValueError(f"{name or recording.path}: not a closed-loop recording")
        self.recording = recording
        self.name = name or (recording.path.stem if recording.path else "recording")
        self.source = str(recording.path) if recording.path else self.name  # for error messages
        #: model-discrepancy factor, the likelihood tempered by it (set at the MAP by Calibration)
        self.inflation = 1.0
        self.experiment = recording.experiment()
        self.window = window
        self.transient = float(transient)
        self.dt = float(dt)
        self.tau, self.data = _data_window(recording, window)
        span = self.tau[-1]
        if self.tau.size < 10:
            raise ValueError(f"{self.source}: the window holds {self.tau.size} samples")
        self.sigma_hat = estimate_noise(self.data)
        self.level = float(np.mean(self.data))
        self.amplitude = 0.5 * float(np.max(self.data) - np.min(self.data))
        ups = upward_mean_crossings(
            self.tau, self.data, self.level, crossing_hysteresis(self.data, self.amplitude)
        )
        if ups.size < 3:
            raise ValueError(
                f"{self.source}: the recording shows no limit cycle over its last {span:.3g} s "
                f"({max(ups.size - 1, 0)} whole periods; at least two are needed)"
            )
        k = np.arange(ups.size)
        slope, intercept = np.polyfit(k, ups, 1)
        self.period = float(slope)
        self.phase0 = float(intercept % slope)  # first crossing time in the window
        self.data_rate = float(recording.sample_rate)
        self.n = self.tau.size
        self.sim_t_end = self.transient + span + 2.5 * self.period + 0.2
        self.simulator = None
        #: :class:`.fastsim.Continuation` of the runs, or ``None`` (every run from the shared start)
        self.continuation = None

    @property
    def cycle_rms(self) -> float:
        """RMS of the recorded cycle about its mean, sensor noise removed (rad)."""
        return math.sqrt(max(float(np.var(self.data)) - self.sigma_hat**2, 0.0))

    @property
    def start_rms(self) -> float:
        """The size (rad) warm starts are scaled to: the recorded cycle's."""
        return self.cycle_rms

    def setup(self, start_params, warm_start=True):
        self._build_simulator(start_params, warm_start, self.dt)
        return self

    def _build_simulator(self, start_params, warm_start, dt):
        ws = (warm_start_state(start_params, self.experiment, dt, rms_target=self.start_rms)
              if warm_start else None)
        self.warm_start = ws
        self.simulator = BatchSimulator(
            self.experiment, self.sim_t_end, dt,
            rate=output_rate_for(dt, self.data_rate), warm_start=ws,
        )

    def set_transient(self, transient):
        """Simulate ``transient`` seconds before the compared window from now on (the simulator
        rebuilt at its present step, with its warm start). Returns ``self``."""
        self.transient = float(transient)
        self.sim_t_end = self.transient + float(self.tau[-1]) + 2.5 * self.period + 0.2
        old = self.simulator
        if old is not None:
            self.simulator = BatchSimulator(self.experiment, self.sim_t_end, old.dt,
                                            rate=old.rate, warm_start=old.warm_start)
        return self

    def continue_runs(self, radius=CONTINUATION_RADIUS):
        """Start each run from the end state of the stored run nearest its parameters, when one
        is within ``radius`` (relative, every field): a walker's proposal continues its walker's
        cycle (:class:`.fastsim.Continuation`). Returns ``self``."""
        self.continuation = Continuation(radius=radius)
        return self

    def simulate(self, param_sets):
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
        ws = (warm_start_state(params, self.experiment, half, rms_target=self.start_rms)
              if warm_start else None)
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


class IllPosedLikelihoodWarning(UserWarning):
    """The waveform likelihood of a record depends on more than the parameters."""


#: A simulated cycle that differs from itself one period later by more than this many noise sds
#: (rms) is not periodic; its phase-aligned waveform depends on the initial state.
PERIOD_MISMATCH_LIMIT = 3.0
#: Relative size by which :meth:`WaveformTerm.settling_load`'s run starts larger than the record's
#: cycle.
SETTLING_PERTURBATION = 0.2
#: Seconds of the run that finds the warm start of :meth:`WaveformTerm.settling_load`
#: (:func:`.fastsim.warm_start_state`'s default).
SETTLING_REFERENCE = 20.0


class WaveformTerm(_WaveformSolverError, _ClosedLoopTerm):
    """Phase-aligned output error of one closed-loop recording over its last ``window`` s.

    :meth:`setup` checks that the start parameters' simulated cycle is periodic and warns
    (:class:`IllPosedLikelihoodWarning`) when it is not: a quasi-periodic cycle (M000's band-pass
    loop) makes the likelihood a function of the initial state and the transient, and the
    features likelihood is the one to use.

    A constant sensor offset is profiled out (the mean residual, one number against thousands of
    samples), as the open-loop term and the features (which compare no mean) do: without it a
    record with an offset of 2.8e-4 rad (coverage draw 22, noise 2.6e-5) cost the right model an
    rms residual of 2.8e-4 at the truth, a discrepancy factor of 24 and a dead zone outside its
    90 % interval.
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
        and runs started on a cycle of the record's size carry their start's imprint: coverage
        draw 22 (dead zone on the velocity signal, controller held at 200 Hz, its record's window
        21-31 s after the kick; 990 nats at its truth with a 20 % larger start) had a record
        4.6e-6 rad rms from the settled cycle over the window's first half and 1.2e-6 over its
        second (noise 2.6e-5), which put the truth 75 nats under a point whose dead zone and delay
        lay outside their 90 % intervals.
        """
        ws = warm_start_state(params, self.experiment, self.simulator.dt, t_ref=SETTLING_REFERENCE,
                              rms_target=(1.0 + perturbation) * self.cycle_rms)
        sim = BatchSimulator(self.experiment, self._settling_run(long),
                             self.simulator.dt, rate=self.simulator.rate, warm_start=ws)
        delta, ok = sim.run([params])
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
        c = _crossings(tm, m, float(np.mean(m)))
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
        c = _crossings(tm, m, float(np.mean(m)))
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


class FeatureTerm(_ClosedLoopTerm):
    """Gaussian likelihood of the limit-cycle features of one closed-loop recording.

    Covariance: the features' spread under the recording's sensor noise (Monte Carlo over
    ``n_mc`` noise draws), plus twice the cycle's own window-to-window wander measured on
    ``n_segments`` pieces of the window (zero for a periodic cycle), plus the uncertainty of the
    settled features when the cycle is still settling over the window (zero for a settled one),
    plus an optional relative ``floor``. For the bundled M000 records the estimated wander of a
    10 s window's frequency is 0.43 % (controller A) and 0.36 % (B), while 40 windows of a 420 s
    run spread by 0.12 % and 0.06 %: per feature the estimate is 1.1-3.8x (A) and 3.9-7.5x (B)
    the measured spread, i.e. conservative (``tests/test_calibration_features.py``).
    """

    kind = "features"
    #: The covariance follows the sampled noise sd (scaled by ``sigma / sigma_hat``); ``False``
    #: keeps the record's own noise estimate (a record that fell back from the waveform: its 15
    #: numbers cannot estimate the noise, and a sigma free to shrink narrowed coverage draw 0's
    #: dead-zone interval 4x, the truth outside it).
    noise_from_sigma = True

    def __init__(self, recording, window, transient, dt, name=None, features=DEFAULT_FEATURES,
                 n_mc=64, rng=None, floor=0.0, n_segments=4):
        super().__init__(recording, window, transient, dt, name=name)
        self.features = _check_feature_names(features)
        try:
            self.observed = self._data_features(self.data)
        except InsufficientPeriodsError as exc:
            raise ValueError(f"{self.name}: {exc}") from None
        rng = np.random.default_rng(0) if rng is None else rng
        draws = np.array([
            self._data_features(self.data + self.sigma_hat * rng.standard_normal(self.n))
            for _ in range(int(n_mc))
        ])
        cov = np.atleast_2d(np.cov(draws, rowvar=False))
        # a cycle that is not periodic (the band-pass loop's unlocked 9-10 Hz oscillation) wanders
        # from window to window beyond what sensor noise explains; the data's and the simulated
        # window each wander by that much
        self.wander_var, self.settling_var = self._wander_variance(n_segments, n_mc, rng)
        cov += np.diag(2.0 * self.wander_var + self.settling_var)
        cov += np.diag((float(floor) * np.abs(self.observed)) ** 2)
        cov += np.diag(1e-12 * np.diag(cov) + 1e-300)
        self._data_cov = cov
        self.solver_var = np.zeros(len(self.features))
        self.solver_bias = np.zeros(len(self.features))
        self.transient_var = np.zeros(len(self.features))
        self._factor(cov)
        #: ``(rms, seconds, piece)``: the record still settles over its length, so runs start
        #: where it does, sized so that their first ``piece`` seconds have the rms of the
        #: record's, ``seconds`` before its window (:meth:`_record_start`); ``None``: runs start
        #: at the window's size, ``transient`` seconds before it
        self.record_start = self._record_start(n_segments)
        if self.record_start is not None:
            self.set_transient(self.record_start[1])  # no simulator yet: sets the run's length
        self._start_rms = None

    @property
    def start_rms(self) -> float:
        if self.record_start is None:
            return self.cycle_rms
        return self.record_start[0] if self._start_rms is None else self._start_rms

    def _build_simulator(self, start_params, warm_start, dt):
        """As the base class; for a record that settles, the start's size is then matched:
        a run started on the reference cycle scaled to the record's first-piece rms does not have
        that rms over its own first piece (the scaled state is not on the approach and relaxes
        first), so the size is corrected by the ratio, twice."""
        super()._build_simulator(start_params, warm_start, dt)
        if self.record_start is None or self.warm_start is None:
            return
        target, _, piece = self.record_start
        for _ in range(2):
            sim = BatchSimulator(self.experiment, piece, dt, rate=None, warm_start=self.warm_start)
            delta, ok = sim.run([start_params])
            if not ok[0]:
                return
            rms = float(np.std(delta[0]))
            if not rms > 0:
                return
            self._start_rms = self.start_rms * target / rms
            super()._build_simulator(start_params, warm_start, dt)

    def _record_start(self, n_segments, n_noise=24):
        """Where runs start when the whole record shows its cycle still settling.

        A cycle that settles slowly (coverage draw 15: a ~4.5 s time constant; H1 1.4063, 1.4646,
        1.4711, 1.4718, 1.4720 e-2 rad over successive 10 s) is still about 8 noise sd under its
        settled size in the record's last 10 s, while the window's own pieces show no clear trend
        (:meth:`_wander_variance`), and a run started at the window's size settles within the
        transient: the right model's discrepancy factor was 1.7-2.8 and its dead zone and friction
        offset intervals 1.8x as wide. The record is cut, back from its end, into pieces as long
        as the window's (at least three periods); where their frequency or size (H1 or
        amplitude) follows an exponential approach (:func:`settling_gain` at least
        :data:`SETTLING_FIT_GAIN`), a run starts at the size of the record's first piece (sensor
        noise removed; the start's size is then matched at set-up, :meth:`_build_simulator`), as
        many seconds before the window as the record has before it: it then approaches its cycle
        as the record does, each from its own matched size (:meth:`simulate`). Those runs do
        not continue each other (:meth:`continue_runs`) and carry no start imprint
        (:meth:`transient_variance`): the imprint is the record's. Draw 15 rerun: factors 1.0,
        every truth inside, intervals 0.92-0.98x as wide as without the discrepancy term.
        ``None`` for a record that does not settle (everything as before).
        """
        t = np.asarray(self.recording.t, dtype=float)
        d = np.asarray(self.recording.delta, dtype=float)
        length = max(float(self.tau[-1] - self.tau[0]) / max(int(n_segments), 1), 3.0 * self.period)
        centres, rows, end = [], [], float(t[-1])
        while end - length >= t[0] - 1e-9:
            sel = (t >= end - length) & (t <= end)
            try:
                rows.append(self._data_features_at(t[sel] - t[sel][0], d[sel]))
            except InsufficientPeriodsError:
                break
            centres.append(end - 0.5 * length)
            end -= length
        if len(rows) < SETTLING_MIN_PIECES:
            return None
        centres, rows = np.asarray(centres[::-1]), np.asarray(rows[::-1])
        rng = np.random.default_rng(0)  # its own draws: the term's noise draws stay as they were
        sel = t >= t[-1] - length
        noise = np.var([self._data_features_at(t[sel] - t[sel][0],
                                               d[sel] + self.sigma_hat * rng.standard_normal(sel.sum()))
                        for _ in range(int(n_noise))], axis=0, ddof=1)
        tested = [i for i, n in enumerate(self.features) if n in ("frequency", "H1", "amplitude")]
        if not any(settling_gain(centres, rows[:, i], np.full(len(rows), noise[i]))
                   >= SETTLING_FIT_GAIN for i in tested):
            return None
        first = d[t <= t[0] + length]
        rms = math.sqrt(max(float(np.var(first)) - self.sigma_hat**2, 0.0))
        before = float(t[-1] - t[0]) - float(self.tau[-1])
        if not (rms > 0 and before > length):
            return None
        return rms, before, length

    def continue_runs(self, radius=CONTINUATION_RADIUS):
        """As :meth:`_ClosedLoopTerm.continue_runs`, except for a record that settles: its runs
        start where the record does."""
        return self if self.record_start is not None else super().continue_runs(radius)

    def simulate(self, param_sets):
        """As :meth:`_ClosedLoopTerm.simulate`; for a record that settles, each run is then
        started again with its size corrected so that its own first piece has the record's rms.

        One start size for every parameter set makes the approach's imprint on the window depend
        on how far each set's cycle is from that start: coverage draw 15 with a shared start put
        its dead zone and friction offset just outside intervals 0.6 % wide (rank 0.01), and
        draw 12's chain did not converge in 1500 steps. Matched per set, every run begins its
        approach from the record's first size, as the record did.
        """
        delta, ok = super().simulate(param_sets)
        ws = self.simulator.warm_start
        if self.record_start is None or ws is None:
            return delta, ok
        target, _, piece = self.record_start
        first = self.simulator.t <= piece
        redo, starts = [], []
        for i in np.flatnonzero(ok):
            rms = float(np.std(delta[i, first]))
            if rms > 0 and abs(rms / target - 1.0) > 1e-3:
                redo.append(i)
                starts.append(dataclasses.replace(ws, rms_target=ws.rms_target * target / rms))
        if redo:
            again, ok_again = self.simulator.run([param_sets[i] for i in redo], starts=starts)
            delta[redo], ok[redo] = again, ok_again
        return delta, ok

    def _factor(self, cov):
        self.cov_hat = cov
        chol = np.linalg.cholesky(cov)
        self._whiten = np.linalg.inv(chol)  # applied without BLAS in loglike
        self._logdet = 2.0 * float(np.sum(np.log(np.diag(chol))))

    def setup(self, start_params, warm_start=True):
        """The simulator, and the solver's own error in the covariance (:meth:`solver_variance`)."""
        super().setup(start_params, warm_start)
        self.solver_var = self.solver_variance(start_params, warm_start)
        self._refactor()
        return self

    def _refactor(self):
        self._factor(self._data_cov + np.diag(self.solver_var + self.transient_var))

    def set_transient_variance(self, value):
        """Set :attr:`transient_var` (from :meth:`transient_variance`, or a checkpoint)."""
        self.transient_var = np.asarray(value, dtype=float).reshape(len(self.features))
        self._refactor()

    def transient_variance(self, param_sets):
        """Mean squared change of the simulated features from the window after the transient
        to the next one, over ``param_sets`` (the walkers' starting points).

        A run starts on the reference cycle, not on its own; where the cycle attracts slowly, or
        is not periodic, the window's features still depend on that start. A drawn truth
        (coverage draw 20: dead zone on the velocity signal with a friction offset, settling time
        ~5 s), started from a cycle 30 % off in the delay, changed its log-likelihood by 155 nats
        between transients of 20 and 60 s (``tests/test_calibration_features.py``), and a sampler
        read the start's imprint as information: the dead zone / friction offset ridge's mass sat
        40 % below the truth. The change to the next window measures that imprint (and a
        wander of the model's own cycle, which the data's pieces may not show); its square is
        added to the features' variance like the solver's error. Zero for a cycle that has
        settled within the transient, and for a record that settles (:meth:`_record_start`).
        """
        if self.record_start is not None:
            return np.zeros(len(self.features))
        span = float(self.tau[-1])
        sim = BatchSimulator(self.experiment, self.sim_t_end + span, self.simulator.dt,
                             rate=self.simulator.rate, warm_start=self.warm_start)
        delta, ok = sim.run(param_sets)
        t = sim.t
        first = (t >= self.transient) & (t <= self.transient + span)
        second = (t >= self.transient + span) & (t <= self.transient + 2 * span)
        changes = []
        for i in np.flatnonzero(ok):
            a = cycle_features(t[first], delta[i, first], self.features)
            b = cycle_features(t[second], delta[i, second], self.features)
            if a is not None and b is not None:
                changes.append(np.asarray(a) - np.asarray(b))
        if not changes:
            return np.zeros(len(self.features))
        return np.mean(np.square(changes), axis=0)

    def solver_variance(self, params, warm_start=True):
        """The solver's error in the simulated features at ``params``: sets :attr:`solver_bias`
        (the first-order Richardson correction, ``SOLVER_ERROR_FACTOR`` times the change when the
        step is halved) and returns the squared change, the correction's own uncertainty.

        With a dead zone, a backlash or a held controller RK4 converges at first order near each
        switching event, and over a 10-40 s record the features are known to a precision the
        step's error can exceed by tens of sd (a drawn truth at dt = 5e-4 missed its own data's
        H1 by 61 sd; at 2.5e-4 the features moved by about as much). The error is one-signed and
        alike across a design's records, so the parameters can absorb it if it is only counted as
        variance: coverage draw 16 (three limit cycles, noise 1.9e-5 rad) had H1 2.3, 3.9 and 1.1
        sd low at the truth at 5e-4 s; corrected, 0.14-0.32 sd from a 5e-5 s simulation's (that
        draw's posterior, whose dead zone sits 5 % below the truth, did not move: its open-loop
        square decides it). Zeros when the halved step does not fit the grid.
        """
        self.solver_bias = np.zeros(len(self.features))
        pair = _step_doubling(self, self.model_features, params, warm_start)
        if pair is None:
            return np.zeros(len(self.features))
        change = pair[1] - pair[0]
        ok = np.isfinite(change)
        self.solver_bias = np.where(ok, SOLVER_ERROR_FACTOR * change, 0.0)
        return np.where(ok, change * change, 0.0)

    def refine_at(self, params):
        """The solver's correction and variance measured again at ``params`` (the maximum a
        posteriori; :meth:`solver_variance`)."""
        self.solver_var = self.solver_variance(params, self.warm_start is not None)
        self._refactor()
        return self

    def _wander_variance(self, n_segments, n_mc, rng):
        """``(wander, settling)`` variances of the window's features beyond sensor noise.

        The window is cut into ``n_segments`` pieces (fewer if a piece would hold under three
        periods). Wander: where the spread of the pieces' features is clearly (over 4x in
        variance) more than sensor noise makes it at that length (``n_mc`` noise draws spread over
        the pieces), the excess, divided by the number of pieces for the whole window.

        Settling: a cycle still growing or shrinking towards its limit (a drawn truth's amplitude
        took ~20 s to settle; its record's last 10 s sat 7 % under the settled H1, 5 sd of the
        noise-and-wander covariance, and the right model needed a 58x inflation) shows a trend
        across the pieces. Where the trend is clear (slope over ``SETTLING_SLOPE_SD`` times its
        noise-only standard error, and over ``SETTLING_R2`` of the pieces' spread), the settled
        value the model simulates is taken as unknown by ``SETTLING_WINDOWS`` times the drift
        over the window (sd), the gap left by a settling time of up to that many windows; the
        harmonics take the amplitude's relative drift (H1 or amplitude, when among the
        features).
        Both are zero when a piece holds under two periods.
        """
        zero = np.zeros(len(self.features))
        if "frequency" in self.features:
            omega = self.observed[self.features.index("frequency")]
            n_segments = min(n_segments, (self.tau[-1] - self.tau[0]) * omega / (2 * math.pi) // 3)
        n_segments = int(n_segments)
        if n_segments < 2:
            return zero, zero
        edges = np.linspace(self.tau[0], self.tau[-1], n_segments + 1)
        rows, noise = [], []
        per_piece = max(2, int(n_mc) // n_segments)
        for lo, hi in zip(edges[:-1], edges[1:]):
            sel = (self.tau >= lo) & (self.tau <= hi)
            tau, d = self.tau[sel], self.data[sel]
            try:
                f = self._data_features_at(tau, d)
                draws = [self._data_features_at(tau, d + self.sigma_hat * rng.standard_normal(d.size))
                         for _ in range(per_piece)]
            except InsufficientPeriodsError:
                return zero, zero
            rows.append(f)
            noise.append(np.var(draws, axis=0, ddof=1))
        rows = np.asarray(rows)
        seg_var = np.var(rows, axis=0, ddof=1)
        noise_var = np.mean(noise, axis=0)
        wander = np.where(seg_var > 4.0 * noise_var, (seg_var - noise_var) / len(rows), 0.0)
        settling = zero
        if len(rows) >= 3:
            c = 0.5 * (edges[:-1] + edges[1:])
            c = c - c.mean()
            sxx = float(np.sum(c * c))
            slope = (c @ (rows - rows.mean(axis=0))) / sxx
            explained = slope**2 * sxx / np.maximum((len(rows) - 1) * seg_var, 1e-300)
            clear = ((np.abs(slope) > SETTLING_SLOPE_SD * np.sqrt(noise_var / sxx))
                     & (explained > SETTLING_R2))
            drift = slope * (self.tau[-1] - self.tau[0])
            # a cycle whose size is settling moves the frequency too, even where its own trend
            # is too small to pass the test (draw 2: 0.07 % over the record, the settled
            # frequency 12 noise sd beyond the record's)
            sizes = [i for i, n in enumerate(self.features) if n in ("H1", "amplitude")]
            growing = bool(clear[sizes[0]]) if sizes else False
            settling = np.where(clear | growing, (SETTLING_WINDOWS * drift) ** 2, 0.0)
            # the harmonics move with the amplitude, but over a few periods their estimates
            # scatter by more than their slow drift (the drawn truth's H3: 2.63, 2.58, 2.59, 2.61
            # e-4, missing its settled 2.53 by 3 %) and a wander can look like a trend (M000's
            # B: H7 "drifted" by 3x its size): the amplitude's relative drift stands for them
            if sizes:
                i = sizes[0]
                relative = abs(drift[i]) / max(abs(self.observed[i]), 1e-300) if clear[i] else 0.0
                harmonic = np.array([n != "frequency" for n in self.features])
                spread = (SETTLING_WINDOWS * relative * self.observed) ** 2
                settling = np.where(harmonic, spread, settling)
        return wander, settling

    def _data_features(self, d):
        return self._data_features_at(self.tau, d)

    def _data_features_at(self, tau, d):
        f = limit_cycle_features(tau, d, n_harmonics=max(
            [int(n[1:]) for n in self.features if n.startswith("H")] or [1]))
        out = []
        for n in self.features:
            if n == "frequency":
                out.append(f.frequency)
            elif n == "amplitude":
                out.append(f.amplitude)
            else:
                out.append(f.harmonics[int(n[1:]) - 1])
        return np.asarray(out)

    def model_features(self, param_sets):
        delta, ok = self.simulate(param_sets)
        t = self.simulator.t
        sel = (t >= self.transient) & (t <= self.transient + self.tau[-1])
        out = np.full((len(param_sets), len(self.features)), np.nan)
        for i in np.flatnonzero(ok):
            m = delta[i, sel]
            if 0.5 * (np.max(m) - np.min(m)) < MIN_AMPLITUDE_RATIO * self.amplitude:
                continue
            f = cycle_features(t[sel], m, self.features)
            if f is not None:
                out[i] = f
        return out

    def whitened_residuals(self, param_sets, sigma):
        """``(n_sets, k)`` feature residuals in units of their sd at noise ``sigma`` (one per
        set), without the discrepancy inflation; NaN rows for invalid runs."""
        r = self.observed[None, :] - (self.model_features(param_sets) + self.solver_bias[None, :])
        scale = self._noise_scale(sigma)
        return np.sum(self._whiten[None, :, :] * r[:, None, :], axis=2) / scale[:, None]

    def _noise_scale(self, sigma):
        sigma = np.asarray(sigma, dtype=float)
        return sigma / self.sigma_hat if self.noise_from_sigma else np.ones_like(sigma)

    def discrepancy(self, params, sigma) -> float:
        """:func:`features_inflation` at ``params``."""
        return features_inflation(self.whitened_residuals([params], np.array([sigma]))[0])

    def loglike(self, param_sets, sigma, pointwise=False):
        scale = self._noise_scale(sigma)
        z = self.whitened_residuals(param_sets, sigma)
        k = len(self.features)
        ll = tempered(-0.5 * z**2 - np.log(scale)[:, None] - 0.5 * _LOG_2PI - 0.5 * self._logdet / k,
                      self.inflation)
        ll = np.where(np.isfinite(ll), ll, -np.inf)
        return ll if pointwise else ll.sum(axis=1)

    def describe(self):
        d = super().describe()
        d.update({"features": list(self.features), "observed": self.observed.tolist(),
                  "sd": np.sqrt(np.diag(self.cov_hat)).tolist(),
                  "wander_sd": np.sqrt(self.wander_var).tolist(),
                  "settling_sd": np.sqrt(self.settling_var).tolist(),
                  "solver_sd": np.sqrt(self.solver_var).tolist(),
                  "solver_bias": self.solver_bias.tolist(),
                  "transient_sd": np.sqrt(self.transient_var).tolist(),
                  "record_start": (None if self.record_start is None else
                                   {"rms": self.record_start[0], "seconds": self.record_start[1],
                                    "start_rms": self.start_rms})})
        return d


class OpenLoopTerm(_WaveformSolverError):
    """Output error of an open-loop recording, simulated from rest with the recorded command.

    The sensor's constant offset is profiled out of the residuals (their mean removed), as a
    measured record carries one (HWIL: ~1.5e-4 rad). A piecewise-constant command known only as
    samples (a square wave, a step) has an edge timing the samples leave open within up to a
    sample; it is integrated out under a uniform prior (:class:`.edge_timing.EdgeTiming`), so
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
        #: simulated edges on the step grid, then shifted (:mod:`.edge_timing`); cleared by
        #: :meth:`setup` when the response does not settle between edges
        self.edges_on_grid = True
        self.edge_loads_ = None
        self.edge_load = 0.0  # the chi-square of the edges' placement at the present step
        #: the timing the edges are simulated at when off the grid (None: the centre)
        self.edge_theta = None
        self._time_edges(self.dt)
        self.n = self.tau.size
        self.sigma_hat = estimate_noise(self.data)
        self.data_rate = float(recording.sample_rate)
        self.inflation = 1.0  # model-discrepancy factor (tempering; Calibration sets it at the MAP)
        self.warm_start = None
        self.simulator = None

    offset_profiled = True

    def _time_edges(self, dt):
        """The edge timing and the simulated experiment, edges on the grid of step ``dt``."""
        from models.edge_timing import edge_timing_for

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
        cannot see it (coverage draw 16's 200 Hz square at its truth: 40 at 5e-4 s, unseen)."""
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
            # timing is not counted (README, "Known limits")
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
        the way. At the centre alone a 200 Hz square's edges fall on the grid, where both ways
        are one simulation: coverage draw 18 (band-pass loop, a 2.56 Hz square at 200 Hz, noise
        2.2e-5 rad) had both loads 0.76 there, while the grid's response shifted 2.4 ms to the
        record's timing sat 2.5e-5 rad rms from the exact edges' (chi-square 2,900 at the
        truth; 249 against 5.7 for its own edges), its right model's discrepancy factor 6.1 and
        its dead zone and delay outside intervals 0.2 % wide.
        """
        from models.edge_timing import EdgeTiming

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


def make_term(recording, likelihood, window, transient, dt, name=None, features=DEFAULT_FEATURES,
              rng=None):
    """The likelihood term of one recording (open-loop recordings always use the output error)."""
    if likelihood not in LIKELIHOODS:
        raise ValueError(f"unknown likelihood {likelihood!r}; choose one of {', '.join(LIKELIHOODS)}")
    if recording.kind == "open":
        return OpenLoopTerm(recording, window, transient, dt, name=name)
    if likelihood == "features":
        return FeatureTerm(recording, window, transient, dt, name=name, features=features, rng=rng)
    return WaveformTerm(recording, window, transient, dt, name=name)
