"""The numerical pieces of the start search, as functions of a log posterior ``lp`` in internal
(sampling) coordinates, vectorised over rows.

* optimisers: Nelder-Mead in its first simplex's units (:func:`_nelder_mead`), from a point
  (:func:`_nelder_mead_from`, its costs :func:`_cost` and first simplex :func:`_simplex`), a
  quasi-Newton ascent whose evaluations come in batches (:func:`_quasi_newton`), a
  differential evolution over the prior box (:func:`_global_start`) and the noise sd's
  conditional maximum (:func:`_profile_sigma`);
* curvature: each axis' sd (:func:`_axis_scales`), the Hessian by central differences
  (:func:`_hessian`), the principal axes with ridges spread over the prior
  (:func:`_principal_axes`), and the Laplace covariance where it can serve as a proposal
  (:func:`laplace_covariance`).
"""
from __future__ import annotations

import math

import numpy as np

from .priors import SIGMA

__all__ = ["laplace_covariance", "bounded_laplace_covariance"]

#: Largest principal sd of a usable Laplace approximation, as a fraction of the prior's extent.
LAPLACE_MAX_FRACTION = 0.25
#: Nelder-Mead stops once its simplex has shrunk to this fraction of its first edges (each axis'
#: sd, so the tolerance means the same on a log and a linear axis) ...
NM_XATOL = 0.1
#: ... and its vertices' log posteriors agree within this (nats).
NM_FATOL = 0.05


def _global_start(lp, z0, seed, names):
    """The better of ``z0`` and a differential evolution over the prior box (vectorised: each
    generation one batch of simulations), refined by Nelder-Mead."""
    from scipy.optimize import differential_evolution

    bounds = [p.internal_bounds for p in lp.priors]

    def cost(z):  # (ndim, S) -> (S,)
        f = np.asarray(lp(np.atleast_2d(z.T)), dtype=float)
        return np.where(np.isfinite(f), -f, 1e30)  # finite: DE squares the spread of costs

    res = differential_evolution(cost, bounds, vectorized=True, popsize=12, maxiter=40, tol=1e-3,
                                 seed=seed, polish=False, init="sobol", updating="deferred")
    z = _profile_sigma(lp, _nelder_mead_from(lp, res.x), names)
    return z if lp(z) > lp(z0) else z0


def _nelder_mead(lp, simplex, maxfev):
    """The end of Nelder-Mead on ``-lp`` from the first simplex ``simplex`` (``(ndim + 1, ndim)``,
    its first row the start), run in units of the simplex's edges.

    Nelder-Mead's steps commute with an affine change of coordinates, so the path is the one it
    takes in internal coordinates; only the stop differs. In the edges' units (each axis' sd)
    :data:`NM_XATOL` means a tenth of a standard deviation on every axis, where one absolute
    tolerance in internal coordinates means a different precision on a log and a linear axis,
    and one far below an axis' sd keeps the search going to its evaluation cap for a few
    hundredths of a nat (``tests/test_calibration_start.py``).
    """
    from scipy.optimize import minimize

    simplex = np.asarray(simplex, dtype=float)
    z0, n = simplex[0], simplex.shape[1]
    edges = (simplex[1:] - z0).T
    cost = _cost(lp)
    res = minimize(lambda u: cost(z0 + edges @ u), np.zeros(n), method="Nelder-Mead",
                   options={"maxfev": maxfev, "xatol": NM_XATOL, "fatol": NM_FATOL,
                            "initial_simplex": np.vstack([np.zeros(n), np.eye(n)])})
    return z0 + edges @ res.x


#: Iterations of :func:`_quasi_newton` at most (each one gradient, ``2 d`` points, and two
#: trial points) ...
QN_ITERATIONS = 12
#: ... its first trust radius, in each axis' sd ...
QN_RADIUS = 2.0
#: ... and the curvature floor in the same units: a ridge's step is the trust radius's.
QN_MIN_CURVATURE = 1e-2


