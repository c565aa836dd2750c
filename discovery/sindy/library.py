"""A pysindy feature library of the actuator's nonlinearities.

The elements are those of ``docs/models.md#conventions`` and :mod:`tvcid.models.nonlinearities`: the dead
zone ``DZ_z`` (paper 002 eq. 3), the saturation ``sat_s`` (paper 001 section 3), the sign of the
friction offset ``FRIC(q) = q + off*sign(q)`` (paper 001 section 3), the backlash as a play operator
of half width ``r`` (paper 002 eqs. 4-5; a memory term computed along the trajectory) and the
delayed command ``u(t - Td)`` (papers 002, 001, 000). Thresholds and the delay enter nonlinearly, so
they are fixed arguments of the library; :mod:`tvcid.discovery.sindy.threshold_scan` scans them.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from pysindy.feature_library.base import BaseFeatureLibrary, x_sequence_or_item
from pysindy.utils import AxesArray

from tvcid.models.nonlinearities import dead_zone, saturation

__all__ = [
    "ActuatorLibrary",
    "ACTUATOR_TERMS",
    "play_along",
    "delayed_command",
    "command_jumps",
    "actuator_error",
]

#: Names of the terms :class:`ActuatorLibrary` can build, in output order.
ACTUATOR_TERMS = (
    "delta",
    "u(t-Td)",
    "play_r(delta)",
    "DZ_z(u(t-Td)-K*play_r(delta))",
    "sat_s(u(t-Td)-K*play_r(delta))",
    "sign(delta')",
)


@njit(cache=True)
def _play(x, half_width, initial):
    out = np.empty_like(x)
    b = initial
    for k in range(x.size):
        lo = x[k] - half_width
        hi = x[k] + half_width
        if b < lo:
            b = lo
        elif b > hi:
            b = hi
        out[k] = b
    return out


def play_along(x, half_width, initial=None):
    """Backlash ``play_r(x)`` along a sampled trajectory (``docs/models.md#conventions``, numba
    loop).

    Same rule as :func:`tvcid.models.nonlinearities.play_operator`: ``b_k = min(max(b_{k-1}, x_k - r),
    x_k + r)``. The default initial memory is ``x_0`` (the play centred at the start).
    """
    x = np.ascontiguousarray(x, dtype=float)
    if half_width < 0 or not math.isfinite(half_width):
        raise ValueError(f"backlash half width must be finite and >= 0 (got {half_width!r})")
    if x.size == 0:
        return x.copy()
    b0 = float(x[0]) if initial is None else float(initial)
    return _play(x, float(half_width), b0)


def command_jumps(u):
    """Boolean per sample interval: True where the command jumps (a square wave's edge).

    A jump is a step larger than a quarter of the command's range; across such an interval the
    command is held (zero-order) instead of interpolated, so a square command sampled at its edges
    is reconstructed exactly and the weak integrals of terms built from it stay accurate.
    """
    u = np.asarray(u, dtype=float)
    span = float(np.max(u) - np.min(u)) if u.size else 0.0
    if span == 0.0:
        return np.zeros(max(u.size - 1, 0), dtype=bool)
    return np.abs(np.diff(u)) > 0.25 * span


def delayed_command(t_query, t, u, delay, jumps=None):
    """The command ``u(t - Td)`` at ``t_query`` from uniform samples ``(t, u)``.

    Linear interpolation between samples except across a jump (:func:`command_jumps`), where the
    previous sample is held. Before the first sample the first value is held.
    """
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    if jumps is None:
        jumps = command_jumps(u)
    dt = (t[-1] - t[0]) / (t.size - 1)
    tau = (np.asarray(t_query, dtype=float) - delay - t[0]) / dt
    tau = np.clip(tau, 0.0, t.size - 1.0)
    k = np.minimum(np.floor(tau + 1e-9).astype(np.int64), t.size - 2)
    frac = np.clip(tau - k, 0.0, 1.0)
    frac = np.where(jumps[k], np.where(frac >= 1.0 - 1e-9, 1.0, 0.0), frac)
    return u[k] + frac * (u[k + 1] - u[k])


def actuator_error(u_delayed, backlash, feedback_gain):
    """Actuator error ``e = u(t - Td) - K*play_r(delta)`` (``docs/models.md#the-actuator``)."""
    return u_delayed - feedback_gain * backlash


class ActuatorLibrary(BaseFeatureLibrary):
    """pysindy feature library of the actuator nonlinearities.

    Input columns are ``(delta, u)`` sampled uniformly at ``1/dt``; memory (play operator) and
    delay terms are computed along the sample order, so rows must be in time order. Usable with
    ``pysindy.SINDy(feature_library=ActuatorLibrary(...), optimizer=ps.STLSQ())`` or, as
    :mod:`tvcid.discovery.sindy.weak` does, by calling :meth:`transform` and handing the weak system to a
    pysindy optimizer.

    Parameters
    ----------
    dead_zone : float
        Half width ``z`` of ``DZ_z`` (rad), paper 002 eq. 3.
    backlash : float
        Half width ``r`` of the play operator (rad), paper 002 eqs. 4-5 with ``f = r``.
    saturation : float
        Level ``s`` of ``sat_s`` (rad); ``inf`` makes the term the plain error.
    delay : float
        ``Td`` (s) of the delayed command ``u(t - Td)``.
    feedback_gain : float
        ``K`` of the error ``e = u(t - Td) - K*play_r(delta)``.
    dt : float
        Sample step (s) of the rows.
    terms : sequence of str or None
        Subset of :data:`ACTUATOR_TERMS` to output (default all).
    """

    def __init__(
        self,
        dead_zone=0.0,
        backlash=0.0,
        saturation=math.inf,
        delay=0.0,
        feedback_gain=1.0,
        dt=1e-3,
        terms=None,
    ):
        self.dead_zone = dead_zone
        self.backlash = backlash
        self.saturation = saturation
        self.delay = delay
        self.feedback_gain = feedback_gain
        self.dt = dt
        self.terms = terms

    def _selected(self):
        terms = ACTUATOR_TERMS if self.terms is None else tuple(self.terms)
        unknown = [name for name in terms if name not in ACTUATOR_TERMS]
        if unknown:
            raise ValueError(
                f"unknown library term(s) {', '.join(unknown)}; known: {', '.join(ACTUATOR_TERMS)}"
            )
        return terms

    @x_sequence_or_item
    def fit(self, x_full, y=None):
        """Check the parameters and the input width; returns ``self``.

        ``x_full`` is one trajectory ``(n_samples, 2)`` or a list of them (pysindy's convention).
        """
        x = np.asarray(x_full[0])
        if x.ndim != 2 or x.shape[1] != 2:
            raise ValueError(
                f"ActuatorLibrary expects two input columns (delta, u); got shape {x.shape}"
            )
        for name in ("dead_zone", "backlash", "delay"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0 (got {value!r})")
        if not self.dt > 0:
            raise ValueError(f"dt must be > 0 (got {self.dt!r})")
        self.n_features_in_ = 2
        self.n_output_features_ = len(self._selected())
        return self

    def evaluate(self, delta, u, t=None):
        """Every selected term as a dict ``name -> samples`` (the work behind :meth:`transform`)."""
        delta = np.asarray(delta, dtype=float)
        u = np.asarray(u, dtype=float)
        if t is None:
            t = self.dt * np.arange(delta.size)
        selected = self._selected()
        out = {}
        need_error = any(name.startswith(("DZ", "sat")) for name in selected)
        u_delayed = delayed_command(t, t, u, self.delay) if self.delay > 0 else u
        b = play_along(delta, self.backlash) if self.backlash > 0 else delta
        e = actuator_error(u_delayed, b, self.feedback_gain) if need_error else None
        for name in selected:
            if name == "delta":
                out[name] = delta
            elif name == "u(t-Td)":
                out[name] = u_delayed
            elif name == "play_r(delta)":
                out[name] = b
            elif name.startswith("DZ"):
                out[name] = dead_zone(e, self.dead_zone)
            elif name.startswith("sat"):
                out[name] = saturation(e, self.saturation)
            elif name == "sign(delta')":
                out[name] = np.sign(np.gradient(delta, t))
        return out

    @x_sequence_or_item
    def transform(self, x_full):
        """Rows ``(delta, u)`` in time order -> the selected terms, ``(n_samples, n_terms)``.

        One trajectory or a list of them; memory and delay terms restart with each trajectory.
        """
        out = []
        for x in x_full:
            x = np.asarray(x, dtype=float)
            values = self.evaluate(x[:, 0], x[:, 1])
            out.append(AxesArray(
                np.column_stack([values[name] for name in self._selected()]),
                {"ax_time": 0, "ax_coord": 1},
            ))
        return out

    def get_feature_names(self, input_features=None):
        """Term names; ``input_features`` renames ``delta`` and ``u``."""
        names = list(self._selected())
        if input_features is not None:
            d, c = input_features
            names = [n.replace("delta", d).replace("u(", f"{c}(") for n in names]
        return names
