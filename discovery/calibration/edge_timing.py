"""The edge timing of a command known only as samples, marginalised as a nuisance.

A square wave (or a step) recorded at 200 Hz says only that each edge lies between the last
sample at the old level and the first at the new one: a window of 5 ms, the size of the delay
being identified. Over several edges of a regular square the common phase and the half period
are narrowed (:func:`models.commands._edge_polygon`), but rarely below a fraction of a sample.
In open loop that timing trades one for one with the delay, so any single replay (the samples,
the hold, the centre) biases the delay, and a Gaussian approximation of the response's spread
over the timings (the previous remedy) still pulled a drawn truth's delay by 10-17 us, 2.4 nats
(coverage draw 1). Here the timing is what it is, a nuisance ``theta = (phase, half period)``
uniform over every value the samples allow, and the likelihood is its integral over them.

How (one simulation per parameter set, no more):

* the command is simulated once with its edges rounded to the solver's step grid (an edge
  between steps costs RK4 first-order accuracy: up to 1e-4 rad near each edge at 5e-4 s);
* the response to edges at ``e_j(theta) = c_j + phase + j * half`` is the simulated one shifted,
  segment by segment, by ``e_j(theta) - g_j`` (``g_j`` the grid edge): exact for a time-invariant
  system whose response to an edge has settled before the next, and 3-4x closer to a 1e-5 s
  reference than simulating the off-grid edges directly (draw 1's truth, 0.13 ms shift);
* a response that never settles between edges (a band-pass loop hunting on the plateaus,
  coverage draw 5: its phase at the next edge moves with the plateau's length) is not a shifted
  copy; the owner then simulates the edges where they are, at the most probable timing for
  the parameters it was last checked at (:meth:`EdgeTiming.simulate_at`), and shifts only from
  there (draw 5's square at its truth, noise-free: rms 5.6e-5 rad from the grid, 2.2e-6 from
  the edges themselves, noise 8.9e-5);
* the likelihood in ``theta`` is a needle (an edge's response pins its time to microseconds), so
  its integral is the Laplace approximation at the Gauss-Newton optimum inside the feasible set:
  ``ll(theta*) + d/2 log 2 pi - 1/2 log det H - log(area)``, never above ``ll(theta*)``
  (a response too flat to time its edges leaves the timing's prior in place).
"""
from __future__ import annotations

import math

import numpy as np

from models.commands import _edge_polygon, is_piecewise_constant, regular_edge_times
from models.experiments import OpenLoop

__all__ = ["EdgeTiming", "uniform_interp"]

#: Gauss-Newton iterations of the timing per parameter set (the needle sits within a sample of
#: the previous iterate after two; a third settles the segment boundaries).
GN_ITERATIONS = 3
#: Slack of the feasibility test (s): edges on a sample belong to the hold's side.
SLACK = 1e-9