def _quasi_newton(lp, z0, scale, hess=None, maxiter=QN_ITERATIONS):
    """The maximum of ``lp`` from ``z0`` by quasi-Newton steps whose evaluations come in batches.

    In units of each axis' sd (``scale``), a model ``-B`` of the curvature (from ``hess``,
    :func:`_hessian` at ``z0``, computed here when not given; eigenvalues floored at
    ``QN_MIN_CURVATURE``) gives the step ``B^-1 g``, cut to a trust radius; the gradient ``g``
    is the central difference over one sd of each axis (the scale at which the Hessian is read,
    so that a cycle's features, rough at finer scales, are seen smooth). The step and its half
    are tried in one batch; the better is taken if it gains, the radius grows after a full step
    that gains and shrinks four-fold after none; ``B`` is updated by BFGS from the gradients.
    Stops where the model's gain is under :data:`NM_FATOL` nats or the step under
    :data:`NM_XATOL` sd (Nelder-Mead's own tolerances), or after ``maxiter`` gradients.

    A chain point costs one simulation of every recording; Nelder-Mead needs about ``150 d`` of
    them, one at a time, where this takes one Hessian and ``(2 d + 2)`` per iteration
    (docs/methods/calibration.md, "Start and moves"). Returns ``z0`` where a probe fails
    (no finite posterior) before any step, else the best point reached.
    """
    h = np.asarray(scale, dtype=float)
    if hess is None:
        hess = _hessian(lp, z0, h)
    if hess is None:
        return z0
    lam, vec = np.linalg.eigh(-hess * np.outer(h, h))
    b = (vec * np.maximum(lam, QN_MIN_CURVATURE)) @ vec.T
    lows, highs = _box(lp)
    z, f = np.asarray(z0, dtype=float), float(np.ravel(lp(z0))[0])
    if not math.isfinite(f):
        return z0
    radius, g = QN_RADIUS, None
    for _ in range(maxiter):
        if g is None:
            g = _gradient(lp, z, h, lows, highs)
            if g is None:
                break
        step = np.linalg.solve(b, g)
        if 0.5 * float(g @ step) < NM_FATOL:
            break
        length = float(np.sqrt(step @ step))
        if length > radius:
            step *= radius / length
            length = radius
        if length < NM_XATOL:
            break
        trials = np.clip(z + np.vstack([step, 0.5 * step]) * h, lows, highs)
        ft = np.asarray(lp(trials), dtype=float)
        best = int(np.nanargmax(np.where(np.isfinite(ft), ft, -np.inf)))
        if not ft[best] > f:
            radius *= 0.25
            continue
        s = (trials[best] - z) / h
        if best == 0 and length >= radius:
            radius *= 2.0
        z, f = trials[best], float(ft[best])
        g_new = _gradient(lp, z, h, lows, highs)
        if g_new is None:
            break
        y = g - g_new  # the change of the cost's gradient
        if float(s @ y) > 1e-12:
            bs = b @ s
            b = b + np.outer(y, y) / float(y @ s) - np.outer(bs, bs) / float(s @ bs)
        g = g_new
    return z


def _gradient(lp, z, h, lows, highs):
    """The gradient of ``lp`` at ``z`` per sd ``h`` of each axis: central differences over
    ``h``, shortened where ``z`` is nearer a bound of the box (``2 d`` points, one batch); None
    where a probe fails."""
    step = np.minimum(h, 0.999 * np.minimum(highs - z, z - lows))
    step = np.where(step > 1e-6 * h, step, h)  # on a bound: the probe fails, and so does this
    d = len(z)
    fp = np.asarray(lp(np.vstack([z + np.diag(step), z - np.diag(step)])), dtype=float)
    if not np.all(np.isfinite(fp)):
        return None
    return 0.5 * (fp[:d] - fp[d:]) * h / step


def _nelder_mead_from(lp, z):
    """Nelder-Mead from ``z`` (100 evaluations per coordinate); its end if more probable than ``z``."""
    end = _nelder_mead(lp, _simplex(z, lp), 100 * len(z))
    if np.isfinite(lp(end)) and lp(end) > lp(z):
        return end
    return z


