"""The edge timing of a command known only as samples, marginalised as a nuisance.

A square wave (or a step) recorded at 200 Hz says only that each edge lies between the last sample
at the old level and the first at the new one: a window of 5 ms, the size of the delay being
identified. Over several edges of a regular square the common phase and the half period are narrowed
(:func:`tvcid.models.commands._edge_polygon`), but rarely below a fraction of a sample. In open loop that
timing trades one for one with the delay, so any single replay (the samples, the hold, the centre)
biases the delay, and so does a Gaussian approximation of the response's spread over the
timings. Here the timing is what it is, a
nuisance ``theta = (phase, half period)`` uniform over every value the samples allow, and the
likelihood is its integral over them.
How (one simulation per parameter set, no more):

* the command is simulated once with its edges rounded to the solver's step grid (an edge
  between steps costs RK4 first-order accuracy: up to 1e-4 rad near each edge at 5e-4 s);
* the response to edges at ``e_j(theta) = c_j + phase + j * half`` is the simulated one shifted,
  segment by segment, by ``e_j(theta) - g_j`` (``g_j`` the grid edge): exact for a time-invariant
  system whose response to an edge has settled before the next, and closer to a fine
  reference than simulating the off-grid edges directly;
* a response that never settles between edges (a band-pass loop hunting on the plateaus: its
  phase at the next edge moves with the plateau's length) is not a shifted copy; the owner then
  simulates the edges where they are, at the most probable timing for the parameters it was
  last checked at (:meth:`EdgeTiming.simulate_at`), and shifts only from there;
* the likelihood in ``theta`` is a needle (an edge's response pins its time to microseconds), so
  its integral is the Laplace approximation at the Gauss-Newton optimum inside the feasible set:
  ``ll(theta*) + d/2 log 2 pi - 1/2 log det H - log(area)``, never above ``ll(theta*)``
  (a response too flat to time its edges leaves the timing's prior in place).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from tvcid.models.commands import _edge_polygon, is_piecewise_constant, regular_edge_times
from tvcid.models.experiments import OpenLoop

__all__ = ["EdgeTiming", "edge_timing_for"]

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

    def simulate_at(self, theta, dt, on_grid=False):
        """Simulate the edges at timing ``theta`` where they are (off the step grid; shifts are
        then taken from there): for a response that does not settle between edges, whose shifted
        copy errs in proportion to the shift.
        ``on_grid`` rounds them to the grid of step ``dt`` (shifts then under ``dt / 2``)."""
        theta = np.asarray(theta, dtype=float)
        off = theta[0] + (self.index * theta[1] if self.dim == 2 else 0.0)
        grid = self.centre + off
        if on_grid:
            grid = np.round(grid / dt) * dt
        grid = np.maximum(grid, dt)
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
        theta = np.asarray(theta, dtype=float)
        tau = np.asarray(tau, dtype=float)
        y = np.empty(tau.size)
        jac = np.empty((self.dim, tau.size))
        _shift_read(self._edges(theta), self.grid, self.index, tau, float(t_sim[0]),
                    float(t_sim[1] - t_sim[0]), np.asarray(y_sim, dtype=float), y, jac[0],
                    jac[-1], self.dim == 2)
        return y, jac.T

    def _edges(self, theta):
        return self.centre + theta[0] + (self.index * theta[1] if self.dim == 2 else 0.0)

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
        tau = np.asarray(tau, dtype=float)
        data = np.asarray(data, dtype=float)
        w = 1.0 / np.asarray(var, dtype=float)
        t0, h = float(t_sim[0]), float(t_sim[1] - t_sim[0])
        y_sim = np.asarray(y_sim, dtype=float)
        r = np.empty(tau.size)
        scratch = np.empty((3, tau.size))
        hess = np.empty((self.dim, self.dim))
        grad = np.empty(self.dim)

        def linearised(theta):
            """Residuals at ``theta`` (into ``r``), the weighted normal matrix and gradient
            there (``r(theta + d) ~ r - jac d``), in one compiled pass over the samples."""
            _normal_equations(self._edges(theta), self.grid, self.index, tau, data, w, t0, h,
                              y_sim, bool(demean), r, scratch, hess, grad)
            return hess.copy(), grad.copy()

        theta = np.zeros(self.dim)
        if not self.feasible(theta):
            theta = self._vertices.mean(axis=0)
        for _ in range(GN_ITERATIONS):
            h_mat, g_vec = linearised(theta)
            try:
                step = np.linalg.lstsq(h_mat, g_vec, rcond=1e-12)[0]
            except np.linalg.LinAlgError:
                break
            new = self._project(theta + step, h_mat)
            done = np.all(np.abs(new - theta) < 1e-8)
            theta = new
            if done:
                break
        h_mat, _ = linearised(theta)
        sign, logdet = np.linalg.slogdet(h_mat)
        if sign <= 0 or not np.isfinite(logdet):
            return r, 0.0, theta
        log_volume = 0.5 * self.dim * math.log(2 * math.pi) - 0.5 * logdet - self.log_area
        return r, min(0.0, float(log_volume)), theta


@njit(cache=True, error_model="numpy")
def _grid_interval(u, n_intervals):
    """Interval ``k`` (of ``n_intervals`` on a uniform grid) holding position ``u`` (in steps from
    the first node) and the fraction ``f`` across it; beyond either end the end node (numpy.interp
    holds the end values)."""
    if u <= 0.0:
        return 0, 0.0
    if u >= n_intervals:
        return n_intervals - 1, 1.0
    k = int(u)
    return k, u - k


@njit(cache=True, error_model="numpy")
def _shift_read(edges, grid, index, tau, t0, h, y_sim, y_out, j0_out, j1_out, two):
    """The response to edges at ``edges``, read at ``tau`` (into ``y_out``), and its derivative
    with respect to the timing's phase (``j0_out``) and, when ``two``, half period (``j1_out``).

    Each sample after edge ``j`` reads the simulated response (edges at ``grid``) at
    ``tau - (edges[j] - grid[j])``, linearly interpolated on its uniform grid ``t0 + h k``; the
    derivative is minus the response's slope there (interpolated between the midpoints of the
    grid's intervals) times ``d shift / d theta`` = ``(1, j)``.
    """
    n_sim = y_sim.size
    n_edges = edges.size
    inv_h = 1.0 / h
    lo = 0
    for i in range(tau.size):
        # number of edges at or before tau[i] (numpy.searchsorted, side="right"): walked
        # forward from the previous sample's count while the times increase, else searched
        if i == 0 or tau[i] < tau[i - 1]:
            lo, hi = 0, n_edges
            while lo < hi:
                mid = (lo + hi) // 2
                if edges[mid] <= tau[i]:
                    lo = mid + 1
                else:
                    hi = mid
        while lo < n_edges and edges[lo] <= tau[i]:
            lo += 1
        x = tau[i] if lo == 0 else tau[i] - (edges[lo - 1] - grid[lo - 1])
        # numpy.interp on the uniform grid: the interval by index arithmetic, ends held
        u = (x - t0) * inv_h
        k, f = _grid_interval(u, n_sim - 1)
        y_out[i] = y_sim[k] + f * (y_sim[k + 1] - y_sim[k])
        if lo == 0:
            j0_out[i] = 0.0
            if two:
                j1_out[i] = 0.0
            continue
        # the slope between grid points m and m + 1 sits at the interval's midpoint
        m, f = _grid_interval(u - 0.5, n_sim - 2)
        s0 = y_sim[m + 1] - y_sim[m]
        s1 = y_sim[m + 2] - y_sim[m + 1]
        slope = (s0 + f * (s1 - s0)) * inv_h
        j0_out[i] = -slope
        if two:
            j1_out[i] = -slope * index[lo - 1]


@njit(cache=True, error_model="numpy")
def _normal_equations(edges, grid, index, tau, data, w, t0, h, y_sim, demean, r_out, scratch,
                      hess_out, grad_out):
    """Residuals ``data - y`` at the timing ``edges`` (into ``r_out``), and ``jac' W jac`` and
    ``jac' W r`` (into ``hess_out``, ``grad_out``, ``dim`` = 1 or 2); with ``demean`` the
    residuals and the Jacobian's columns have their plain means removed first (the profiled
    sensor offset). ``scratch``: ``(3, n)`` work space."""
    n = tau.size
    two = hess_out.shape[0] == 2
    y, j0, j1 = scratch[0], scratch[1], scratch[2]
    _shift_read(edges, grid, index, tau, t0, h, y_sim, y, j0, j1, two)
    rm, m0, m1 = 0.0, 0.0, 0.0
    for i in range(n):
        r_out[i] = data[i] - y[i]
        rm += r_out[i]
        m0 += j0[i]
    if two:
        for i in range(n):
            m1 += j1[i]
    if demean:
        rm, m0, m1 = rm / n, m0 / n, m1 / n
    else:
        rm, m0, m1 = 0.0, 0.0, 0.0
    h00, h01, h11, g0, g1 = 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(n):
        r = r_out[i] - rm
        r_out[i] = r
        a = j0[i] - m0
        wa = w[i] * a
        h00 += wa * a
        g0 += wa * r
    if two:
        for i in range(n):
            a = j0[i] - m0
            b = j1[i] - m1
            wb = w[i] * b
            h01 += wb * a
            h11 += wb * b
            g1 += wb * r_out[i]
        hess_out[0, 1] = h01
        hess_out[1, 0] = h01
        hess_out[1, 1] = h11
        grad_out[1] = g1
    hess_out[0, 0] = h00
    grad_out[0] = g0


def edge_timing_for(experiment, t, u, dt, on_grid=True):
    """An :class:`EdgeTiming` when ``experiment`` replays a sampled piecewise command, else None."""
    if getattr(experiment, "waveform", None) != "piecewise":
        return None
    try:
        return EdgeTiming(t, u, dt, on_grid=on_grid)
    except ValueError:
        return None