class EdgeTiming:
    """The feasible edge timings of a sampled piecewise-constant command.

    Parameters
    ----------
    t, u : array_like
        Sample times (s, any origin) and the command (rad).
    dt : float
        The solver's step (s): the replayed edges are put on its grid.
    on_grid : bool
        Round the simulated edges to the step grid (default); ``False`` simulates the centre
        edges where they are (for a response that does not settle between edges).

    Attributes
    ----------
    experiment : OpenLoop
        The command with the centre edges rounded to the step grid (simulate this), or the
        centre edges themselves when not ``on_grid``.
    dim : int
        2 for a regular sequence of three or more edges (phase and half period), else 1 (a
        common shift of every edge).
    log_area : float
        Log of the feasible set's area (s^dim).
    """

    def __init__(self, t, u, dt, on_grid=True):
        t = np.asarray(t, dtype=float)
        u = np.asarray(u, dtype=float)
        if not is_piecewise_constant(u):
            raise ValueError("the command is not piecewise constant")
        t = t - t[0]
        k = np.flatnonzero(np.diff(u)) + 1
        if k.size == 0:
            raise ValueError("the command has no edge")
        self.levels = np.concatenate([[u[0]], u[k]])
        lo, hi = t[k - 1], t[k]
        polygon = _edge_polygon(t, k)
        centre = regular_edge_times(t, k, unresolved="centre") if polygon is not None else None
        if centre is None or not np.all(np.isfinite(centre)):
            centre = 0.5 * (lo + hi)
        self.centre = centre
        self.index = np.arange(k.size, dtype=float)
        # constraints lo_j - c_j <= phase + j * half <= hi_j - c_j on the offsets from the centre
        regular = polygon is not None and np.any(polygon[6] - polygon[5] >= 0)
        self.dim = 2 if regular else 1
        a = np.stack([np.ones(k.size), self.index], axis=1)[:, : self.dim]
        self._a = np.concatenate([a, -a])
        self._b = np.concatenate([hi - centre, -(lo - centre)])
        self._vertices = self._feasible_vertices()
        self.log_area = self._log_area()
        grid = np.round(centre / dt) * dt if on_grid else centre.copy()
        grid = np.maximum(grid, dt)  # an edge at t = 0 would be lost before the first step
        if np.any(np.diff(grid) <= 0):
            raise ValueError("edges closer than the solver's step")
        self.grid = grid
        self.experiment = OpenLoop.piecewise(grid, self.levels)

    def simulate_at(self, theta, dt):
        """Simulate the edges at timing ``theta`` where they are (off the step grid; shifts are
        then taken from there): for a response that does not settle between edges, whose shifted
        copy errs in proportion to the shift (coverage draw 5's square, 4 s: theta 0.9 ms from
        the centre, rms 2.9e-5 rad against noise 8.9e-5 when simulated at the centre)."""
        theta = np.asarray(theta, dtype=float)
        off = theta[0] + (self.index * theta[1] if self.dim == 2 else 0.0)
        grid = np.maximum(self.centre + off, dt)
        if np.any(np.diff(grid) <= 0):
            raise ValueError("edges closer than the solver's step")
        self.grid = grid
        self.experiment = OpenLoop.piecewise(grid, self.levels)
        return self

    # -- the feasible set --------------------------------------------------------------------
    def feasible(self, theta) -> bool:
        return bool(np.all(self._a @ np.asarray(theta) <= self._b + SLACK))

    def _feasible_vertices(self):
        if self.dim == 1:
            return np.array([[-np.min(self._b[self._a[:, 0] < 0])], [np.min(self._b[self._a[:, 0] > 0])]])
        a, b = self._a, self._b
        i, j = np.triu_indices(a.shape[0], 1)
        det = a[i, 0] * a[j, 1] - a[i, 1] * a[j, 0]
        ok = np.abs(det) > 1e-12
        i, j, det = i[ok], j[ok], det[ok]
        x = (b[i] * a[j, 1] - a[i, 1] * b[j]) / det
        y = (a[i, 0] * b[j] - b[i] * a[j, 0]) / det
        pts = np.stack([x, y], axis=1)
        inside = np.all(pts @ a.T <= b + 1e-12 + 1e-9 * np.abs(b), axis=1)
        pts = pts[inside]
        if pts.shape[0] < 3:
            raise ValueError("the edges' samples leave no consistent timing")
        return pts

    def _log_area(self):
        v = self._vertices
        if self.dim == 1:
            return math.log(max(float(v[1, 0] - v[0, 0]), 1e-12))
        c = v.mean(axis=0)
        order = np.argsort(np.arctan2(v[:, 1] - c[1], v[:, 0] - c[0]))
        x, y = v[order, 0], v[order, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        return math.log(max(area, 1e-300))

    def _project(self, theta, h):
        """The feasible point nearest ``theta`` in the metric ``h`` (a tiny quadratic program)."""
        if self.feasible(theta):
            return theta
        if self.dim == 1:
            v = self._vertices[:, 0]
            return np.clip(theta, v[0], v[1])
        hinv = np.linalg.pinv(h)
        cands = [self._vertices]
        # the minimum on each constraint line
        ah = self._a @ hinv
        den = np.einsum("ij,ij->i", ah, self._a)
        ok = den > 0
        step = (self._a[ok] @ theta - self._b[ok]) / den[ok]
        cands.append(theta[None, :] - step[:, None] * ah[ok])
        pts = np.concatenate(cands)
        pts = pts[np.all(pts @ self._a.T <= self._b + SLACK, axis=1)]
        d = pts - theta
        q = np.einsum("ij,jk,ik->i", d, h, d)
        return pts[int(np.argmin(q))]

    # -- the response at a timing ------------------------------------------------------------
    def shifted(self, theta, tau, t_sim, y_sim):
        """The simulated response (at ``t_sim``, a uniform grid) for edges at ``theta``, read at
        ``tau``, and its derivative with respect to ``theta`` (``(n, dim)``)."""
        h = float(t_sim[1] - t_sim[0])
        return self._shifted(theta, tau, float(t_sim[0]), h, y_sim, np.diff(y_sim) / h)

    def _shifted(self, theta, tau, t0, h, y_sim, slope_sim):
        """:meth:`shifted` with the response's slopes between grid points given (a marginal
        evaluates several timings of one response)."""
        off = theta[0] + (self.index * theta[1] if self.dim == 2 else 0.0)
        edges = self.centre + off
        seg = np.searchsorted(edges, tau, side="right")  # edges passed at each sample
        before = seg > 0
        j = np.maximum(seg - 1, 0)
        shift = np.where(before, edges[j] - self.grid[j], 0.0)
        x = tau - shift
        y = uniform_interp(x, t0, h, y_sim)
        slope = uniform_interp(x, t0 + 0.5 * h, h, slope_sim)
        # d y(tau - shift) / d theta = -y' * d shift / d theta
        jac = np.zeros((tau.size, self.dim))
        jac[:, 0] = np.where(before, -slope, 0.0)
        if self.dim == 2:
            jac[:, 1] = np.where(before, -slope * self.index[j], 0.0)
        return y, jac

    def marginal(self, tau, data, t_sim, y_sim, var, demean=True):
        """Residuals at the most probable timing and the log of the timing's integral.

        Parameters
        ----------
        tau, data : ndarray
            Sample times (s, from the record's start) and the recorded output (rad).
        t_sim, y_sim : ndarray
            The simulated response to :attr:`experiment` on the solver's grid.
        var : ndarray
            Per-sample variance of the residuals (noise, solver error, inflation).
        demean : bool
            Profile a constant sensor offset out of the residuals (and their derivatives).

        Returns
        -------
        residuals : ndarray
            ``data - model`` at the optimum timing (offset removed when ``demean``).
        log_volume : float
            ``log`` of the integral of ``exp(ll(theta) - ll(theta*))`` over the uniform prior of
            the timing (<= 0).
        theta : ndarray
        """
        w = 1.0 / var
        t0, h = float(t_sim[0]), float(t_sim[1] - t_sim[0])
        slope_sim = np.diff(y_sim) / h

        def linearised(theta):
            """Residuals at ``theta``, and the weighted normal matrix and gradient there
            (``r(theta + d) ~ r - jac d``)."""
            y, jac = self._shifted(theta, tau, t0, h, y_sim, slope_sim)
            r = data - y
            if demean:
                r = r - r.mean()
                jac = jac - jac.mean(axis=0)
            return r, jac.T @ (jac * w[:, None]), jac.T @ (w * r)

        theta = np.zeros(self.dim)
        if not self.feasible(theta):
            theta = self._vertices.mean(axis=0)
        for _ in range(GN_ITERATIONS):
            _, hess, grad = linearised(theta)
            try:
                step = np.linalg.lstsq(hess, grad, rcond=1e-12)[0]
            except np.linalg.LinAlgError:
                break
            new = self._project(theta + step, hess)
            done = np.all(np.abs(new - theta) < 1e-8)
            theta = new
            if done:
                break
        r, hess, _ = linearised(theta)
        sign, logdet = np.linalg.slogdet(hess)
        if sign <= 0 or not np.isfinite(logdet):
            return r, 0.0, theta
        log_volume = 0.5 * self.dim * math.log(2 * math.pi) - 0.5 * logdet - self.log_area
        return r, min(0.0, float(log_volume)), theta


def uniform_interp(x, x0, h, y):
    """``numpy.interp(x, x0 + h * arange(y.size), y)`` without its binary search.

    The simulated response lies on the solver's uniform grid, so the interval of each point is
    an index computed directly; outside the grid the end values hold, as in ``numpy.interp``.
    """
    u = (np.asarray(x, dtype=float) - x0) / h
    i = np.clip(np.floor(u), 0, y.size - 2).astype(np.intp)
    f = np.clip(u - i, 0.0, 1.0)
    return y[i] + f * (y[i + 1] - y[i])


def edge_timing_for(experiment, t, u, dt, on_grid=True):
    """An :class:`EdgeTiming` when ``experiment`` replays a sampled piecewise command, else None."""
    if getattr(experiment, "waveform", None) != "piecewise":
        return None
    try:
        return EdgeTiming(t, u, dt, on_grid=on_grid)
    except ValueError:
        return None
