"""Experiments the actuator can be put through: the HWIL closed loop and open-loop commands.

The HWIL loop (paper 002 section 3, Fig. 2): vehicle ``theta'' = mu * delta``, PD controller with
null reference ``u = -Kp*(theta + Kd*theta')``. The HWIL ran vehicle and controller at 200 Hz;
``sample_rate`` holds the controller output between samples (zero-order hold), off by default.
A compensator ``F(s)`` in series with the PD and a bending mode of the vehicle are optional
(:mod:`tvcid.models.controllers`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .controllers import BendingMode, TransferFunction

__all__ = [
    "ClosedLoop",
    "OpenLoop",
    "CONTROLLER_A",
    "CONTROLLER_B",
    "OPEN_LOOP_WAVEFORMS",
]


def _finite(name, value, positive=False):
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number (got {value!r})") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite (got {value})")
    if positive and value <= 0:
        raise ValueError(f"{name} must be > 0 (got {value})")
    return value


@dataclass(frozen=True)
class ClosedLoop:
    """The HWIL limit-cycle test: vehicle ``mu/s^2`` and PD controller with null reference.

    ``u = -Kp (1 + Kd s) F(s) theta_m`` with the optional compensator ``F`` and the sensed
    attitude ``theta_m`` (the rigid attitude plus the optional bending mode).

    Parameters
    ----------
    kp : float
        Proportional gain ``Kp`` (rad of command per rad of attitude).
    kd : float
        Derivative time ``Kd`` (s): ``u = -Kp*(theta + Kd*theta')``.
    mu : float
        Vehicle control effectiveness ``mu`` (1/s^2): ``theta'' = mu*delta``.
    sample_rate : float or None
        Controller rate (Hz) for a zero-order hold of ``u``; ``None`` (default) is continuous.
    theta0, thetad0 : float
        Initial attitude (rad) and rate (rad/s).
    compensator : tvcid.models.controllers.TransferFunction or None
        Proper ``F(s)`` after the PD (lead/lag, notch, or any controller given as a transfer
        function with ``kp=1, kd=0``). Held at ``sample_rate`` it runs as its Tustin realisation.
    bending : tvcid.models.controllers.BendingMode or None
        Bending mode added to the sensed attitude.
    """

    kp: float
    kd: float
    mu: float
    sample_rate: float | None = None
    theta0: float = 0.0
    thetad0: float = 0.0
    compensator: TransferFunction | None = None
    bending: BendingMode | None = None

    kind = "closed"

    def __post_init__(self):
        for name in ("kp", "kd", "mu", "theta0", "thetad0"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.sample_rate is not None:
            object.__setattr__(self, "sample_rate", _finite("sample_rate", self.sample_rate, True))
        if self.compensator is not None and not isinstance(self.compensator, TransferFunction):
            object.__setattr__(self, "compensator", TransferFunction.from_dict(self.compensator))
        if self.bending is not None and not isinstance(self.bending, BendingMode):
            object.__setattr__(self, "bending", BendingMode.from_dict(self.bending))

    @property
    def is_plain_pd(self) -> bool:
        """No compensator and no bending mode: the loop of the papers."""
        return self.compensator is None and self.bending is None

    def compensator_response(self, frequency):
        """``F(jw)`` as the loop runs it: continuous, or Tustin at ``sample_rate``."""
        w = np.asarray(frequency, dtype=float)
        if self.compensator is None:
            return np.ones_like(w, dtype=complex)
        if self.sample_rate is None:
            return self.compensator.response(w)
        return self.compensator.discrete_response(w, self.sample_rate)

    def controller_response(self, frequency):
        """``C(jw) = Kp (1 + Kd jw) F(jw)``, times the zero-order hold's first-harmonic factor
        ``exp(-jwT/2) sin(wT/2)/(wT/2)`` when held at ``sample_rate``."""
        w = np.asarray(frequency, dtype=float)
        c = self.kp * (1.0 + 1j * w * self.kd) * self.compensator_response(w)
        if self.sample_rate is not None:
            half = 0.5 * w / self.sample_rate
            c = c * np.exp(-1j * half) * np.sinc(half / np.pi)
        return c

    def vehicle_response(self, frequency):
        """Sensed attitude per nozzle deflection: ``mu/(jw)^2`` plus the bending mode."""
        s = 1j * np.asarray(frequency, dtype=float)
        g = self.mu / (s * s)
        if self.bending is not None:
            g = g + self.bending.response(frequency)
        return g

    def to_dict(self) -> dict:
        out = {
            "kind": self.kind,
            "kp": self.kp,
            "kd": self.kd,
            "mu": self.mu,
            "sample_rate": self.sample_rate,
            "theta0": self.theta0,
            "thetad0": self.thetad0,
        }
        if self.compensator is not None:
            out["compensator"] = self.compensator.to_dict()
        if self.bending is not None:
            out["bending"] = self.bending.to_dict()
        return out


#: Paper 002 section 6 (HWIL limit cycle 4.89e-3 rad at 8.57 rad/s).
CONTROLLER_A = ClosedLoop(kp=5.84, kd=0.062, mu=12.3)
#: Paper 002 section 3, Fig. 3.
CONTROLLER_B = ClosedLoop(kp=9.8, kd=0.06, mu=4.5)

OPEN_LOOP_WAVEFORMS = ("step", "square", "sine", "samples", "piecewise")
#: How a ``samples`` command is read between its samples.
SAMPLE_INTERPOLATIONS = ("linear", "cubic")


@dataclass(frozen=True, eq=False)
class OpenLoop:
    """An open-loop test: the actuator driven by a given command ``u(t)`` (rad).

    Build one with :meth:`step`, :meth:`square`, :meth:`sine` or :meth:`from_samples`.

    Parameters
    ----------
    waveform : str
        One of ``step``, ``square``, ``sine``, ``samples``, ``piecewise``.
    amplitude : float
        Command amplitude (rad).
    frequency : float
        Frequency of square and sine commands (Hz).
    start : float
        Time of the step (s).
    offset : float
        Constant added to the command (rad).
    t_samples, u_samples : numpy.ndarray
        A sampled command for ``waveform='samples'``, interpolated (``interpolation``) and held
        before its first and after its last sample. For ``waveform='piecewise'``: the edge times
        (n) and the levels (n + 1) before, between and after them.
    from_rest : bool
        Start the actuator at rest (``y = y' = x = 0``), as a bench test does, whatever initial
        conditions the hypothesis carries for its closed-loop runs. Default True.
    interpolation : str
        ``linear`` (default) or ``cubic`` (a not-a-knot cubic spline) between the samples of a
        ``samples`` command. A smooth command known only as samples wants ``cubic``: linearly
        interpolated, a sine's chords lower its fundamental by ``(2 pi f h)^2 / 12`` (5.5e-4 of a
        2.6 Hz sine sampled at 200 Hz, about 1.2e-5 rad at 23 mrad, comparable to the sensor
        noise), where the spline's error is of order ``(2 pi f h)^4``.
    """

    waveform: str
    amplitude: float = 0.0
    frequency: float = 0.0
    start: float = 0.0
    offset: float = 0.0
    t_samples: np.ndarray | None = field(default=None, repr=False)
    u_samples: np.ndarray | None = field(default=None, repr=False)
    from_rest: bool = True
    interpolation: str = "linear"

    kind = "open"

    def __post_init__(self):
        if self.waveform not in OPEN_LOOP_WAVEFORMS:
            raise ValueError(
                f"unknown open-loop waveform {self.waveform!r}; choose one of "
                f"{', '.join(OPEN_LOOP_WAVEFORMS)}"
            )
        if self.interpolation not in SAMPLE_INTERPOLATIONS:
            raise ValueError(f"unknown interpolation {self.interpolation!r} of a sampled command; "
                             f"choose one of {', '.join(SAMPLE_INTERPOLATIONS)}")
        for name in ("amplitude", "frequency", "start", "offset"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.waveform in ("square", "sine") and self.frequency <= 0:
            raise ValueError(f"frequency must be > 0 for a {self.waveform} command")
        if self.waveform == "piecewise":
            t = np.atleast_1d(np.asarray(self.t_samples, dtype=float))
            u = np.atleast_1d(np.asarray(self.u_samples, dtype=float))
            if t.ndim != 1 or u.shape != (t.size + 1,):
                raise ValueError("a piecewise command needs n edge times and n + 1 levels")
            if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
                raise ValueError("the piecewise command holds NaN or infinite values")
            if np.any(np.diff(t) <= 0):
                raise ValueError("the edge times of a piecewise command must be strictly increasing")
            object.__setattr__(self, "t_samples", t)
            object.__setattr__(self, "u_samples", u)
        if self.waveform == "samples":
            t = np.asarray(self.t_samples, dtype=float)
            u = np.asarray(self.u_samples, dtype=float)
            if t.ndim != 1 or t.shape != u.shape or t.size < 2:
                raise ValueError("t_samples and u_samples must be 1-D of equal length >= 2")
            if self.interpolation == "cubic" and t.size < 4:
                raise ValueError("a cubic interpolation of a sampled command needs >= 4 samples")
            if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
                raise ValueError("the sampled command holds NaN or infinite values")
            if np.any(np.diff(t) <= 0):
                raise ValueError("t_samples must be strictly increasing")
            object.__setattr__(self, "t_samples", t)
            object.__setattr__(self, "u_samples", u)

    @classmethod
    def step(cls, amplitude, start=0.0):
        """``u = amplitude`` for ``t >= start``, else 0."""
        return cls("step", amplitude=amplitude, start=start)

    @classmethod
    def square(cls, amplitude, frequency, offset=0.0):
        """Square wave ``+-amplitude`` at ``frequency`` Hz, positive half first."""
        return cls("square", amplitude=amplitude, frequency=frequency, offset=offset)

    @classmethod
    def sine(cls, amplitude, frequency, offset=0.0):
        """``u = amplitude * sin(2 pi frequency t) + offset``."""
        return cls("sine", amplitude=amplitude, frequency=frequency, offset=offset)

    @classmethod
    def from_samples(cls, t, u, interpolation="linear"):
        """Any sampled command, interpolated between its samples (``linear`` or ``cubic``) and
        held constant before the first and after the last."""
        return cls("samples", t_samples=t, u_samples=u, interpolation=interpolation)

    @classmethod
    def piecewise(cls, edges, levels):
        """A piecewise-constant command: ``levels[i]`` from ``edges[i-1]`` to ``edges[i]``.

        ``u = levels[0]`` before the first edge and ``levels[-1]`` after the last; at an edge time
        the new level holds (as :meth:`square` and :meth:`step`). Square waves of any phase, steps
        and staircases known only as samples are replayed this way
        (:func:`tvcid.models.commands.command_from_samples`), with no ramp between samples.
        """
        return cls("piecewise", t_samples=edges, u_samples=levels)

    def command(self, t):
        """The command ``u(t)`` (rad) at the times ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        if self.waveform == "step":
            return np.where(t >= self.start, self.amplitude, 0.0)
        if self.waveform == "square":
            phase = np.mod(t * self.frequency, 1.0)
            return np.where(phase < 0.5, self.amplitude, -self.amplitude) + self.offset
        if self.waveform == "sine":
            return self.amplitude * np.sin(2 * np.pi * self.frequency * t) + self.offset
        if self.waveform == "piecewise":
            return self.u_samples[np.searchsorted(self.t_samples, t, side="right")]
        if self.interpolation == "cubic":
            from scipy.interpolate import CubicSpline

            ts, us = self.t_samples, self.u_samples
            inside = CubicSpline(ts, us)(np.clip(t, ts[0], ts[-1]))
            return np.where(t < ts[0], us[0], np.where(t > ts[-1], us[-1], inside))
        return np.interp(t, self.t_samples, self.u_samples)

    def solver_command(self, t, dt):
        """The command as the RK4 solver of step ``dt`` sees it at its stage times ``t``.

        Smooth commands are sampled. A command with jumps (step, square, piecewise) is averaged
        over the stage's share of Simpson's rule, which RK4 applies to the input: a node of the
        step grid stands for ``dt/3`` around it, a half-step point for ``2 dt/3``. Sampled at the
        stages, an edge between them would move to the next stage (up to half a step late: 0.25 ms
        at 5e-4 s, several noise units of a square-wave response); averaged, the input's
        integral is exact and the edge's effect lands within a small fraction of a step of its
        time. The average is the command's integral over the share, exact.
        Both the kernel (:mod:`tvcid.models.simulate`) and the reference path use this.
        """
        t = np.asarray(t, dtype=float)
        if self.waveform not in ("step", "square", "piecewise"):
            return self.command(t)
        on_node = np.mod(np.rint(2.0 * t / dt), 2) == 0
        half_width = np.where(on_node, dt / 6.0, dt / 3.0)
        edges, levels = self._jumps(float(np.max(t, initial=0.0)) + dt)
        # the run starts at t = 0: before it the command holds u(0) (a square's periodic
        # extension before 0 averaged its first node to 0, the start's step dt/6 late)
        start = np.concatenate([[0.0], edges])  # where each level begins (the first at 0)
        at_start = np.concatenate([[0.0], np.cumsum(levels[:-1] * np.diff(start))])

        def integral(x):  # of u(max(s, 0)) from 0 to x
            k = np.searchsorted(edges, x, side="right")
            return at_start[k] + levels[k] * (x - start[k]), k

        lo, k_lo = integral(t - half_width)
        hi, k_hi = integral(t + half_width)
        # within one level the level itself (no rounding from the difference of integrals)
        return np.where(k_lo == k_hi, levels[k_lo], (hi - lo) / (2.0 * half_width))

    def _jumps(self, t_max):
        """Edges after ``t = 0`` (s) up to past ``t_max``, and the levels (rad) between them:
        ``levels[0]`` = ``u(0)``, ``levels[j]`` after edge ``j - 1`` (step, square, piecewise)."""
        if self.waveform == "step":
            if self.start > 0:
                return np.array([self.start]), np.array([0.0, self.amplitude])
            return np.empty(0), np.array([self.amplitude])
        if self.waveform == "square":
            n = int(np.ceil(2.0 * self.frequency * max(t_max, 0.0))) + 1
            edges = np.arange(1, n + 1) / (2.0 * self.frequency)
            signs = np.where(np.arange(n + 1) % 2 == 0, 1.0, -1.0)
            return edges, self.amplitude * signs + self.offset
        after = self.t_samples > 0
        levels = np.concatenate([[float(self.command(0.0))], self.u_samples[1:][after]])
        return self.t_samples[after], levels

    def to_dict(self) -> dict:
        out = {
            "kind": self.kind,
            "waveform": self.waveform,
            "amplitude": self.amplitude,
            "frequency": self.frequency,
            "start": self.start,
            "offset": self.offset,
            "from_rest": self.from_rest,
        }
        return out
