"""The weak-SINDy estimator of the actuator structure, with its threshold and delay scan.

An sklearn-style estimator (``__init__`` stores arguments, ``fit`` validates and returns
``self``, learned attributes end in ``_``). For every structure form
(:mod:`tvcid.discovery.sindy.forms`) it

1. builds the weak system of the recordings (:mod:`tvcid.discovery.sindy.weak`);
2. scans the parameters that enter nonlinearly (dead zone ``z``, backlash ``r``, delay ``Td``, ...)
   coarse-then-fine on the profile residual, the linear coefficients solved at every point by
   bias-compensated normal equations when the sensor noise level is given;
3. decides by an information criterion whether the backlash and the dead zone are present;
4. hands the weak system at the chosen thresholds to a pysindy optimizer (``STLSQ`` by default;
   ``SR3``, ``EnsembleOptimizer`` or any ``pysindy.optimizers.BaseOptimizer`` work) and repeats the
   fit on bootstrap resamples of the test functions for per-term inclusion probabilities.
"""
from __future__ import annotations

import copy
import math
import time
import warnings

import numpy as np
import pysindy as ps
from scipy.optimize import minimize
from sklearn.base import BaseEstimator

from tvcid.models.cycle_reading import cycle_crossings
from tvcid.models.recording import load_recordings

from .candidates import Candidate
from .forms import MOVING_FRACTION, TARGET, form_by_name
from .simulation import score_on_recordings
from .threshold_scan import ThresholdScan
from .weak import BumpTestFunctions, prepare_signals

__all__ = ["WeakSINDyActuator", "DEFAULT_FORMS"]

#: Forms fitted by default: the papers' placements.
DEFAULT_FORMS = (
    "dead_zone_on_error",
    "dead_zone_on_velocity",
    "dead_zone_on_velocity_delay_in_loop",
    "dead_zone_on_velocity_bandpass",
)


#: Fine-quadrature step (s) used while scanning; the final refinement uses ``fine_step``.
SCAN_FINE_STEP = 2e-4
#: Longest stretch (s) of each recording simulated in the velocity forms' simulation stage.
SIMULATED_SPAN = 8.0
#: Simulation-stage residual of a run that diverged or lost its cycle.
FAILED_SIMULATION = 1e6
#: STLSQ threshold on unit-norm columns, the target scaled by the largest term's contribution: a
#: term contributing less than 1 % of the largest one is dropped.
DEFAULT_THRESHOLD = 0.01


