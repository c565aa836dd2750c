"""Search coordinates of a structure: a bounded box in which the fit's ridges lie along axes.

The natural parameters of the actuator are badly scaled (``K1`` ~ 3e5, ``z`` ~ 1e-3) and strongly
coupled, so every structure is searched in coordinates that follow what the data determine:

* linear block: ``log wn`` (``K3 = wn^2``), ``log zeta`` (``K2 = 2 zeta wn``), ``log g0``
  (``K1 = g0 K3``, the block's static gain, rad/s per rad) and ``log K``; the user may fix any of
  ``gain``, ``damping``, ``stiffness`` (e.g. from an ARX step-test fit, as paper 002 did), and the
  others are then searched as ``log K1``, ``log K2``, ``log K3``;
* dead zone on the error: ``log z`` (rad);
* dead zone on the velocity signal: the threshold while moving, ``c = z - off``
  (docs/models.md#what-a-recording-pins: only ``z - off`` is pinned by motion), as ``log(c / g0)`` (rad of error),
  and with friction the split ``lam = z / c`` (``off = z - c``; ``lam < 1`` is paper 001's negative
  offset);
* ``log r`` (backlash), ``Td`` (linear), ``log G`` and ``log(s / g0)`` (band-pass loop).

Bounds span the papers' values by a factor of 10 or more (structures and values are not tuned
to the papers). Any field may be fixed (``fixed``); fixed fields leave the box.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from tvcid.models.hypotheses import ActuatorParams, DeadZonePosition
from tvcid.models.structures import Structure

__all__ = ["Coordinate", "SearchSpace", "UnknownParameterError", "LINEAR_FIELDS"]

LINEAR_FIELDS = ("gain", "damping", "stiffness")
#: Floor of a value before its log in :meth:`SearchSpace.coordinates` (the box clips it).
TINY = 1e-300


class UnknownParameterError(ValueError):
    """A fixed parameter that the model does not have."""


@dataclass(frozen=True)
class Coordinate:
    """One search coordinate: name, bounds and whether it is the log of a positive quantity."""

    name: str
    low: float
    high: float


#: Bounds of each coordinate (internal units: natural logs where the name starts with log_).
BOUNDS = {
    "log_wn": (math.log(30.0), math.log(600.0)),
    "log_zeta": (math.log(0.15), math.log(4.0)),
    "log_g0": (math.log(3.0), math.log(300.0)),
    "log_K1": (math.log(1e4), math.log(3e7)),
    "log_K2": (math.log(10.0), math.log(3000.0)),
    "log_K3": (math.log(900.0), math.log(4e5)),
    "log_K": (math.log(0.4), math.log(2.5)),
    "log_z": (math.log(1e-5), math.log(3e-2)),
    "log_c_e": (math.log(1e-5), math.log(3e-2)),
    "lam": (0.0, 1.6),
    "log_off": (math.log(1e-5), math.log(0.3)),
    "log_r": (math.log(1e-6), math.log(3e-3)),
    "delay": (None, 0.02),  # low bound: one RK4 step (the kernel's shortest delay)
    "log_G": (math.log(3.0), math.log(300.0)),
    "log_s_e": (math.log(2e-5), math.log(5e-3)),
}


class SearchSpace:
    """The box of one structure, with the maps to and from :class:`ActuatorParams`.

    Parameters
    ----------
    structure : tvcid.models.structures.Structure
    base : ActuatorParams
        Supplies every field the search does not set (initial conditions, band of the filter).
    fixed : dict
        Known parts: field name -> value, used in every structure.
    dt : float
        RK4 step (s); the delay's low bound.
    """

    def __init__(self, structure: Structure, base: ActuatorParams, fixed: dict, dt: float):
        self.structure = structure
        self.base = base
        self.fixed = dict(fixed)
        self.dt = float(dt)
        known = set(ActuatorParams.parameter_names())
        unknown = sorted(set(self.fixed) - known)
        if unknown:
            raise UnknownParameterError(
                f"unknown parameter(s) {', '.join(unknown)} in --fix; known: {', '.join(sorted(known))}")
        names = []
        free = lambda n: n not in self.fixed  # noqa: E731
        if all(free(n) for n in LINEAR_FIELDS):
            names += ["log_wn", "log_zeta", "log_g0"]
        else:
            names += [c for c, n in zip(("log_K1", "log_K2", "log_K3"), LINEAR_FIELDS) if free(n)]
        if free("feedback_gain"):
            names.append("log_K")
        velocity = structure.dead_zone_position is DeadZonePosition.VELOCITY
        if not velocity:
            if free("dead_zone"):
                names.append("log_z")
        elif structure.friction:
            if free("dead_zone") and free("friction_offset"):
                names += ["log_c_e", "lam"]
            elif free("dead_zone"):
                names.append("log_z")
            elif free("friction_offset"):
                names.append("log_off")
        elif free("dead_zone"):
            names.append("log_c_e")
        if structure.backlash and free("backlash"):
            names.append("log_r")
        if free("delay"):
            names.append("delay")
        if structure.bandpass:
            if free("bandpass_gain"):
                names.append("log_G")
            if free("bandpass_saturation"):
                names.append("log_s_e")
        self.names = tuple(names)
        lows, highs = [], []
        for n in self.names:
            lo, hi = BOUNDS[n]
            lows.append(1.0001 * self.dt if lo is None else lo)
            highs.append(hi)
        self.low = np.array(lows)
        self.high = np.array(highs)

    @property
    def ndim(self) -> int:
        return len(self.names)

    def bounds(self):
        return list(zip(self.low, self.high))

    def narrowed(self, centre, half_width) -> "SearchSpace":
        """The same space with its box cut to ``centre +- half_width`` (``inf``: the whole axis)."""
        out = copy.copy(self)
        half = np.nan_to_num(np.asarray(half_width, dtype=float), nan=np.inf)
        out.low = np.maximum(self.low, centre - half)
        out.high = np.minimum(self.high, centre + half)
        return out

    # -- maps -----------------------------------------------------------------------------------
    def natural(self, theta) -> dict:
        """Field values of one coordinate vector (fixed fields included)."""
        v = dict(zip(self.names, np.asarray(theta, dtype=float)))
        f = self.fixed
        out = {}
        if "log_wn" in v:
            wn, zeta = math.exp(v["log_wn"]), math.exp(v["log_zeta"])
            out["stiffness"] = wn * wn
            out["damping"] = 2.0 * zeta * wn
            out["gain"] = math.exp(v["log_g0"]) * out["stiffness"]
        else:
            for c, n in zip(("log_K1", "log_K2", "log_K3"), LINEAR_FIELDS):
                out[n] = math.exp(v[c]) if c in v else float(f[n])
        g0 = out["gain"] / out["stiffness"]
        out["feedback_gain"] = math.exp(v["log_K"]) if "log_K" in v else float(f["feedback_gain"])
        s = self.structure
        if "log_z" in v:
            out["dead_zone"] = math.exp(v["log_z"])
        if "log_c_e" in v:
            c = math.exp(v["log_c_e"]) * g0
            if s.friction and "lam" in v:
                out["dead_zone"] = v["lam"] * c
                out["friction_offset"] = (v["lam"] - 1.0) * c
            elif s.friction:  # dead zone fixed
                out["friction_offset"] = float(f["dead_zone"]) - c
            else:
                out["dead_zone"] = c
        if "log_off" in v:
            out["friction_offset"] = -math.exp(v["log_off"])
        if "log_r" in v:
            out["backlash"] = math.exp(v["log_r"])
        if "delay" in v:
            out["delay"] = float(v["delay"])
        if "log_G" in v:
            out["bandpass_gain"] = math.exp(v["log_G"])
        if "log_s_e" in v:
            out["bandpass_saturation"] = math.exp(v["log_s_e"]) * g0
        for n, value in f.items():
            out.setdefault(n, value)
        return out

    def params(self, theta) -> ActuatorParams | None:
        """The parameter object of one coordinate vector, ``None`` if the values are invalid."""
        try:
            return self.structure.to_params(self.base, **self.natural(theta))
        except (ValueError, OverflowError):
            return None

    def coordinates(self, params: ActuatorParams) -> np.ndarray:
        """Coordinates of a parameter object (clipped into the box); the inverse of :meth:`params`.

        A value a log coordinate cannot hold (a SINDy seed with ``K2 = 0`` or a negative
        stiffness) goes to the box's edge on its side instead of raising.
        """
        p = params
        k1, k2, k3 = (max(v, TINY) for v in (p.gain, p.damping, p.stiffness))
        g0 = k1 / k3
        c = p.dead_zone - p.friction_offset
        value = {
            "log_wn": 0.5 * math.log(k3),
            "log_zeta": math.log(k2 / (2.0 * math.sqrt(k3))),
            "log_g0": math.log(g0),
            "log_K1": math.log(k1), "log_K2": math.log(k2),
            "log_K3": math.log(k3),
            "log_K": math.log(max(p.feedback_gain, TINY)),
            "log_z": math.log(max(p.dead_zone, TINY)),
            "log_c_e": math.log(max(c / g0, TINY)),
            "lam": p.dead_zone / c if c > 0 else 1.0,
            "log_off": math.log(max(-p.friction_offset, TINY)),
            "log_r": math.log(max(p.backlash, TINY)),
            "delay": p.delay,
            "log_G": math.log(max(p.bandpass_gain, TINY)),
            "log_s_e": math.log(max(min(p.bandpass_saturation, 1e300) / g0, TINY)),
        }
        theta = np.array([value[n] for n in self.names])
        return np.clip(theta, self.low, self.high)