def _profile_sigma(lp, z0, names):
    """``z0`` with the noise sd at its conditional maximum given the other parameters.

    The noise estimate from the record's floor is far below the misfit of a misspecified model
    (a SINDy proposal): started there, the posterior is so sharp that the walkers' ball collapses
    and the chain crawls for hundreds of steps (a ``discover`` study's proposals).
    """
    if SIGMA not in names:
        return z0
    from scipy.optimize import minimize_scalar

    j = list(names).index(SIGMA)
    lo, hi = lp.priors[j].internal_bounds
    full_cost = _cost(lp)

    def cost(v):
        z = z0.copy()
        z[j] = v
        return full_cost(z)

    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4 * (hi - lo)})
    if res.fun < cost(z0[j]):
        z0 = z0.copy()
        z0[j] = res.x
    return z0


def _cost(lp):
    """``-lp(z)`` for the optimisers, one evaluation per call; a huge finite value where ``lp``
    is ``-inf`` (Nelder-Mead and the bounded scalar search need finite costs)."""

    def cost(z):
        f = lp(z)
        return -f if np.isfinite(f) else 1e300

    return cost


def _simplex(z0, lp):
    scale = _axis_scales(lp, z0)
    simplex = [z0]
    for j in range(len(z0)):
        z = z0.copy()
        z[j] += scale[j]
        simplex.append(z)
    return np.array(simplex)


def _hessian(lp, z0, scale):
    """Hessian of ``lp`` at ``z0`` (internal coordinates) by central differences with steps
    ``scale`` (the per-axis sds, so each probe moves ``lp`` by ~0.5), all probes in one
    vectorised call; ``None`` when a probe fails."""
    ndim = len(z0)
    h = np.asarray(scale, dtype=float)
    pts = [z0]
    for i in range(ndim):
        for si in (1, -1):
            z = z0.copy()
            z[i] += si * h[i]
            pts.append(z)
    for i in range(ndim):
        for j in range(i + 1, ndim):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                z = z0.copy()
                z[i] += si * h[i]
                z[j] += sj * h[j]
                pts.append(z)
    f = np.asarray(lp(np.array(pts)), dtype=float)
    if not np.all(np.isfinite(f)):
        return None
    f0, k = f[0], 1
    hess = np.empty((ndim, ndim))
    for i in range(ndim):
        hess[i, i] = (f[k] - 2 * f0 + f[k + 1]) / h[i] ** 2
        k += 2
    for i in range(ndim):
        for j in range(i + 1, ndim):
            fpp, fpm, fmp, fmm = f[k:k + 4]
            hess[i, j] = hess[j, i] = (fpp - fpm - fmp + fmm) / (4 * h[i] * h[j])
            k += 4
    return hess


def _principal_axes(lp, z0, scale, hess):
    """Columns: the posterior's principal axes at ``z0``, each as long as its sd.

    From the Hessian ``hess`` (:func:`_hessian`). Along a direction the data barely constrain (a
    ridge: an eigenvalue near zero or positive), the sd is a quarter of the prior box's extent
    through ``z0`` in that direction, so the walkers start spread along the ridge instead of in a
    ball that must crawl along it. Falls back to the axis sds when the probes failed.
    """
    ndim = len(z0)
    h = np.asarray(scale, dtype=float)
    if hess is None:
        return np.diag(0.5 * h)
    # in units of the axis sds, so that eigenvalues compare across parameters
    precision = -hess * np.outer(h, h)
    vals, vecs = np.linalg.eigh(precision)
    lows, highs = _box(lp)
    axes = np.empty((ndim, ndim))
    for m in range(ndim):
        v = vecs[:, m] * h  # direction in internal coordinates, one unit = one eigen-sd at 1
        extent = _box_extent(z0, v, lows, highs)
        sd = 1.0 / math.sqrt(vals[m]) if vals[m] > 0 else math.inf
        axes[:, m] = v * min(sd, 0.25 * extent)
    return axes


