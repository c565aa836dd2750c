"""A 90 % interval widened to what the simulation step resolves.

Where a quantity's interval is narrower than twice its step error
(:func:`tvcid.discovery.calibration.step_error.measure_step_error`), what the report prints is at
least the median plus or minus that error: an interval the step cannot resolve says nothing at
its own width. The rule on one interval (:func:`widen_interval`), on a member's draws before the
members are mixed (:func:`widen_draws`), and on a table of quantities (:func:`widen_quantiles`).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["widen_interval", "widen_draws", "widen_quantiles"]


def widen_interval(q05, q50, q95, error, bounds=None):
    """A 90 % interval widened to what the simulation step resolves.

    Rule: where the interval is narrower than ``2 error`` (``q95 - q05 < 2 error``), it becomes
    ``[min(q05, q50 - error), max(q95, q50 + error)]``: at least the median plus or minus the
    step error; an interval at least that wide is kept as it is. A widened end stops at the
    quantity's ``bounds`` (a dead zone, a delay: not below 0), never inside the sampled end.

    Parameters
    ----------
    q05, q50, q95 : float
    error : float or None
        The quantity's step error (:attr:`.step_error.StepError.errors`); ``None`` or NaN: not
        measured, nothing changes.
    bounds : (float, float), optional
        Where the quantity can lie (the prior's support); ``None`` for either end: unbounded.

    Returns
    -------
    low, high : float
    widened : bool
    """
    if error is None or not math.isfinite(float(error)):
        return q05, q95, False
    e = float(error)
    if e < 0:
        raise ValueError(f"a step error is a size (got {e})")
    if not q95 - q05 < 2.0 * e:
        return q05, q95, False
    low, high = min(q05, q50 - e), max(q95, q50 + e)
    floor, ceiling = bounds if bounds is not None else (None, None)
    if floor is not None:
        low = min(q05, max(low, float(floor)))
    if ceiling is not None:
        high = max(q95, min(high, float(ceiling)))
    return low, high, bool(low < q05 or high > q95)


def widen_draws(values, error, bounds=None):
    """A member's draws of one quantity widened as :func:`widen_interval` widens its interval.

    Each side of the median is stretched about it, linearly, so that the draws' 5 % and 95 %
    quantiles become the widened interval's ends; draws already wide enough are returned as they
    are. The stretched draws are clipped to ``bounds``. Mixing members' draws widened each by
    its own step error (:func:`tvcid.discovery.members.set_posterior.combine`) carries each
    member's error at its weight, where widening the mixture by the largest error would let one
    member that the step does not resolve widen every other member's answer.

    Parameters
    ----------
    values : array_like
    error : float or None
    bounds : (float, float), optional

    Returns
    -------
    draws : ndarray
    widened : bool
    """
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    if error is None or not math.isfinite(float(error)) or not ok.any():
        return v, False
    q05, q50, q95 = np.quantile(v[ok], (0.05, 0.5, 0.95))
    low, high, widened = widen_interval(q05, q50, q95, error, bounds)
    if not widened:
        return v, False
    out = v.copy()
    if q95 == q05:  # no spread at all: the draws spread evenly, by rank, so that 90 % span the ends
        u = (np.argsort(np.argsort(v[ok], kind="stable"), kind="stable") + 0.5) / ok.sum()
        out[ok] = low + (high - low) * (u - 0.05) / 0.9
    else:  # a side without spread (q05 or q95 at the median) is left as it is
        for side, end, q in ((ok & (v < q50), low, q05), (ok & (v > q50), high, q95)):
            if end != q and q != q50:
                out[side] = q50 + (v[side] - q50) * (end - q50) / (q - q50)
    if bounds is not None:
        floor, ceiling = bounds
        out[ok] = np.clip(out[ok], -np.inf if floor is None else floor,
                          np.inf if ceiling is None else ceiling)
    return out, True


def widen_quantiles(quantiles: dict, errors: dict, bounds: dict | None = None) -> dict:
    """:func:`widen_interval` over a table of quantities.

    ``quantiles``: name -> a dict with ``q05``, ``q50`` and ``q95`` (a posterior summary's
    ``parameters``, a set posterior's ``quantities``); ``errors``: name -> step error;
    ``bounds``: name -> where it can lie (the priors' supports). Returns a copy in which every
    entry with an error also has ``step_error`` and ``widened``, and, where widened, its
    ``q05``/``q95`` replaced and the original ones kept as ``q05_sampled`` and
    ``q95_sampled``."""
    out = {}
    for name, q in quantiles.items():
        q = dict(q)
        e = errors.get(name)
        if e is not None and None not in (q.get("q05"), q.get("q50"), q.get("q95")):
            low, high, widened = widen_interval(q["q05"], q["q50"], q["q95"], e,
                                                (bounds or {}).get(name))
            q["step_error"], q["widened"] = float(e), widened
            if widened:
                q["q05_sampled"], q["q95_sampled"] = q["q05"], q["q95"]
                q["q05"], q["q95"] = float(low), float(high)
        out[name] = q
    return out
