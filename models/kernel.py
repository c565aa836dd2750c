"""The fixed-step numba kernel: classic RK4 with an exact transport delay and a play operator.

The kernel is a pure function of packed arrays; :mod:`tvcid.models.simulate` packs the dataclasses and
unpacks the result. Conventions are those of ``docs/models.md#conventions``:

* the transport delay outputs 0 before ``t = Td - dt`` and interpolates its stored input linearly
  between grid points and a 0 one step before ``t = 0`` (continuous in ``Td``; the input is
  stored on the step grid, so ``Td >= dt`` is required); a
  run continued from a cycle state (``P_HIST_ON``) outputs the given history line instead;
* the play operator's memory is updated once per step; the RK4 stages clamp the memory of the
  step start to their own ``x`` (the rate-independent operator evaluated along the stage);
* ``sign(0) = 0`` in the friction offset, whose jump is located inside the step: RK4's weighted
  mean of the offset over the stages is replaced by its mean with the switching signal linear
  between the first and last stages (:func:`tvcid.models.nonlinearities.sign_switch_average`), so the
  cycle does not lock to the step grid;
* closed loop, ``u = -(C x_c + D v)`` with ``v = Kp (theta_m + Kd theta_m')``: the compensator's
  output for the input ``v`` (``D = 1`` and no states without a compensator, which is bit for bit
  ``u = -Kp (theta + Kd theta')``); ``theta_m = theta + q`` adds the bending mode's ``q`` when there
  is one. Continuous, the compensator's states are RK4 states; held (``C_HOLD_STEPS > 0``), its
  Tustin realisation steps once per sample and ``u`` is held between samples. The bending mode's
  ``q, q'`` are always RK4 states, driven by the same ``delta`` as the vehicle. Compensator and
  bending states start at 0. The output row ``theta`` is the rigid attitude, not ``theta_m``.

The slots of the packed vectors are named by the module constants below; nothing outside this
module and :mod:`tvcid.models.simulate` should index them.
"""
from __future__ import annotations

import math
import os

# numba's OpenMP workers spin after a parallel batch and starve BLAS calls that follow it (matrix
# products measured 2-700x slower); passive waiting costs the batch nothing. Set before the OpenMP
# runtime loads; a value the user exported wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from numba import njit, prange  # noqa: E402

# -- packed actuator parameters ---------------------------------------------------------------
P_GAIN, P_DAMPING, P_STIFFNESS, P_FEEDBACK = 0, 1, 2, 3
P_DEAD_ZONE, P_DZ_ON_VELOCITY, P_BACKLASH, P_FRICTION = 4, 5, 6, 7
P_DELAY_STEPS, P_DELAY_WHERE, P_BP_GAIN, P_BP_SAT = 8, 9, 10, 11
P_Y0, P_YD0, P_X0, P_N_BP, P_NOISE_RATE = 12, 13, 14, 15, 16
#: a continued run (a warm start on a cycle): the play memory at t = 0 (NaN: the default
#: clamp of 0 to [x0 - r, x0 + r]) and, when P_HIST_ON, the delayed signal before t = 0 as
#: ``value + slope * t`` (t < 0) instead of the delay's 0
P_MEMORY0, P_HIST_ON, P_HIST_VALUE, P_HIST_SLOPE = 17, 18, 19, 20
N_PARAMS = 21

#: values of the P_DELAY_WHERE slot
DELAY_NONE, DELAY_OUTPUT, DELAY_BEFORE_INTEGRATOR, DELAY_BEFORE_FIRST_INTEGRATOR = 0, 1, 2, 3

# -- packed experiment ------------------------------------------------------------------------
C_CLOSED, C_KP, C_KD, C_MU, C_HOLD_STEPS, C_THETA0, C_THETAD0, C_BOUND = 0, 1, 2, 3, 4, 5, 6, 7
#: compensator order n and feedthrough D (1 without a compensator); bending frequency (rad/s,
#: 0 = no bending mode), damping and gain
C_N_COMP, C_COMP_D, C_BEND_W, C_BEND_ZETA, C_BEND_GAIN = 8, 9, 10, 11, 12
#: length of the fixed slots; the compensator's A (n*n, row-major), B (n) and C (n) follow from
#: C_COMP_MATRICES (continuous realisation, or the Tustin one when held)
N_CONTROL = 13
C_COMP_MATRICES = N_CONTROL