def _box(lp):
    lows = np.array([p.internal_bounds[0] for p in lp.priors])
    highs = np.array([p.internal_bounds[1] for p in lp.priors])
    return lows, highs


def laplace_covariance(lp, z0, hess, max_fraction=LAPLACE_MAX_FRACTION):
    """The Laplace covariance ``(-hess)^-1`` at ``z0`` when it can serve as a proposal, else
    ``None``: the negative Hessian must be positive definite and every principal sd under
    ``max_fraction`` of the prior box's extent along it (otherwise the posterior is a ridge the
    prior cuts, far from its Gaussian)."""
    eig = _curvature_without_ridge(lp, z0, hess, max_fraction)
    if eig is None or not np.all(eig[0] > 0):
        return None
    vals, vecs = eig
    return (vecs / vals) @ vecs.T


def bounded_laplace_covariance(hess, ball, max_growth=30.0):
    """``(-hess)^-1`` in the coordinates of the walkers' starting ball (``ball``: its covariance,
    ``axes @ axes.T``), each principal sd there held to ``max_growth`` times the ball's (no
    curvature reads as a barely positive one), and a direction of wrong-signed curvature given
    the ball's own: a first proposal for
    importance sampling where :func:`laplace_covariance` refuses one for the chain's move (the
    prior's extent would be a cap thousands of times the posterior's width). ``None`` for a
    Hessian with non-finite entries."""
    if hess is None or not np.all(np.isfinite(hess)):
        return None
    b = np.linalg.cholesky(np.atleast_2d(ball))
    vals, vecs = np.linalg.eigh(-(b.T @ hess @ b))
    sd = np.where(vals > 0, 1.0 / np.sqrt(np.where(vals > 0, vals, 1.0)), 1.0)
    sd = np.minimum(sd, max_growth)
    inner = (vecs * sd**2) @ vecs.T
    return b @ inner @ b.T


def _curvature_without_ridge(lp, z0, hess, max_fraction):
    """``(vals, vecs)`` of ``-hess`` when it is finite and no direction of positive curvature has
    a principal sd reaching ``max_fraction`` of the prior box's extent along it; else ``None``."""
    if hess is None or not np.all(np.isfinite(hess)):
        return None
    vals, vecs = np.linalg.eigh(-hess)
    lows, highs = _box(lp)
    for m, v in enumerate(vals):
        if v > 0 and 1.0 / math.sqrt(v) >= max_fraction * _box_extent(z0, vecs[:, m], lows, highs):
            return None
    return vals, vecs


def _box_extent(z0, v, lows, highs):
    """Length (in multiples of ``v``) of the line ``z0 + t v`` inside the box ``[lows, highs]``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lows - z0) / v, (highs - z0) / v
    lo = np.where(v != 0, np.minimum(a, b), -np.inf)
    hi = np.where(v != 0, np.maximum(a, b), np.inf)
    return float(np.min(hi) - np.max(lo))


def _axis_scales(lp, z0):
    """Posterior sd along each internal axis from the curvature at ``z0`` (bounded guesses)."""
    ndim = len(z0)
    widths = np.array([hi - lo for lo, hi in (p.internal_bounds for p in lp.priors)])
    scale = np.empty(ndim)
    f0 = lp(z0)
    for j in range(ndim):
        h = 1e-3 * widths[j]
        scale[j] = 1e-3 * widths[j]
        for _ in range(6):
            pts = np.array([z0, z0, z0])
            pts[1, j] -= h
            pts[2, j] += h
            f = lp(pts)
            if not np.all(np.isfinite(f)):
                h *= 0.3
                continue
            d2 = (f[1] - 2 * f0 + f[2]) / h**2
            if d2 < 0:
                s = 1.0 / math.sqrt(-d2)
                scale[j] = min(s, 0.1 * widths[j])
                if 0.1 * s < h < 10 * s:
                    break
                h = s
            else:
                h *= 3.0
    return scale
