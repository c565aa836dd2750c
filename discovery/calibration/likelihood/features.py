"""The limit-cycle features likelihood of a closed-loop recording (:class:`FeatureTerm`).

The features are the cycle's frequency and the amplitudes of chosen harmonics (odd by default,
:data:`DEFAULT_FEATURES`), compared as a Gaussian. Their covariance is propagated from the sensor
noise by re-noising the recording (``n_mc`` seeded draws at the noise level estimated from it),
widened by the cycle's own wander and settling over the window, and scales as
``(sigma/sigma_hat)^2`` when ``sigma`` is sampled. Amplitude as ``(max-min)/2`` is available as
``"amplitude"`` but is biased upwards by the noise extremes; ``"H1"`` (first-harmonic amplitude) is
the unbiased amplitude and the default. The features are read off the record and off each
simulated cycle by :mod:`tvcid.models.cycle_reading` (:func:`~tvcid.models.cycle_reading.limit_cycle_features`,
:func:`~tvcid.models.cycle_reading.cycle_features`), and a record still settling is told by
:func:`~tvcid.models.cycle_settling.settling_gain`.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from tvcid.models.batch import CONTINUATION_RADIUS, BatchSimulator
from tvcid.models.cycle_reading import (
    InsufficientPeriodsError,
    cycle_features,
    limit_cycle_features,
)
from tvcid.models.cycle_settling import SETTLING_MIN_PIECES, settling_gain

from .base import _LOG_2PI, features_inflation, tempered
from .closed_loop import MIN_AMPLITUDE_RATIO, _ClosedLoopTerm
from .solver import SOLVER_ERROR_FACTOR, _step_doubling

__all__ = [
    "FeatureTerm",
    "DEFAULT_FEATURES",
    "IMPRINT_WINDOWS",
    "SETTLING_SLOPE_SD",
    "SETTLING_R2",
    "SETTLING_WINDOWS",
    "SETTLING_FIT_GAIN",
]

DEFAULT_FEATURES = ("frequency", "H1", "H3", "H5", "H7")
#: Windows of each run the start imprint compares (:meth:`FeatureTerm.transient_variance`): the
#: first against each later one.
IMPRINT_WINDOWS = 4


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
#: 12 pieces (a lower gain lets settled records whose pieces scatter beyond their noise count
#: as settling), from at least :data:`tvcid.models.cycle_settling.SETTLING_MIN_PIECES` pieces.
SETTLING_FIT_GAIN = 100.0


class FeatureTerm(_ClosedLoopTerm):
    """Gaussian likelihood of the limit-cycle features of one closed-loop recording.

    Covariance: the features' spread under the recording's sensor noise (Monte Carlo over
    ``n_mc`` noise draws), plus twice the cycle's own window-to-window wander measured on
    ``n_segments`` pieces of the window (zero for a periodic cycle), plus the uncertainty of the
    settled features when the cycle is still settling over the window (zero for a settled one),
    plus an optional relative ``floor``. The wander estimate is conservative
    (``tests/test_calibration_features.py``).
    """

    kind = "features"
    #: The covariance follows the sampled noise sd (scaled by ``sigma / sigma_hat``); ``False``
    #: keeps the record's own noise estimate (a record that fell back from the waveform: its 15
    #: numbers cannot estimate the noise).
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
        self._piece_simulator = None

    def _run_end(self) -> float:
        """Length (s) of a run: the transient and the window (features read nothing beyond)."""
        return self.transient + float(self.tau[-1]) + 2.0 / self.data_rate

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

        The record is cut, back from its end, into pieces as long as the window's (at least
        three periods); where their frequency or size (H1 or amplitude) follows an exponential
        approach (:func:`settling_gain` at least :data:`SETTLING_FIT_GAIN`), a run starts at the
        size of the record's first piece (sensor noise removed; the start's size is then matched
        at set-up, :meth:`_build_simulator`), as many seconds before the window as the record has
        before it, and approaches its cycle as the record does (:meth:`simulate`). Such runs do
        not continue each other (:meth:`continue_runs`) and carry no start imprint
        (:meth:`transient_variance`): the imprint is the record's. A run started at the window's
        size instead has settled by the window, which the record has not
        (``tests/test_calibration_features.py``).

        Returns ``(rms, seconds, piece)``, or ``None`` for a record that does not settle (runs
        start at the window's size).
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
        rng = np.random.default_rng(0)  # its own draws, apart from the term's noise draws
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
        """As :meth:`_ClosedLoopTerm.simulate`; for a record that settles, each run starts with
        its size corrected so that its own first piece has the record's rms.

        One start size for every parameter set would make the approach's imprint on the window
        depend on how far each set's cycle is from that start; matched per set, every run begins
        its approach from the record's first size, as the record did. The first piece alone is
        simulated to size the start, then the whole run once from the corrected start.
        """
        ws = self.simulator.warm_start
        if self.record_start is None or ws is None:
            return super().simulate(param_sets)
        target, _, piece = self.record_start
        if self._piece_simulator is None or self._piece_simulator.warm_start is not ws:
            self._piece_simulator = BatchSimulator(self.experiment, piece + 2 * self.simulator.dt,
                                                   self.simulator.dt, rate=self.simulator.rate,
                                                   warm_start=ws)
        short = self._piece_simulator
        first_delta, ok = short.run(param_sets)
        first = short.t <= piece
        starts = []
        for i in range(len(param_sets)):
            rms = float(np.std(first_delta[i, first])) if ok[i] else 0.0
            starts.append(dataclasses.replace(ws, rms_target=ws.rms_target * target / rms)
                          if rms > 0 and abs(rms / target - 1.0) > 1e-3 else None)
        return self.simulator.run(param_sets, starts=starts)

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
        to each of the next :data:`IMPRINT_WINDOWS` - 1 windows, over ``param_sets`` (the
        walkers' starting points).

        A run starts on the reference cycle, not on its own; where the cycle attracts slowly, or is
        not periodic, the window's features still depend on that start, and a sampler that
        ignores this reads the start's imprint as information. The change to later windows
        measures that imprint, and how much a window's features depend on where the window falls
        on the model's own cycle, which the data's pieces may not show (a period-2 cycle's
        features depend on the parity of the periods in the window); against several windows the
        recorded window and the simulated one are both draws of that spread
        (``tests/test_calibration_features.py``). Its square is added to the features' variance like
        the solver's error. Zero for a cycle that has settled within the transient, and for a record
        that settles (:meth:`_record_start`).
        """
        if self.record_start is not None:
            return np.zeros(len(self.features))
        span = float(self.tau[-1])
        sim = BatchSimulator(self.experiment, self.sim_t_end + (IMPRINT_WINDOWS - 1) * span,
                             self.simulator.dt, rate=self.simulator.rate, warm_start=self.warm_start)
        delta, ok = sim.run(param_sets)
        t = sim.t
        windows = [(t >= self.transient + k * span) & (t <= self.transient + (k + 1) * span)
                   for k in range(IMPRINT_WINDOWS)]
        changes = []
        for i in np.flatnonzero(ok):
            first = cycle_features(t[windows[0]], delta[i, windows[0]], self.features)
            if first is None:
                continue
            for w in windows[1:]:
                later = cycle_features(t[w], delta[i, w], self.features)
                if later is not None:
                    changes.append(np.asarray(first) - np.asarray(later))
        if not changes:
            return np.zeros(len(self.features))
        return np.mean(np.square(changes), axis=0)

    def solver_variance(self, params, warm_start=True):
        """The solver's error in the simulated features at ``params``: sets :attr:`solver_bias`
        (the first-order Richardson correction, ``SOLVER_ERROR_FACTOR`` times the change when the
        step is halved) and returns the squared change, the correction's own uncertainty.

        With a dead zone, a backlash or a held controller RK4 converges at first order near each
        switching event, and over a 10-40 s record the features are known to a precision the
        step's error can exceed by tens of sd. The error is one-signed and alike across a
        design's records, so the parameters would absorb it if it were only counted as variance;
        hence the correction. Zeros when the halved step does not fit the grid.
        """
        return self.solver_correction([params], warm_start)

    def solver_correction(self, param_sets, warm_start=True):
        """:meth:`solver_variance` over ``param_sets``: the correction is ``SOLVER_ERROR_FACTOR``
        times the median change, its variance the mean squared change; sets :attr:`solver_bias`
        and returns the variance.

        The change is not smooth in the parameters: near a held controller's or a dead zone's
        switching events it jumps from point to point, so that one point can be a special one
        where halving the step moves a feature many times more (or less) than at its neighbours
        (``tests/test_calibration_features.py``). A correction taken at one such point shifts every
        draw's likelihood by that much; the median is the systematic part. The mean square is what a
        one-point variance is on average, and it covers the points where the change is far from
        the median.
        """
        self.solver_bias = np.zeros(len(self.features))
        change = []
        for params in param_sets:  # each with the half step's warm start at its own point
            pair = _step_doubling(self, self.model_features, params, warm_start)
            if pair is None:
                return np.zeros(len(self.features))
            change.append(pair[1] - pair[0])
        change = np.asarray(change, dtype=float)
        ok = np.isfinite(change).any(axis=0)
        filled = np.where(np.isfinite(change), change, np.nan)
        with np.errstate(all="ignore"):
            median = np.array([np.nanmedian(c) if k else 0.0 for c, k in zip(filled.T, ok)])
            square = np.array([np.nanmean(c * c) if k else 0.0 for c, k in zip(filled.T, ok)])
        self.solver_bias = np.where(ok, SOLVER_ERROR_FACTOR * median, 0.0)
        return np.where(ok, square, 0.0)

    def correct_over(self, param_sets, warm_start=True):
        """:meth:`solver_correction` over ``param_sets``, set as the term's; returns ``self``."""
        var = self.solver_correction(param_sets, warm_start)
        return self.set_solver_correction(self.solver_bias, var)

    def set_solver_correction(self, bias, var):
        """Set :attr:`solver_bias` and :attr:`solver_var` (from :meth:`solver_correction`, or a
        checkpoint)."""
        self.solver_bias = np.asarray(bias, dtype=float).reshape(len(self.features))
        self.solver_var = np.asarray(var, dtype=float).reshape(len(self.features))
        self._refactor()
        return self

    def refine_at(self, params):
        """The solver's correction and variance measured again at ``params`` (the maximum a
        posteriori; :meth:`solver_variance`)."""
        return self.correct_over([params], self.warm_start is not None)

    def _wander_variance(self, n_segments, n_mc, rng):
        """``(wander, settling)`` variances of the window's features beyond sensor noise.

        The window is cut into ``n_segments`` pieces (fewer if a piece would hold under three
        periods). Wander: where the spread of the pieces' features is clearly (over 4x in
        variance) more than sensor noise makes it at that length (``n_mc`` noise draws spread over
        the pieces), the excess, divided by the number of pieces for the whole window.

        Settling: a cycle still growing or shrinking towards its limit (which would cost the right
        model a large discrepancy inflation unless the settled value is taken as unknown) shows a
        trend across the pieces. Where the trend is clear (slope over ``SETTLING_SLOPE_SD`` times
        its noise-only standard error, and over ``SETTLING_R2`` of the pieces' spread), the settled
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
            # is too small to pass the test
            sizes = [i for i, n in enumerate(self.features) if n in ("H1", "amplitude")]
            growing = bool(clear[sizes[0]]) if sizes else False
            settling = np.where(clear | growing, (SETTLING_WINDOWS * drift) ** 2, 0.0)
            # the harmonics move with the amplitude, but over a few periods their estimates
            # scatter by more than their slow drift and a wander can look like a trend: the
            # amplitude's relative drift stands for them
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

    def _read(self, t, m):
        """Features of one simulated stretch; ``None`` under the recorded cycle's size (not
        oscillating) or under two whole periods."""
        if 0.5 * (np.max(m) - np.min(m)) < MIN_AMPLITUDE_RATIO * self.amplitude:
            return None
        return cycle_features(t, m, self.features)

    def model_features(self, param_sets):
        """Each run's features over the window; NaN rows for runs that fail or do not
        oscillate."""
        delta, ok = self.simulate(param_sets)
        t = self.simulator.t
        sel = (t >= self.transient) & (t <= self.transient + self.tau[-1])
        out = np.full((len(param_sets), len(self.features)), np.nan)
        for i in np.flatnonzero(ok):
            f = self._read(t[sel], delta[i, sel])
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