#: rows of the output array
SIGNALS = ("t", "u", "delta", "theta", "x", "y", "w", "backlash")
N_SIGNALS = len(SIGNALS)

#: status codes
OK, NON_FINITE, OUT_OF_BOUND = 0, 1, 2

N_CORE_STATES = 5  # theta, theta', y, y', x


def control_length(n_comp):
    """Length of a packed experiment whose compensator has ``n_comp`` states."""
    return N_CONTROL + n_comp * n_comp + 2 * n_comp


@njit(cache=True)
def _dead_zone(q, z):
    if q > z:
        return q - z
    if q < -z:
        return q + z
    return 0.0


@njit(cache=True)
def _acceleration(u, b, kfb, dz_vel, z, k1g, k2, k3, y, yd):
    """``y''`` of the second-order block for command ``u`` and play output ``b``
    (``docs/models.md#the-actuator``)."""
    e = u - kfb * b
    g = e if dz_vel else _dead_zone(e, z)
    return k1g * g - k2 * yd - k3 * y


@njit(cache=True)
def _fraction_above(a, b, c):
    if a > c and b > c:
        return 1.0
    if a <= c and b <= c:
        return 0.0
    crossing = (c - a) / (b - a)
    return 1.0 - crossing if b > c else crossing


@njit(cache=True)
def _sign_switch_average(q_start, q_end, z):
    """The kernel's :func:`tvcid.models.nonlinearities.sign_switch_average`."""
    return _fraction_above(q_start, q_end, z) - _fraction_above(-q_start, -q_end, z)


@njit(cache=True)
def simulate_kernel(p, ctrl, bp_a, bp_b, bp_c, u_cmd, noise, dt, n_steps, decimation, out):
    """Integrate one run; fill ``out[N_SIGNALS, n_steps // decimation + 1]``.

    Parameters
    ----------
    p : float64[N_PARAMS]
        Packed actuator parameters; the delay is given in steps (``Td/dt``, may be fractional).
    ctrl : float64[:]
        Packed experiment, ``control_length(n)`` slots or more (padding is ignored).
    bp_a, bp_b, bp_c : float64 arrays
        Band-pass state space (only the first ``p[P_N_BP]`` states are used).
    u_cmd : float64[2*n_steps + 1]
        Open-loop command on the half-step grid (ignored in closed loop).
    noise : float64[:]
        Output noise held over samples of rate ``p[P_NOISE_RATE]`` (ignored when that is 0).
    dt : float
    n_steps, decimation : int
    out : float64[N_SIGNALS, :] or float64[1, :]
        Every signal of ``SIGNALS``, or (one row) ``delta`` alone.

    Returns
    -------
    status : int
        ``OK``, ``NON_FINITE`` or ``OUT_OF_BOUND``.
    step : int
        Step at which the run was stopped (``n_steps`` when it finished).
    """
    # The papers' loop runs a specialisation compiled without the compensator and bending code
    # (numba prunes the branches on ``extended is None``), so it costs what it did before them.
    closed = ctrl[C_CLOSED] > 0.5
    if not closed or (
        ctrl[C_N_COMP] == 0.0 and ctrl[C_BEND_W] == 0.0 and ctrl[C_COMP_D] == 1.0
    ):
        return _integrate(p, ctrl, bp_a, bp_b, bp_c, u_cmd, noise, dt, n_steps, decimation, out,
                          None)
    return _integrate(p, ctrl, bp_a, bp_b, bp_c, u_cmd, noise, dt, n_steps, decimation, out, ctrl)


