"""Reference simulator in plain Python, written apart from the numba kernel to cross-check it.

It composes the element functions of :mod:`tvcid.models.nonlinearities`, a :class:`tvcid.models.delay.DelayLine` and
a generic RK4 stepper over a state dictionary, where the kernel fuses everything into one loop over
packed arrays. Both discretise the same way (RK4 on a fixed grid, the delay line interpolated
linearly between grid points, the play memory updated once per step, the friction offset's jump
located inside the step by :func:`tvcid.models.nonlinearities.sign_switch_average`), so they agree to
round-off on periodic cycles; it is ~500x slower and meant for tests and the benchmark only.

The compensator is realised here independently of :mod:`tvcid.models.controllers`' own realisations:
continuous, in observable canonical form built from ``num``/``den``; held, as the difference
equation of its Tustin transform (polynomials in ``z`` from the substitution
``s = 2/h (z - 1)/(z + 1)``). So the cross-check also covers ``state_space`` and ``discretise``.
"""
from __future__ import annotations

import numpy as np

from .delay import DelayLine
from .experiments import ClosedLoop, OpenLoop
from .hypotheses import ActuatorParams, DeadZonePosition, DelayPosition
from .linear import bandpass_state_space
from .noise import band_limited_white_noise
from .nonlinearities import dead_zone, friction_offset, play_step, saturation, sign_switch_average
from .simulate import (
    DEFAULT_BOUND,
    DEFAULT_DT,
    SimulationDiverged,
    Trajectory,
    _check_grid,
)

__all__ = ["simulate_reference"]


def _scalar(fn, *args):
    return float(fn(*args))


def _padded(tf):
    """``(b, a)``: numerator padded to the denominator's length, both divided by ``a[0]``."""
    a = np.asarray(tf.den, dtype=float)
    b = np.zeros(a.size)
    b[a.size - len(tf.num):] = tf.num
    return b / a[0], a / a[0]


class _ContinuousFilter:
    """``F(s)`` in observable canonical form: ``y = x[0] + b0 v``,
    ``x[i]' = x[i+1] - a[i+1] x[0] + (b[i+1] - a[i+1] b0) v`` (``x[n] = 0``)."""

    def __init__(self, tf):
        self.b, self.a = _padded(tf)
        self.n = self.a.size - 1

    def output(self, x, v):
        return (x[0] if self.n else 0.0) + self.b[0] * v

    def derivative(self, x, v):
        dx = np.zeros(self.n)
        for i in range(self.n):
            nxt = x[i + 1] if i + 1 < self.n else 0.0
            dx[i] = nxt - self.a[i + 1] * x[0] + (self.b[i + 1] - self.a[i + 1] * self.b[0]) * v
        return dx


class _TustinFilter:
    """``F`` at the sample period ``h`` as the difference equation of ``F(2/h (z-1)/(z+1))``:
    ``y[k] = sum bz[i] v[k-i] - sum_{i>0} az[i] y[k-i]`` (past values start at 0)."""

    def __init__(self, tf, h):
        b, a = _padded(tf)
        n = a.size - 1
        zm1, zp1 = np.array([1.0, -1.0]), np.array([1.0, 1.0])
        bz, az = np.zeros(n + 1), np.zeros(n + 1)
        for k in range(n + 1):  # s^(n-k) times (z+1)^n becomes (2/h)^(n-k) (z-1)^(n-k) (z+1)^k
            term = (2.0 / h) ** (n - k) * np.polymul(np.poly1d(zm1) ** (n - k), np.poly1d(zp1) ** k).coeffs
            bz += b[k] * term
            az += a[k] * term
        self.bz, self.az = bz / az[0], az / az[0]
        self.v_past = [0.0] * n
        self.y_past = [0.0] * n

    def step(self, v):
        y = self.bz[0] * v
        for i in range(1, self.bz.size):
            y += self.bz[i] * self.v_past[i - 1] - self.az[i] * self.y_past[i - 1]
        self.v_past = [v] + self.v_past[:-1]
        self.y_past = [y] + self.y_past[:-1]
        return y