class WeakSINDyActuator(ThresholdScan, BaseEstimator):
    """Weak-form SINDy of the actuator with a threshold and delay scan.

    Parameters
    ----------
    forms : sequence of str or StructureForm
        Structure forms to fit (default :data:`DEFAULT_FORMS`).
    optimizer : pysindy optimizer or None
        Sparse regression handed the weak system (default ``ps.STLSQ(threshold=0.01)``); it sees
        unit-norm columns and a target scaled so that each coefficient is the term's contribution
        over the largest term's, so its threshold is a fraction of the dominant term.
    noise : float or None
        Sensor noise rms (rad) of ``delta``; enables the bias-compensated normal equations.
    test_functions : BumpTestFunctions or None
        Default: half width 45 ms, power 6, half overlap.
    thresholds : dict or None
        Fix some nonlinear parameters instead of scanning them, e.g.
        ``{"dead_zone": 1.2e-3, "backlash": 2.182e-4, "delay": 7e-3}``.
    feedback_gain : float
        ``K`` in the dead-zone-on-error forms (paper 002 has K = 1); velocity forms fit it.
    max_delay : float
        Upper end (s) of the delay scan.
    criterion : {"bic", "aic"}
        Information criterion deciding whether backlash and dead zone are present.
    n_bootstrap : int
        Bootstrap resamples of the test functions for the inclusion probabilities.
    seed : int
        Seed of the ``numpy.random.Generator`` drawing every bootstrap.
    smoothing : float
        Savitzky-Golay window (s) of the smoothed ``delta``.
    fine_step : float
        Step (s) of the fine quadrature of terms built from the command.

    Attributes
    ----------
    candidates_ : list of Candidate
        One proposal per form, best (lowest criterion) first.
    recordings_ : list of Recording
    n_rows_ : int
        Test functions (weak equations) over all recordings.
    fit_time_ : float
        Wall time (s) of :meth:`fit`.
    scan_ : dict
        Per form, the profile points evaluated ``(thresholds, residual)``.
    skipped_ : dict
        Forms the data could not support (e.g. too few test functions in motion), with the reason.
    """

    def __init__(
        self,
        forms=DEFAULT_FORMS,
        optimizer=None,
        noise=None,
        test_functions=None,
        thresholds=None,
        feedback_gain=1.0,
        max_delay=0.02,
        criterion="bic",
        n_bootstrap=30,
        seed=0,
        smoothing=0.008,
        fine_step=5e-5,
    ):
        self.forms = forms
        self.optimizer = optimizer
        self.noise = noise
        self.test_functions = test_functions
        self.thresholds = thresholds
        self.feedback_gain = feedback_gain
        self.max_delay = max_delay
        self.criterion = criterion
        self.n_bootstrap = n_bootstrap
        self.seed = seed
        self.smoothing = smoothing
        self.fine_step = fine_step

    # -- validation ----------------------------------------------------------------------------
    def _validate(self):
        if self.noise is not None and not (math.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"noise must be a finite rms >= 0 in rad (got {self.noise!r})")
        if self.criterion not in ("bic", "aic"):
            raise ValueError(f"criterion must be 'bic' or 'aic' (got {self.criterion!r})")
        if not (math.isfinite(self.max_delay) and self.max_delay >= 0):
            raise ValueError(f"max_delay must be >= 0 (got {self.max_delay!r})")
        if int(self.n_bootstrap) < 0:
            raise ValueError(f"n_bootstrap must be >= 0 (got {self.n_bootstrap!r})")
        forms = [form_by_name(f) for f in (self.forms or ())]
        if not forms:
            raise ValueError("no structure form to fit")
        return forms

    def fit(self, recordings):
        """Fit every form to the recordings (paths or :class:`Recording`); returns ``self``.

        Raises
        ------
        ValueError
            For an unknown form, a bad argument, a non-uniform or too short recording (the message
            names the file).
        """
        start = time.perf_counter()
        forms = self._validate()
        self.recordings_ = load_recordings(recordings)
        for rec in self.recordings_:  # a regression on an output that never moves has no scale
            if not np.ptp(rec.delta) > 0:
                raise ValueError(f"{rec.path or 'recording'}: column 'delta' is constant; SINDy "
                                 "needs a recording in which the actuator moves")
            if rec.kind == "closed":  # the ranking compares cycles: two periods at least
                ups = cycle_crossings(rec.t, rec.delta)
                if ups.size < 3:
                    raise ValueError(
                        f"{rec.path or 'recording'}: the closed-loop record of "
                        f"{rec.t[-1] - rec.t[0]:.4g} s holds {max(ups.size - 1, 0)} whole period(s) "
                        "of the cycle; SINDy and its ranking need at least two")
        tf = self.test_functions or BumpTestFunctions(0.045)
        fixed = dict(self.thresholds or {})
        margin = max(self.max_delay, fixed.get("delay", 0.0)) + 0.005
        self._prepared_by_step = {}
        for step in (max(self.fine_step, SCAN_FINE_STEP), self.fine_step):
            prepared = []
            for rec in self.recordings_:
                try:
                    prepared.append(
                        prepare_signals(
                            rec.t, rec.u, rec.delta, tf, delay_margin=margin,
                            smoothing=self.smoothing, fine_step=step, kind=rec.kind,
                            meta=rec.meta, noise=self.noise,
                        )
                    )
                except ValueError as exc:
                    raise type(exc)(f"{rec.path or 'recording'}: {exc}") from None
            self._prepared_by_step[step] = prepared
        self._prepared = self._prepared_by_step[self.fine_step]
        self.n_rows_ = sum(p.n_rows for p in self._prepared)
        self._overlap = tf.overlap
        # one speed floor for all recordings: a slow test must not lower it below the friction
        self._speed_floor = MOVING_FRACTION * max(
            float(np.percentile(p.speed, 99)) for p in self._prepared)
        self._rng = np.random.default_rng(self.seed)
        self.scan_ = {}
        self.skipped_ = {}
        candidates = []
        for form in forms:
            try:
                candidates.append(self._fit_form(form, fixed))
            except ValueError as exc:
                if len(forms) == 1:
                    raise
                # one form that the data cannot support does not stop the others
                self.skipped_[form.name] = str(exc)
        if not candidates:
            raise ValueError("no structure form could be fitted: " + "; ".join(
                f"{name}: {why}" for name, why in self.skipped_.items()))
        self.candidates_ = sorted(candidates, key=lambda c: c.criterion)
        self.fit_time_ = time.perf_counter() - start
        return self

    # -- the weak system -------------------------------------------------------------------------
    def _system(self, form, thresholds, lifted=True, linear=None, caches=None):
        """Stacked target, columns, names, row mask and per-recording noise Gram matrices."""
        ys, xs, grams, rec_index = [], [], [], []
        names = None
        for i, prep in enumerate(self._prepared):
            cache = None if caches is None else caches[i]
            target, cols, weights = form.columns(prep, thresholds, lifted, linear, cache)
            names = list(cols)
            mask = form.row_mask(prep, self._speed_floor)
            ys.append(target[mask])
            xs.append(np.column_stack([cols[n] for n in names])[mask])
            rec_index.append(np.full(int(mask.sum()), i))
            w = np.column_stack([weights.get(n, np.zeros(prep.support)) for n in [TARGET] + names])
            sigma = self.noise or 0.0
            grams.append(sigma**2 * prep.dt**2 * (w.T @ w))
        y = np.concatenate(ys)
        if y.size < 8:
            raise ValueError(
                f"form {form.name}: only {y.size} test functions hold its equation (the velocity "
                "forms need stretches of motion longer than a test-function support)"
            )
        return y, np.vstack(xs), names, np.concatenate(rec_index), np.array(grams)

    @staticmethod
    def _solve(y, x, rec_index, grams, rows=None):
        """Bias-compensated least squares; returns coefficients, raw residual, compensated Gram."""
        if rows is not None:
            y, x, rec_index = y[rows], x[rows], rec_index[rows]
        counts = np.bincount(rec_index, minlength=len(grams)).astype(float)
        noise_gram = np.tensordot(counts, grams, axes=1)
        gram = x.T @ x - noise_gram[1:, 1:]
        rhs = x.T @ y - noise_gram[1:, 0]
        scale = np.sqrt(np.maximum(np.diag(x.T @ x), 1e-300))
        gs = gram / np.outer(scale, scale)
        try:
            coef = np.linalg.solve(gs + 1e-12 * np.eye(gs.shape[0]), rhs / scale) / scale
        except np.linalg.LinAlgError:
            coef = np.linalg.lstsq(x, y, rcond=None)[0]
        resid = float(np.sum((x @ coef - y) ** 2))
        self_resid = float(y @ y - noise_gram[0, 0] - 2.0 * coef @ rhs + coef @ gram @ coef)
        return coef, resid, gram, rhs, scale, self_resid

    def _criterion(self, resid, norm, n, k):
        # neighbouring test functions overlap, so n rows carry about n*(1 - overlap) independent
        # equations; counting all of them would favour every extra element
        n = max(n * (1.0 - self._overlap), 2.0)
        rel = max(resid / norm, 1e-300)
        penalty = math.log(n) if self.criterion == "bic" else 2.0
        return n * math.log(rel) + k * penalty

    # -- one form --------------------------------------------------------------------------------
    def _fit_form(self, form, fixed):
        final_prepared = self._prepared
        self._prepared = self._prepared_by_step[max(self.fine_step, SCAN_FINE_STEP)]
        caches = [{} for _ in self._prepared]
        best, _, values = self._scan(form, fixed, caches)
        alternatives = {"full": best}
        # sub-structures without an element, for the information criterion
        for element in ("backlash", "dead_zone"):
            if element in form.threshold_names() and element not in fixed and best[element] > 0:
                alt, _, more = self._scan(form, fixed, caches, {element: 0.0})
                alternatives[element] = alt
                values.update(more)
        self.scan_[form.name] = [(dict(k), v) for k, v in values.items()]
        # fine stage: the same profile with the fine quadrature, from the scan's optimum
        self._prepared = final_prepared
        caches = [{} for _ in self._prepared]
        if self._prepared is not self._prepared_by_step.get(SCAN_FINE_STEP):
            for key, thr in alternatives.items():
                alternatives[key] = self._refine(form, thr, fixed, caches)

        def design(thr):
            full = dict(thr)
            full.setdefault("feedback_gain", self.feedback_gain)
            return self._system(form, full, caches=caches)

        designs = {key: design(thr) for key, thr in alternatives.items()}
        n = designs["full"][0].size

        def n_params(thr, n_cols):
            return n_cols + sum(1 for k in form.threshold_names() if thr.get(k, 0) > 0)

        def ic_of(key, rows=None):
            y, x, _, idx, grams = designs[key]
            resid = self._solve(y, x, idx, grams, rows)[1]
            yy = y if rows is None else y[rows]
            return self._criterion(resid, float(yy @ yy), yy.size,
                                   n_params(alternatives[key], x.shape[1]))

        ics = {key: ic_of(key) for key in designs}
        chosen_key = min(ics, key=ics.get)
        thresholds = dict(alternatives[chosen_key])
        # inclusion of the threshold elements from bootstrap resamples of the test functions
        boot_rows = [self._rng.integers(0, n, n) for _ in range(int(self.n_bootstrap))]
        element_inclusion = {}
        for element in ("backlash", "dead_zone"):
            if element not in form.threshold_names():
                continue
            if element in fixed:
                element_inclusion[element] = float(fixed[element] > 0)
            elif element not in designs:
                element_inclusion[element] = float(thresholds.get(element, 0) > 0)
            else:
                wins = [ic_of("full", rows) < ic_of(element, rows) for rows in boot_rows]
                element_inclusion[element] = float(np.mean(wins)) if wins else float(
                    chosen_key == "full")
        if form.simulated_threshold_names():
            thresholds = self._simulation_stage(form, thresholds, fixed, caches)
            element_inclusion["backlash"] = float(thresholds["backlash"] > 0)
            element_inclusion["dead_zone"] = float(thresholds["dead_zone"] > 0)
        # linear block from the lifted fit, then the sparse regression on the final columns
        full = dict(thresholds)
        full.setdefault("feedback_gain", self.feedback_gain)
        y, x, names, idx, grams = self._system(form, full, caches=caches)
        coef = self._solve(y, x, idx, grams)[0]
        lifted = dict(zip(names, coef))
        linear = (-lifted["delta''"], -lifted["delta'"])
        full = dict(thresholds)
        full.setdefault("feedback_gain", self.feedback_gain)
        y, x, names, idx, grams = self._system(form, full, lifted=False, linear=linear,
                                               caches=caches)
        coef, support = self._sparse(y, x, idx, grams)
        inclusion = {name: 0.0 for name in names}
        if boot_rows:
            hits = np.zeros(len(names))
            for rows in boot_rows:
                hits += self._sparse(y, x, idx, grams, rows)[1]
            inclusion = dict(zip(names, (hits / len(boot_rows)).tolist()))
        inclusion.update(element_inclusion)
        resid = float(np.sum((x @ coef - y) ** 2))
        k = int(support.sum()) + sum(1 for n in form.threshold_names() if thresholds.get(n, 0) > 0)
        terms = {name: float(c) for name, c, s in zip(names, coef, support) if s}
        params = self._block_params(form, terms, thresholds)
        return Candidate(
            form=form.name,
            terms=terms,
            thresholds={k_: float(v) for k_, v in thresholds.items()},
            inclusion=inclusion,
            weak_residual=resid / float(y @ y),
            criterion=self._criterion(resid, float(y @ y), y.size, k),
            params=params,
        )

    # -- velocity forms: dead zone, friction offset, backlash and delay by simulation ----------
    def _velocity_block(self, form, thresholds, caches):
        """Weak least-squares block of a velocity form at a delay, with ``r = 0``.

        Returns the ``ActuatorParams`` fields except ``dead_zone``, ``backlash`` and
        ``friction_offset``, and ``c_eff = z - off - K1*K*r/K3`` (what the moving test functions
        see of the three).
        """
        full = {**thresholds, "backlash": 0.0}
        y, x, names, idx, grams = self._system(form, full, caches=caches)
        lifted = dict(zip(names, self._solve(y, x, idx, grams)[0]))
        linear = (-lifted["delta''"], -lifted["delta'"])
        y, x, names, idx, grams = self._system(form, full, lifted=False, linear=linear,
                                               caches=caches)
        c = dict(zip(names, self._solve(y, x, idx, grams)[0]))
        k1 = c["u(t-Td)"]
        play = c.get("play_r(delta)(t-Td)", c.get("play_r(delta)", 0.0))
        block = {
            "gain": k1, "damping": -c["delta''"], "stiffness": -c["delta'"],
            "feedback_gain": -play / k1 if k1 else 0.0, "delay": float(thresholds["delay"]),
        }
        level = c.get("L[sat_1(G/s*BP(delta'))]", 0.0)
        if form.bandpass and level > 0:
            block["bandpass_saturation"] = level
            block["bandpass_gain"] = level * float(thresholds["bandpass_ratio"])
        return block, -c.get("L[sign(delta')]", 0.0)

    def _velocity_params(self, form, block, c_eff, dead_zone, backlash):
        from tvcid.models.hypotheses import ActuatorParams, DeadZonePosition, DelayPosition

        c = c_eff + block["gain"] * block["feedback_gain"] * backlash / block["stiffness"]
        return ActuatorParams(
            dead_zone=dead_zone, backlash=backlash, friction_offset=dead_zone - c,
            dead_zone_position=DeadZonePosition.VELOCITY,
            delay_position=(DelayPosition.BEFORE_INTEGRATOR if form.delay_inside_loop
                            else DelayPosition.OUTPUT),
            x0=0.5 * float(np.ptp(self.recordings_[0].delta)),
            **block,
        )

    def _simulation_stage(self, form, thresholds, fixed, caches):
        """Coarse grid then Nelder-Mead over ``(z, r, Td[, G])`` on simulations of the recordings.

        The block coefficients are re-fitted by weak least squares at each delay; the band-pass
        loop gain ``G`` is refined here too (the saturated loop's gain is barely seen by the weak
        residual, and a wrong one biases the split of z and off); the friction offset follows from
        the sign coefficient, ``off = z - c``.
        The residual is the mean squared simulation score over the recordings.
        """
        blocks = {}
        q0 = float(thresholds.get("bandpass_ratio", 0.0))

        def block_at(td, q=q0):
            key = (round(float(td), 7), round(float(q), 6))
            if key not in blocks:
                thr = {**thresholds, "delay": key[0]}
                if form.bandpass:
                    thr["bandpass_ratio"] = key[1]
                blocks[key] = self._velocity_block(form, thr, caches)
            return blocks[key]

        def param_sets(points):
            out, ok = [], []
            for z, r, td, q in points:
                block, c_eff = block_at(td)
                if form.bandpass and "bandpass_saturation" in block:
                    # the loop gain moves on simulations, the block stays that of the weak fit
                    block = {**block, "bandpass_gain": block["bandpass_saturation"] * q}
                try:
                    out.append(self._velocity_params(form, block, c_eff, z, r))
                    ok.append(True)
                except ValueError:
                    ok.append(False)
            return out, np.array(ok)

        def scores(points):
            sets, ok = param_sets(points)
            result = np.full(len(points), FAILED_SIMULATION)
            if sets:
                s, _ = score_on_recordings(sets, self.recordings_, max_time=SIMULATED_SPAN)
                # a diverged run or a lost cycle scores a large finite value (Nelder-Mead
                # compares differences of scores)
                result[ok] = np.minimum(np.mean(s**2, axis=1), FAILED_SIMULATION)
            return result

        d_span = max(float(np.ptp(p.delta)) for p in self._prepared)
        if "delay" in fixed:
            td0 = float(fixed["delay"])
        else:
            # the moving test functions hardly see the delay: scan it on simulations first
            r_mid = float(fixed.get("backlash", d_span * 0.003))
            probe = []
            for td in np.arange(0.0, self.max_delay + 1e-9, 1e-3):
                block, c_eff = block_at(td)
                c = c_eff + block["gain"] * block["feedback_gain"] * r_mid / block["stiffness"]
                probe.append((float(fixed.get("dead_zone", max(c, 1e-4) * 0.5)), r_mid, td, q0))
            td0 = probe[int(np.argmin(scores(probe)))][2]
        tds = ([td0] if "delay" in fixed else
               sorted({min(max(td0 + k * 2.5e-4, 0.0), self.max_delay) for k in (-2, -1, 0, 1, 2)}))
        rs = ([float(fixed["backlash"])] if "backlash" in fixed
              else [0.0] + [d_span * f for f in (0.0015, 0.003, 0.006)])
        points = []
        for td in tds:
            block, c_eff = block_at(td)
            for r in rs:
                c = c_eff + block["gain"] * block["feedback_gain"] * r / block["stiffness"]
                zs = ([float(fixed["dead_zone"])] if "dead_zone" in fixed
                      else [max(c, 1e-4) * f for f in (0.15, 0.35, 0.55, 0.75, 0.95)])
                points += [(z, r, td, q0) for z in zs]
        coarse = scores(points)
        best = points[int(np.argmin(coarse))]
        names = ("dead_zone", "backlash", "delay", "bandpass_ratio")
        free = [i for i, n in enumerate(names) if n not in fixed]
        free = [i for i in free if not (i != 2 and best[i] <= 0)]
        logs = (0, 1, 3)
        if free:
            def unpack(v):
                pt = list(best)
                for i, val in zip(free, v):
                    pt[i] = math.exp(val) if i in logs else min(max(val, 0.0), self.max_delay)
                return tuple(pt)

            x0 = [math.log(best[i]) if i in logs else best[i] for i in free]
            steps = [(0.5 if i == 3 else 0.15) if i in logs else 2.5e-4 for i in free]
            simplex = [x0] + [list(np.add(x0, np.eye(len(free))[k] * steps[k]))
                              for k in range(len(free))]
            best_score = float(coarse.min())
            for _ in range(2):  # one restart: Nelder-Mead's simplex collapses on ridges
                res = minimize(lambda v: float(scores([unpack(v)])[0]), x0, method="Nelder-Mead",
                               options={"initial_simplex": simplex, "xatol": 2e-3,
                                        "fatol": 1e-10, "maxfev": 40 * len(free)})
                if res.fun < best_score:
                    best, best_score = unpack(res.x), float(res.fun)
                x0 = list(res.x)
                simplex = [x0] + [list(np.add(x0, np.eye(len(free))[k] * steps[k]))
                                  for k in range(len(free))]
        z, r, td, q = best
        out = dict(thresholds)
        out.update(dead_zone=float(z), backlash=float(r), delay=float(td))
        if form.bandpass:
            out["bandpass_ratio"] = float(q)
        return out

    def _sparse(self, y, x, idx, grams, rows=None):
        """pysindy optimizer on the (bias-compensated) weak system; coefficients and support."""
        coef_ls, _, gram, rhs, scale, _ = self._solve(y, x, idx, grams, rows)
        yy = y if rows is None else y[rows]
        # Target scaled so that a coefficient is the term's contribution over the largest one's:
        # in a limit cycle the third derivative is a small remainder of large cancelling terms.
        ynorm = float(np.max(np.abs(coef_ls * scale))) or math.sqrt(float(yy @ yy)) or 1.0
        gs = gram / np.outer(scale, scale)
        hs = rhs / scale / ynorm
        try:
            chol = np.linalg.cholesky(gs + 1e-12 * np.eye(gs.shape[0]))
            a = chol.T
            b = np.linalg.solve(chol, hs)
        except np.linalg.LinAlgError:
            xx = x if rows is None else x[rows]
            a, b = xx / scale, yy / ynorm
        optimizer = copy.deepcopy(self.optimizer) if self.optimizer is not None else ps.STLSQ(
            threshold=DEFAULT_THRESHOLD, alpha=1e-6
        )
        with warnings.catch_warnings():
            # a resample in which every term falls below the threshold is a legitimate outcome
            warnings.filterwarnings("ignore", message="Sparsity parameter is too big")
            optimizer.fit(a, b)
        coef_scaled = np.ravel(np.asarray(optimizer.coef_))
        support = np.abs(coef_scaled) > 1e-12
        return coef_scaled * ynorm / scale, support

    def _block_params(self, form, terms, thresholds):
        """The ``ActuatorParams`` fields a fitted form stands for."""
        k2 = -terms.get("delta''", 0.0)
        k3 = -terms.get("delta'", 0.0)
        out = {
            "dead_zone_on": form.dead_zone_on,
            "delay_inside_loop": form.delay_inside_loop,
            "damping": k2,
            "stiffness": k3,
            "backlash": float(thresholds.get("backlash", 0.0)),
            "delay": float(thresholds.get("delay", 0.0)),
        }
        sign_term = terms.get("L[sign(delta')]", 0.0)
        if form.dead_zone_on == "error":
            out["gain"] = terms.get(form.term_names()[3], 0.0)
            out["feedback_gain"] = float(thresholds.get("feedback_gain", self.feedback_gain))
            out["dead_zone"] = float(thresholds.get("dead_zone", 0.0))
            out["friction_offset"] = sign_term
        else:
            k1 = terms.get("u(t-Td)", 0.0)
            play = terms.get("play_r(delta)(t-Td)", terms.get("play_r(delta)", 0.0))
            out["gain"] = k1
            out["feedback_gain"] = -play / k1 if k1 else 0.0
            # the sign coefficient is c = z - off; z comes from the simulation stage
            c = -sign_term
            out["dead_zone_minus_offset"] = c
            out["dead_zone"] = float(thresholds.get("dead_zone", max(c, 0.0)))
            out["friction_offset"] = out["dead_zone"] - c
        if form.bandpass:
            level = terms.get("L[sat_1(G/s*BP(delta'))]", 0.0)
            out["bandpass_saturation"] = level if level > 0 else math.inf
            out["bandpass_gain"] = level * float(thresholds["bandpass_ratio"]) if level > 0 else 0.0
        return out