@njit(cache=True)
def _integrate(p, ctrl, bp_a, bp_b, bp_c, u_cmd, noise, dt, n_steps, decimation, out, extended):
    """The body of :func:`simulate_kernel`; ``extended`` is None for the plain PD loop."""
    k1g, k2, k3, kfb = p[P_GAIN], p[P_DAMPING], p[P_STIFFNESS], p[P_FEEDBACK]
    z, dz_vel, r, off = p[P_DEAD_ZONE], p[P_DZ_ON_VELOCITY] > 0.5, p[P_BACKLASH], p[P_FRICTION]
    delay_steps, where = p[P_DELAY_STEPS], int(p[P_DELAY_WHERE])
    bp_gain, bp_sat, nbp = p[P_BP_GAIN], p[P_BP_SAT], int(p[P_N_BP])
    noise_rate = p[P_NOISE_RATE]
    closed = ctrl[C_CLOSED] > 0.5
    kp, kd, mu = ctrl[C_KP], ctrl[C_KD], ctrl[C_MU]
    hold = int(ctrl[C_HOLD_STEPS])
    bound = ctrl[C_BOUND]
    ncomp = int(ctrl[C_N_COMP]) if closed else 0
    comp_d = ctrl[C_COMP_D]
    comp_a = np.zeros((ncomp, ncomp))
    comp_b = np.zeros(ncomp)
    comp_c = np.zeros(ncomp)
    o = C_COMP_MATRICES
    for i in range(ncomp):
        for jj in range(ncomp):
            comp_a[i, jj] = ctrl[o + i * ncomp + jj]
        comp_b[i] = ctrl[o + ncomp * ncomp + i]
        comp_c[i] = ctrl[o + ncomp * ncomp + ncomp + i]
    bend_w = ctrl[C_BEND_W] if closed else 0.0
    bend_2zw = 2.0 * ctrl[C_BEND_ZETA] * bend_w
    bend_w2 = bend_w * bend_w
    bend_gw2 = ctrl[C_BEND_GAIN] * bend_w2
    # RK4 states: core, band-pass, compensator (continuous only), bending q and q'
    ic = N_CORE_STATES + nbp
    nc_rk = ncomp if hold == 0 else 0
    ib = ic + nc_rk
    nbend = 2 if bend_w > 0.0 else 0
    x_held = np.zeros(ncomp)  # the Tustin realisation's state when the controller is held
    x_next = np.zeros(ncomp)

    ns = ib + nbend
    s = np.zeros(ns)
    ss = np.zeros(ns)
    kk = np.zeros((4, ns))
    s[0], s[1] = ctrl[C_THETA0], ctrl[C_THETAD0]
    s[2], s[3], s[4] = p[P_Y0], p[P_YD0], p[P_X0]
    memory = min(max(0.0, s[4] - r), s[4] + r)
    if not math.isnan(p[P_MEMORY0]):
        memory = min(max(p[P_MEMORY0], s[4] - r), s[4] + r)
    hist_on = p[P_HIST_ON] > 0.5
    hist_value, hist_slope = p[P_HIST_VALUE], p[P_HIST_SLOPE]

    # Delay line on the step grid: for the stage times t_k + c*dt (c = 0, 1/2, 1) the delayed
    # time is t_{k+shift} + frac*dt with a constant shift and fraction.
    # a power of two, so that the ring's index is a mask, not a division
    hist_len = 1
    while hist_len < int(math.ceil(delay_steps)) + 3:
        hist_len *= 2
    mask = hist_len - 1
    hist = np.zeros(hist_len)
    # a held command jumps at nodes; before the first integrator the line keeps each node's value
    # just before the jump too, jumps at the node's delayed time and averages the jump over the
    # stage's share of the step (tvcid.models.delay.DelayLine)
    jumps = closed and hold > 0 and where == DELAY_BEFORE_FIRST_INTEGRATOR
    hist_left = np.zeros(hist_len)
    share = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 6.0)  # of a step, by half-step index
    u_before = 0.0
    shift = np.zeros(3, dtype=np.int64)
    frac = np.zeros(3)
    for ci in range(3):
        q = 0.5 * ci - delay_steps
        fq = math.floor(q)
        shift[ci] = int(fq)
        frac[ci] = q - fq

    u_held = 0.0
    vc = 0.0  # the PD output, the compensator's input
    z_switch = z if dz_vel else 0.0
    q_stage = np.zeros(4)  # the friction offset's switching signal and sign at each RK4 stage
    sign_stage = np.zeros(4)
    n_noise = noise.shape[0]
    stage_c = (0, 1, 1, 2)  # half-step index of each RK4 stage
    for k in range(n_steps + 1):
        edge = False
        if closed and hold > 0 and k % hold == 0:
            u_before = u_held
            edge = k > 0
            if extended is None:
                u_held = -kp * (s[0] + kd * s[1])
            else:
                th, thd = s[0], s[1]
                if nbend:
                    th += s[ib]
                    thd += s[ib + 1]
                vc = kp * (th + kd * thd)
                acc = comp_d * vc
                for i in range(ncomp):
                    acc += comp_c[i] * x_held[i]
                u_held = -acc
                for i in range(ncomp):  # output first, then the update, as a digital controller
                    acc = comp_b[i] * vc
                    for jj in range(ncomp):
                        acc += comp_a[i, jj] * x_held[jj]
                    x_next[i] = acc
                for i in range(ncomp):
                    x_held[i] = x_next[i]
        last_stage = 0 if k == n_steps else 3
        for stage in range(last_stage + 1):
            if stage == 0:
                for i in range(ns):
                    ss[i] = s[i]
            else:
                h = 0.5 * dt if stage < 3 else dt
                for i in range(ns):
                    ss[i] = s[i] + h * kk[stage - 1, i]
            ci = stage_c[stage]
            if closed:
                if hold > 0:
                    u = u_held
                elif extended is None:
                    u = -kp * (ss[0] + kd * ss[1])
                else:
                    th, thd = ss[0], ss[1]
                    if nbend:
                        th += ss[ib]
                        thd += ss[ib + 1]
                    vc = kp * (th + kd * thd)
                    acc = comp_d * vc
                    for i in range(nc_rk):
                        acc += comp_c[i] * ss[ic + i]
                    u = -acc
            else:
                u = u_cmd[2 * k + ci]
            xs = ss[4]
            b = min(max(memory, xs - r), xs + r)
            ydd = _acceleration(u, b, kfb, dz_vel, z, k1g, k2, k3, ss[2], ss[3])
            v = ss[2]
            xd = xs
            if where != DELAY_NONE:
                if stage == 0:
                    if where == DELAY_OUTPUT:
                        hist[k & mask] = xs
                    elif where == DELAY_BEFORE_INTEGRATOR:
                        hist[k & mask] = v
                    else:
                        hist[k & mask] = ydd
                        if jumps:
                            hist_left[k & mask] = (
                                _acceleration(u_before, b, kfb, dz_vel, z, k1g, k2, k3, ss[2], ss[3])
                                if edge else ydd)
                j = k + shift[ci]
                fr = frac[ci]
                delayed = 0.0
                if j >= 0:
                    delayed = (1.0 - fr) * hist[j & mask]
                    if fr > 0.0:
                        delayed += fr * (hist_left[(j + 1) & mask] if jumps
                                         else hist[(j + 1) & mask])
                    if jumps:
                        wsh = share[ci]
                        if fr < wsh:
                            jj = j & mask
                            delayed -= (hist[jj] - hist_left[jj]) * (wsh - fr) / (2.0 * wsh)
                        if fr > 0.0 and fr + wsh > 1.0:
                            jj = (j + 1) & mask
                            delayed += (hist[jj] - hist_left[jj]) * (fr + wsh - 1.0) / (2.0 * wsh)
                elif j == -1 and not hist_on:
                    # from the line's 0 before t = 0 to the first sample: continuous in Td
                    delayed = fr * hist[0]
                elif hist_on:  # before t = 0: the given history line, then the stored input
                    delayed = (1.0 - fr) * (hist_value + hist_slope * j * dt)
                    if fr > 0.0:
                        if j + 1 < 0:
                            delayed += fr * (hist_value + hist_slope * (j + 1) * dt)
                        else:
                            delayed += fr * hist[(j + 1) & mask]
                if where == DELAY_OUTPUT:
                    xd = delayed
                elif where == DELAY_BEFORE_INTEGRATOR:
                    v = delayed
                else:
                    ydd = delayed
            pfb = 0.0
            if bp_gain > 0.0:
                acc = 0.0
                for i in range(nbp):
                    acc += bp_c[i] * ss[N_CORE_STATES + i]
                pfb = min(max(bp_gain * acc, -bp_sat), bp_sat)
            q = v + pfb
            q_stage[stage] = q
            if dz_vel:
                q = _dead_zone(q, z)
            w = q
            sign_stage[stage] = 0.0
            if q > 0.0:
                w = q + off
                sign_stage[stage] = 1.0
            elif q < 0.0:
                w = q - off
                sign_stage[stage] = -1.0
            delta = xd
            if noise_rate > 0.0:
                idx = int((k + 0.5 * ci) * dt * noise_rate + 1e-9)
                if idx >= n_noise:
                    idx = n_noise - 1
                delta += noise[idx]
            kk[stage, 0] = ss[1]
            kk[stage, 1] = mu * delta if closed else 0.0
            kk[stage, 2] = ss[3]
            kk[stage, 3] = ydd
            kk[stage, 4] = w
            for i in range(nbp):
                acc = bp_b[i] * w
                for jj in range(nbp):
                    acc += bp_a[i, jj] * ss[N_CORE_STATES + jj]
                kk[stage, N_CORE_STATES + i] = acc
            if extended is not None:
                for i in range(nc_rk):
                    acc = comp_b[i] * vc
                    for jj in range(nc_rk):
                        acc += comp_a[i, jj] * ss[ic + jj]
                    kk[stage, ic + i] = acc
                if nbend:
                    kk[stage, ib] = ss[ib + 1]
                    kk[stage, ib + 1] = bend_gw2 * delta - bend_2zw * ss[ib + 1] - bend_w2 * ss[ib]
            if stage == 0 and k % decimation == 0:
                col = k // decimation
                if out.shape[0] == 1:  # a caller that reads delta alone (the fitting batches)
                    out[0, col] = delta
                else:
                    out[0, col] = k * dt
                    out[1, col] = u
                    out[2, col] = delta
                    out[3, col] = ss[0]
                    out[4, col] = xs
                    out[5, col] = ss[2]
                    out[6, col] = w
                    out[7, col] = b
        if k == n_steps:
            break
        total = 0.0
        for i in range(ns):
            s[i] += dt / 6.0 * (kk[0, i] + 2.0 * kk[1, i] + 2.0 * kk[2, i] + kk[3, i])
            total += s[i]
        if off != 0.0 and not (sign_stage[0] == sign_stage[1] == sign_stage[2] == sign_stage[3]):
            # the offset's jump located inside the step (x and the band-pass states integrate w)
            rk4_mean = (sign_stage[0] + 2.0 * sign_stage[1] + 2.0 * sign_stage[2]
                        + sign_stage[3]) / 6.0
            jump = dt * off * (_sign_switch_average(q_stage[0], q_stage[3], z_switch) - rk4_mean)
            s[4] += jump
            for i in range(nbp):
                s[N_CORE_STATES + i] += jump * bp_b[i]
        memory = min(max(memory, s[4] - r), s[4] + r)
        if not math.isfinite(total):
            return NON_FINITE, k + 1
        if abs(s[4]) > bound or abs(s[0]) > bound:
            return OUT_OF_BOUND, k + 1
    return OK, n_steps


# nogil: discovery simulates several recordings (and refinements) from Python threads at once;
# a one-set batch alone keeps one core busy.
@njit(cache=True, parallel=True, nogil=True)
def simulate_batch_kernel(
    p, ctrl, bp_a, bp_b, bp_c, u_cmd, exp_index, noise, dt, n_steps, decimation, out, status
):
    """Run ``simulate_kernel`` for every row of ``p`` in parallel over all cores.

    ``ctrl[i]``, ``bp_*[i]``, ``noise[i]`` belong to parameter set ``i``; ``u_cmd`` rows are
    shared through ``exp_index[i]``. ``status[i] = (code, step)``.
    """
    n = p.shape[0]
    for i in prange(n):
        code, step = simulate_kernel(
            p[i], ctrl[i], bp_a[i], bp_b[i], bp_c[i], u_cmd[exp_index[i]], noise[i],
            dt, n_steps, decimation, out[i],
        )
        status[i, 0] = code
        status[i, 1] = step