def simulate_reference(
    params: ActuatorParams,
    experiment,
    t_end: float,
    dt: float = DEFAULT_DT,
    rate: float | None = None,
    bound: float = DEFAULT_BOUND,
) -> Trajectory:
    """Plain-Python counterpart of :func:`tvcid.models.simulate.simulate` (same arguments and output)."""
    n_steps, decimation = _check_grid(t_end, dt, rate)
    closed = isinstance(experiment, ClosedLoop)
    if not closed and not isinstance(experiment, OpenLoop):
        raise TypeError("experiment must be a ClosedLoop or an OpenLoop")
    at_rest = not closed and experiment.from_rest
    r = params.backlash
    has_delay = params.delay > 0
    if has_delay and params.delay < dt * (1 - 1e-9):
        raise ValueError(f"delay ({params.delay} s) is shorter than the step dt ({dt} s)")
    line = DelayLine(params.delay, dt) if has_delay else None
    where = params.delay_position if has_delay else None

    if params.has_bandpass_loop:
        bp_a, bp_b, bp_c = bandpass_state_space(
            params.bandpass_low_hz, params.bandpass_high_hz, params.bandpass_order
        )
    else:
        bp_a, bp_b, bp_c = np.zeros((0, 0)), np.zeros(0), np.zeros(0)
    noise = None
    if params.noise_power > 0:
        noise = band_limited_white_noise(
            params.noise_power, params.noise_band, t_end, np.random.default_rng(params.noise_seed)
        )
        noise_rate = 2.0 * params.noise_band

    state = {
        "theta": experiment.theta0 if closed else 0.0,
        "thetad": experiment.thetad0 if closed else 0.0,
        "y": 0.0 if at_rest else params.y0,
        "yd": 0.0 if at_rest else params.yd0,
        "x": 0.0 if at_rest else params.x0,
        "bp": np.zeros(bp_a.shape[0]),
    }
    memory = play_step(0.0, state["x"], r)
    hold = None
    if closed and experiment.sample_rate is not None:
        hold = int(round(1.0 / (experiment.sample_rate * dt)))
    u_held = 0.0
    # compensator F(s) after the PD, and the bending mode q seen by the attitude sensor
    bending = experiment.bending if closed else None
    compensator = experiment.compensator if closed else None
    continuous_filter = held_filter = None
    if compensator is not None and hold is None:
        continuous_filter = _ContinuousFilter(compensator)
        state["comp"] = np.zeros(continuous_filter.n)
    elif compensator is not None:
        held_filter = _TustinFilter(compensator, 1.0 / experiment.sample_rate)
    if bending is not None:
        state["q"] = 0.0
        state["qd"] = 0.0

    def pd_output(st):
        """``v = Kp (theta_m + Kd theta_m')``, the PD acting on the sensed attitude."""
        theta_m, rate_m = st["theta"], st["thetad"]
        if bending is not None:
            theta_m, rate_m = theta_m + st["q"], rate_m + st["qd"]
        return experiment.kp * (theta_m + experiment.kd * rate_m)

    def command(t, st):
        if not closed:
            return float(experiment.solver_command(t, dt))
        if hold is not None:
            return u_held
        if continuous_filter is not None:
            return -continuous_filter.output(st["comp"], pd_output(st))
        return -pd_output(st)

    switch = [None] * 4  # the friction offset's switching signal and sign at each RK4 stage
    z_switch = params.dead_zone if params.dead_zone_position is DeadZonePosition.VELOCITY else 0.0

    def acceleration(u, b, st):
        e = u - params.feedback_gain * b
        if params.dead_zone_position is DeadZonePosition.ERROR:
            e = _scalar(dead_zone, e, params.dead_zone)
        return params.gain * e - params.damping * st["yd"] - params.stiffness * st["y"]

    def evaluate(t, st, store, stage, u_before=None):
        """Derivatives and the recorded signals at time ``t`` and state ``st``; ``u_before``: the
        held command just before it changed at this node (the delay line's left value)."""
        u = command(t, st)
        b = play_step(memory, st["x"], r)
        accel = acceleration(u, b, st)
        if store and line is not None:
            left = None
            if where is DelayPosition.BEFORE_FIRST_INTEGRATOR and u_before is not None:
                left = acceleration(u_before, b, st)
            line.write({DelayPosition.OUTPUT: st["x"], DelayPosition.BEFORE_INTEGRATOR: st["y"],
                        DelayPosition.BEFORE_FIRST_INTEGRATOR: accel}[where], left)
        v, out = st["y"], st["x"]
        if where is DelayPosition.BEFORE_FIRST_INTEGRATOR:
            # a held command's jumps averaged over the stage's share of the step
            share = 0.0 if hold is None else (dt / 3.0 if stage in (1, 2) else dt / 6.0)
            accel = line.read(t, share)
        elif where is DelayPosition.BEFORE_INTEGRATOR:
            v = line.read(t)
        elif where is DelayPosition.OUTPUT:
            out = line.read(t)
        p = 0.0
        if params.has_bandpass_loop:
            p = _scalar(saturation, params.bandpass_gain * float(bp_c @ st["bp"]),
                        params.bandpass_saturation)
        q = q_switch = v + p
        if params.dead_zone_position is DeadZonePosition.VELOCITY:
            q = _scalar(dead_zone, q, params.dead_zone)
        w = _scalar(friction_offset, q, params.friction_offset)
        switch[stage] = (q_switch, float(np.sign(q)))
        delta = out
        if noise is not None:
            delta += noise[min(int(t * noise_rate + 1e-9), noise.size - 1)]
        deriv = {
            "theta": st["thetad"],
            "thetad": experiment.mu * delta if closed else 0.0,
            "y": st["yd"],
            "yd": accel,
            "x": w,
            "bp": bp_a @ st["bp"] + bp_b * w,
        }
        if continuous_filter is not None:
            deriv["comp"] = continuous_filter.derivative(st["comp"], pd_output(st))
        if bending is not None:
            wb = bending.frequency
            deriv["q"] = st["qd"]
            deriv["qd"] = (bending.gain * wb * wb * delta - 2.0 * bending.damping * wb * st["qd"]
                           - wb * wb * st["q"])
        return deriv, (t, u, delta, st["theta"], st["x"], st["y"], w, b)

    def advance(st, deriv, h):
        return {key: st[key] + h * deriv[key] for key in st}

    rows = []
    for k in range(n_steps + 1):
        # stage times as the kernel forms them (command edges land on the same side)
        t, t_half, t_full = 0.5 * dt * (2 * k), 0.5 * dt * (2 * k + 1), 0.5 * dt * (2 * k + 2)
        u_before = None
        if hold is not None and k % hold == 0:
            u_before = u_held if k > 0 else None
            v = pd_output(state)
            u_held = -(held_filter.step(v) if held_filter is not None else v)
        k1, record = evaluate(t, state, store=True, stage=0, u_before=u_before)
        if k % decimation == 0:
            rows.append(record)
        if k == n_steps:
            break
        k2, _ = evaluate(t_half, advance(state, k1, dt / 2), store=False, stage=1)
        k3, _ = evaluate(t_half, advance(state, k2, dt / 2), store=False, stage=2)
        k4, _ = evaluate(t_full, advance(state, k3, dt), store=False, stage=3)
        state = {
            key: state[key] + dt / 6 * (k1[key] + 2 * k2[key] + 2 * k3[key] + k4[key])
            for key in state
        }
        signs = [sign for _, sign in switch]
        if params.friction_offset != 0 and len(set(signs)) > 1:
            # the offset's jump located inside the step, not at RK4's stage weights
            rk4_mean = (signs[0] + 2 * signs[1] + 2 * signs[2] + signs[3]) / 6
            jump = dt * params.friction_offset * (
                sign_switch_average(switch[0][0], switch[3][0], z_switch) - rk4_mean)
            state["x"] = state["x"] + jump
            state["bp"] = state["bp"] + jump * bp_b
        memory = play_step(memory, state["x"], r)
        if not all(np.all(np.isfinite(v)) for v in state.values()):
            raise SimulationDiverged(f"{params.name} (reference) became non-finite at t = {t:.4g} s")
        if abs(state["x"]) > bound or abs(state["theta"]) > bound:
            raise SimulationDiverged(f"{params.name} (reference) exceeded the bound at t = {t:.4g} s")
    columns = np.array(rows).T
    if not closed:  # u as commanded, not the solver's stage average
        columns[1] = experiment.command(columns[0])
    return Trajectory(*columns, params=params, experiment=experiment, dt=dt)
