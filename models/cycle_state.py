"""The closed loop's state on a recorded limit cycle: where a simulation that is to reproduce a
record starts.

A model whose cycle coexists with a stable rest (docs/models.md#what-a-recording-pins: "initial
conditions select the limit cycle") shows the cycle only from a start near it. Started with the
vehicle at rest it can settle at rest, however well its cycle fits the record. Every closed-loop
comparison (the structure search's cycle targets, the calibration's likelihood terms) starts its
runs from the state this module reads off the record.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .cycle_reading import crossing_harmonics
from .hypotheses import DeadZonePosition

__all__ = ["RecordedCycleState", "CYCLE_STATE_HARMONICS"]

#: Harmonics of the recorded cycle the state is built from.
CYCLE_STATE_HARMONICS = 7


@dataclass(frozen=True)
class RecordedCycleState:
    """The loop's state at an upward mean crossing of a recorded cycle.

    Attributes
    ----------
    theta : float
        Vehicle attitude on the cycle (rad).
    thetad : float
        Vehicle rate (rad/s).
    x : float
        Actuator position about the cycle's mean (rad).
    y : float
        The integrator's input, the recorded rate ``x'`` (rad/s).
    theta_mean_command : float
        The attitude at which the controller's command is its recorded mean (rad): the
        structure search's start (:meth:`experiment`).
    """

    theta: float
    thetad: float
    x: float
    y: float
    theta_mean_command: float

    @classmethod
    def from_cycle(cls, recording, t, delta, crossings, omega, n_harmonics=CYCLE_STATE_HARMONICS):
        """The state at the first of ``crossings`` (upward mean crossings of ``delta`` at the
        times ``t``, s from the record's first sample), from the cycle's Fourier series
        (:func:`tvcid.models.cycle_reading.crossing_harmonics`).

        ``delta = mean + sum Re(a_k e^{i k w t})`` over whole periods between the first and the
        last crossing: ``x = delta``, ``y = delta'``, the vehicle's ``theta' = mu integral(delta)``
        and ``theta = mean(theta) + mu double integral(delta)``, the mean set by the controller's
        law ``u = -Kp (theta + Kd theta')``: ``-mean(u) / Kp`` (0 where the record holds no
        command). ``theta_mean_command = -mean(u)/Kp - Kd theta'`` puts the command at its mean
        instead. Started there, a simulation of a model close to the data is close to its cycle:
        the slow growth of the cycle from a bare kick (over 10 s at controller B) is skipped, and
        a model whose rest is stable too is not left at rest.
        """
        exp = recording.experiment()
        a = crossing_harmonics(t, delta, crossings, omega, n_harmonics)  # at the first crossing
        kw = np.arange(1, n_harmonics + 1) * omega
        x = float(np.sum(a.real))
        y = float(np.sum((1j * kw * a).real))
        thetad = float(exp.mu * np.sum((a / (1j * kw)).real))
        u = recording.columns.get("u")  # none recorded: the null reference's mean, 0
        u = None if u is None else np.asarray(u)[recording.t - recording.t[0] >= t[0]]
        mean = -float(np.mean(u)) / exp.kp if u is not None and u.size and exp.kp != 0 else 0.0
        theta = mean + float(exp.mu * np.sum((a / (1j * kw) ** 2).real))
        return cls(theta=theta, thetad=thetad, x=x, y=y,
                   theta_mean_command=mean - exp.kd * thetad)

    def experiment(self, experiment, attitude="mean command"):
        """``experiment`` (a :class:`tvcid.models.experiments.ClosedLoop`) with the vehicle at this state.

        ``attitude``: ``"mean command"``, :attr:`theta_mean_command`, where every closed-loop
        comparison starts, or ``"cycle"``, the cycle's own. A run from the cycle's attitude
        follows the recorded cycle, phase included (over 5 s, 1-2 % of the cycle's rms off for
        M000 at B and M002 at A and B, 11 % for M000 at A, whose band-pass loop does not lock to
        the cycle); from the mean command's it settles on the cycle with its phase shifted
        (39-54 % off; ``tests/test_cycle_state.py``). The comparisons are phase-free or align
        the phase; their checks on records that still settle and on a period-2 cycle
        (``tests/test_settling_records.py``, ``tests/test_calibration_features.py``) hold from
        the mean command's attitude and not all from the cycle's.
        """
        if attitude not in ("cycle", "mean command"):
            raise ValueError(f"attitude {attitude!r}: 'cycle' or 'mean command'")
        theta = self.theta if attitude == "cycle" else self.theta_mean_command
        return dataclasses.replace(experiment, theta0=theta, thetad0=self.thetad)

    def initial_conditions(self, params=None):
        """Actuator initial conditions (fields of :class:`tvcid.models.ActuatorParams`) of a run of
        ``params`` from this state.

        ``x' = FRIC(DZ(y + p))`` (docs/models.md#m001f): while the actuator moves, the velocity
        signal ``y`` exceeds the recorded rate ``x'`` by the threshold ``z - off`` (dead zone on the
        velocity signal) or ``-off`` (on the error), in the direction of motion. Started with
        ``y = x'`` instead, inside the dead zone, a model with coexisting cycles can settle on one
        the record does not show. Without ``params``, ``y = x'``.
        """
        y = self.y
        if params is not None and y != 0.0:
            z = params.dead_zone if params.dead_zone_position is DeadZonePosition.VELOCITY else 0.0
            y += math.copysign(max(z - params.friction_offset, 0.0), y)
        return {"x0": self.x, "y0": y, "yd0": 0.0}
