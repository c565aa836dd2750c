"""The threshold scan of the weak-SINDy estimator: the parameters that enter nonlinearly (dead
zone ``z``, backlash ``r``, delay ``Td``, band-pass ratio) scanned coarse-then-fine on the profile
residual, the linear coefficients solved at every point (:class:`.estimator.WeakSINDyActuator`
mixes this in)."""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize

__all__ = ["ThresholdScan"]

_LOG_THRESHOLDS = ("dead_zone", "backlash", "bandpass_ratio")
#: Profile residual of the dead-zone-on-error forms: the bias-compensated one (the misfit with
#: the expected noise energy removed). The velocity forms keep only the moving test functions and
#: use the raw residual, whose compensated version turns negative at near-collinear points.
PROFILE_COMPENSATED = True
#: Profile penalty of thresholds whose fit is not a physical actuator (non-positive gains).
INADMISSIBLE = 10.0


class ThresholdScan:
    """Grid, profile, scan and Nelder-Mead refinement of the nonlinear thresholds."""

    def _grid(self, form, fixed):
        u_span = max(float(np.max(np.abs(p.u))) for p in self._prepared) or 1.0
        d_span = max(float(np.ptp(p.delta)) for p in self._prepared) or 1.0
        dt = min(p.dt for p in self._prepared)
        grids = {
            "dead_zone": np.concatenate([[0.0], u_span * np.geomspace(0.01, 0.5, 6)]),
            "backlash": np.concatenate([[0.0], d_span * np.geomspace(0.002, 0.1, 5)]),
            "delay": np.arange(0.0, self.max_delay + 0.5 * dt, max(dt, 0.003)),
            "bandpass_ratio": np.geomspace(10.0, 1e5, 9),
        }
        names = form.threshold_names()
        return {n: (np.array([fixed[n]]) if n in fixed else grids[n]) for n in names}

    def _profile(self, form, caches):
        cache_values = {}

        def evaluate(thr):
            key = tuple(sorted(thr.items()))
            if key not in cache_values:
                full = dict(thr)
                full.setdefault("feedback_gain", self.feedback_gain)
                y, x, names, idx, grams = self._system(form, full, caches=caches)
                sol = self._solve(y, x, idx, grams)
                compensated = PROFILE_COMPENSATED and form.dead_zone_on == "error"
                value = (sol[5] if compensated else sol[1]) / float(y @ y)
                if not form.admissible(dict(zip(names, sol[0]))):
                    value = INADMISSIBLE + value  # outside the physical actuators
                cache_values[key] = value
            return cache_values[key]

        return evaluate, cache_values

    def _scan(self, form, fixed, caches, constraints=None):
        """Coarse grid then Nelder-Mead refinement of the profile residual."""
        constraints = dict(constraints or {})
        evaluate, values = self._profile(form, caches)
        grid = self._grid(form, {**fixed, **constraints})
        names = list(grid)
        mesh = np.meshgrid(*[grid[n] for n in names], indexing="ij")
        points = np.column_stack([m.ravel() for m in mesh])
        scores = np.array([evaluate(dict(zip(names, pt))) for pt in points])
        order = np.argsort(scores)
        free = [n for n in names if grid[n].size > 1]
        best_thr, best_score = dict(zip(names, points[order[0]])), scores[order[0]]
        if not free:
            return best_thr, best_score, values
        for start_idx in order[:2]:
            start = dict(zip(names, points[start_idx]))
            thr, score = self._nelder_mead(evaluate, start, free, 0.3, 1e-3)
            if score < best_score:
                best_thr, best_score = thr, score
        return best_thr, best_score, values

    def _refine(self, form, start, fixed, caches):
        """Nelder-Mead from ``start`` on the fine-quadrature profile (small initial simplex)."""
        evaluate, _ = self._profile(form, caches)
        free = [n for n in form.threshold_names() if n not in fixed]
        return self._nelder_mead(evaluate, dict(start), free, 0.05, 2e-4)[0]

    @staticmethod
    def _nelder_mead(evaluate, start, free, log_step, delay_step):
        """Minimise the profile over the free thresholds; a threshold at zero stays at zero."""
        active = [n for n in free if not (n in _LOG_THRESHOLDS and start[n] <= 0)]
        if not active:
            return start, evaluate(start)

        def to_thr(v):
            thr = dict(start)
            for n, val in zip(active, v):
                thr[n] = math.exp(val) if n in _LOG_THRESHOLDS else max(val, 0.0)
            return thr

        x0 = [math.log(start[n]) if n in _LOG_THRESHOLDS else start[n] for n in active]
        steps = [log_step if n in _LOG_THRESHOLDS else delay_step for n in active]
        simplex = [x0] + [list(np.add(x0, np.eye(len(active))[i] * steps[i]))
                          for i in range(len(active))]
        res = minimize(
            lambda v: evaluate(to_thr(v)), x0, method="Nelder-Mead",
            options={"initial_simplex": simplex, "xatol": 1e-4, "fatol": 1e-9,
                     "maxfev": 100 * len(active)},
        )
        return to_thr(res.x), float(res.fun)

