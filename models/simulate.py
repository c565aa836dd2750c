"""Run a hypothesis through an experiment: single runs and parallel batches on the numba kernel."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from . import kernel as K
from .experiments import ClosedLoop, OpenLoop
from .hypotheses import ActuatorParams, DeadZonePosition, DelayPosition
from .linear import MAX_BANDPASS_STATES, bandpass_state_space
from .noise import band_limited_white_noise

__all__ = [
    "DEFAULT_DT",
    "DEFAULT_RATE",
    "DEFAULT_BOUND",
    "SimulationDiverged",
    "Trajectory",
    "BatchResult",
    "simulate",
    "simulate_batch",
    "step_for_rate",
]

#: Default RK4 step (s). ``studies/benchmarks/simulator.py`` shows the cycle amplitude within 0.1 % of
#: a dt = 1e-5 run at this step.
DEFAULT_DT = 2e-4
#: Default output rate (Hz) of a trajectory.
DEFAULT_RATE = 1000.0
#: Default divergence bound (rad) on the actuator position and the vehicle attitude.
DEFAULT_BOUND = 1.0

_DELAY_CODES = {
    DelayPosition.OUTPUT: K.DELAY_OUTPUT,
    DelayPosition.BEFORE_INTEGRATOR: K.DELAY_BEFORE_INTEGRATOR,
    DelayPosition.BEFORE_FIRST_INTEGRATOR: K.DELAY_BEFORE_FIRST_INTEGRATOR,
}


class SimulationDiverged(RuntimeError):
    """A run left the finite numbers or the divergence bound."""


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Sampled output of one run.

    Attributes
    ----------
    t : ndarray
        Time (s).
    u : ndarray
        Actuator command (rad).
    delta : ndarray
        Measured actuator output, delay and noise included (rad).
    theta : ndarray
        Rigid vehicle attitude (rad); 0 in open loop. With a bending mode the controller senses
        ``theta + q``, which is not recorded (the rows stay those of every recording).
    x : ndarray
        Integrator output, the actuator position before an output delay and the noise (rad).
    y : ndarray
        Velocity-level signal, output of the second-order block (rad/s).
    w : ndarray
        Integrator input ``x'`` (rad/s).
    backlash : ndarray
        Play-operator output ``play_r(x)`` (rad).
    params : ActuatorParams
    experiment : ClosedLoop or OpenLoop
    dt : float
        Integration step (s).
    """

    t: np.ndarray
    u: np.ndarray
    delta: np.ndarray
    theta: np.ndarray
    x: np.ndarray
    y: np.ndarray
    w: np.ndarray
    backlash: np.ndarray
    params: ActuatorParams = field(repr=False)
    experiment: object = field(repr=False)
    dt: float = DEFAULT_DT

    @property
    def rate(self) -> float:
        """Output sample rate (Hz)."""
        return 1.0 / (self.t[1] - self.t[0])

    def window(self, seconds):
        """Slice selecting the last ``seconds`` of the record (all of it for ``None``)."""
        if seconds is None:
            return slice(None)
        n = int(round(seconds * self.rate))
        if n < 2:
            raise ValueError(f"window of {seconds} s holds fewer than two samples")
        return slice(max(0, self.t.size - n - 1), None)

    def features(self, window=None, **kwargs):
        """Limit-cycle features of ``delta`` over the last ``window`` seconds."""
        from .cycle_reading import limit_cycle_features

        sl = self.window(window)
        return limit_cycle_features(self.t[sl], self.delta[sl], **kwargs)

    def signals(self) -> dict:
        """All sampled signals by name."""
        return {name: getattr(self, name) for name in K.SIGNALS}

    def plot(self, ax=None, signal="delta", **kwargs):
        """Plot one signal against time; returns the axes."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        ax.plot(self.t, getattr(self, signal), label=kwargs.pop("label", self.params.name), **kwargs)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(signal)
        return ax


@dataclass(frozen=True, eq=False)
class BatchResult:
    """Output of :func:`simulate_batch`.

    Attributes
    ----------
    t : ndarray, shape (n_out,)
    signals : ndarray, shape (n_sets, N_SIGNALS, n_out)
        Rows in the order of :data:`tvcid.models.kernel.SIGNALS`; samples after a divergence are NaN.
    status : ndarray of str, shape (n_sets,)
        ``"ok"``, ``"non-finite"`` or ``"out of bound"``.
    stop_time : ndarray, shape (n_sets,)
        Time (s) at which each run stopped.
    """

    t: np.ndarray
    signals: np.ndarray
    status: np.ndarray
    stop_time: np.ndarray

    @property
    def diverged(self) -> np.ndarray:
        """Boolean mask of the runs that diverged."""
        return self.status != "ok"

    def signal(self, name) -> np.ndarray:
        """One signal for every set, shape (n_sets, n_out)."""
        return self.signals[:, K.SIGNALS.index(name), :]


def _divides(rate, dt) -> bool:
    """Whether ``rate`` (Hz) divides the step rate ``1/dt`` (within a rate read off timestamps)."""
    ratio = 1.0 / (rate * dt)
    k = round(ratio)
    return k >= 1 and abs(ratio - k) <= 1e-6 * max(1.0, ratio)  # a rate's float rounding


#: :func:`step_for_rate` looks this many steps per sample past the first that fits under ``dt``.
SHARED_STEP_SEARCH = 64


def step_for_rate(rate, dt=DEFAULT_DT, controller_rate=None) -> float:
    """The longest step (s) not above ``dt`` whose step rate the output rate ``rate`` (Hz) and a
    held controller's ``controller_rate`` (Hz) both divide: ``dt`` itself where they do, else
    ``1 / (rate k)`` with the smallest whole ``k`` that fits. A recording at 2 kHz is simulated
    at 1/6000 s instead of the default 2e-4 s, whose 5 kHz it does not divide.

    Raises
    ------
    ValueError
        A rate that is not a finite number > 0, or two rates that share no step within
        :data:`SHARED_STEP_SEARCH` steps per sample of the first under ``dt``.
    """
    rates = [r for r in (rate, controller_rate) if r is not None]
    for r in rates:
        if not (isinstance(r, (int, float, np.floating)) and math.isfinite(r) and r > 0):
            raise ValueError(f"rate must be a finite number > 0 (got {r!r})")
    if all(_divides(r, dt) for r in rates):
        return dt
    base = rates[0]
    first = math.ceil(1.0 / (base * dt))
    for k in range(first, first + SHARED_STEP_SEARCH):
        step = 1.0 / (base * k)
        if all(_divides(r, step) for r in rates):
            return step
    raise ValueError(f"the output rate {rate} Hz and the controller's {controller_rate} Hz share "
                     f"no simulation step between {1.0 / (base * (first + SHARED_STEP_SEARCH)):.3g} "
                     f"and {dt:g} s")


def _check_grid(t_end, dt, rate):
    for name, value in (("t_end", t_end), ("dt", dt)):
        if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0 (got {value!r})")
    n_steps = int(round(t_end / dt))
    if n_steps < 1:
        raise ValueError(f"t_end ({t_end}) is shorter than one step dt ({dt})")
    if rate is None:
        decimation = 1
    else:
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"rate must be a finite number > 0 (got {rate!r})")
        if not _divides(rate, dt):
            raise ValueError(
                f"output rate {rate} Hz must divide the step rate 1/dt = {1 / dt:g} Hz"
            )
        decimation = int(round(1.0 / (rate * dt)))
    return n_steps, decimation


def _pack_params(params: ActuatorParams, dt: float) -> tuple:
    if not isinstance(params, ActuatorParams):
        raise TypeError(f"expected an ActuatorParams, got {type(params).__name__}")
    delay_steps = params.delay / dt
    if abs(delay_steps - round(delay_steps)) < 1e-9 * max(1.0, delay_steps):
        delay_steps = float(round(delay_steps))
    if params.delay > 0 and delay_steps < 1.0:
        raise ValueError(
            f"delay ({params.delay} s) is shorter than the step dt ({dt} s); "
            "use delay=0 or a smaller dt"
        )
    p = np.zeros(K.N_PARAMS)
    p[K.P_MEMORY0] = np.nan  # the default initial play memory
    p[K.P_GAIN], p[K.P_DAMPING], p[K.P_STIFFNESS] = params.gain, params.damping, params.stiffness
    p[K.P_FEEDBACK] = params.feedback_gain
    p[K.P_DEAD_ZONE] = params.dead_zone
    p[K.P_DZ_ON_VELOCITY] = float(params.dead_zone_position is DeadZonePosition.VELOCITY)
    p[K.P_BACKLASH] = params.backlash
    p[K.P_FRICTION] = params.friction_offset
    p[K.P_DELAY_STEPS] = delay_steps
    p[K.P_DELAY_WHERE] = _DELAY_CODES[params.delay_position] if params.delay > 0 else K.DELAY_NONE
    p[K.P_Y0], p[K.P_YD0], p[K.P_X0] = params.y0, params.yd0, params.x0
    bp_a = np.zeros((MAX_BANDPASS_STATES, MAX_BANDPASS_STATES))
    bp_b = np.zeros(MAX_BANDPASS_STATES)
    bp_c = np.zeros(MAX_BANDPASS_STATES)
    if params.has_bandpass_loop:
        a, b, c = bandpass_state_space(
            params.bandpass_low_hz, params.bandpass_high_hz, params.bandpass_order
        )
        n = a.shape[0]
        bp_a[:n, :n], bp_b[:n], bp_c[:n] = a, b, c
        p[K.P_N_BP] = n
        p[K.P_BP_GAIN] = params.bandpass_gain
        p[K.P_BP_SAT] = params.bandpass_saturation
    if params.noise_power > 0:
        p[K.P_NOISE_RATE] = 2.0 * params.noise_band
    return p, bp_a, bp_b, bp_c


def _noise(params: ActuatorParams, t_end: float) -> np.ndarray:
    if params.noise_power <= 0:
        return np.zeros(1)
    rng = np.random.default_rng(params.noise_seed)
    return band_limited_white_noise(params.noise_power, params.noise_band, t_end, rng)


def _initial_conditions(p, experiment):
    """Open-loop bench tests start at rest unless told otherwise."""
    if isinstance(experiment, OpenLoop) and experiment.from_rest:
        p = p.copy()
        p[K.P_Y0] = p[K.P_YD0] = p[K.P_X0] = 0.0
    return p


def _pack_experiment(experiment, dt, n_steps, bound):
    """Packed experiment vector (layout in :mod:`tvcid.models.kernel`) and the open-loop command.

    A closed loop's compensator is packed as its controllable canonical form, or as its Tustin
    realisation at ``sample_rate`` when the controller is held; its length is
    ``kernel.control_length(order)``.
    """
    ctrl = np.zeros(K.N_CONTROL)
    ctrl[K.C_BOUND] = bound
    ctrl[K.C_COMP_D] = 1.0  # no compensator: u = -v
    if isinstance(experiment, ClosedLoop):
        ctrl[K.C_CLOSED] = 1.0
        ctrl[K.C_KP], ctrl[K.C_KD], ctrl[K.C_MU] = experiment.kp, experiment.kd, experiment.mu
        ctrl[K.C_THETA0], ctrl[K.C_THETAD0] = experiment.theta0, experiment.thetad0
        if experiment.sample_rate is not None:
            if not _divides(experiment.sample_rate, dt):
                raise ValueError(
                    f"controller sample_rate {experiment.sample_rate} Hz must divide the step "
                    f"rate 1/dt = {1 / dt:g} Hz"
                )
            ctrl[K.C_HOLD_STEPS] = int(round(1.0 / (experiment.sample_rate * dt)))
        if experiment.bending is not None:
            bend = experiment.bending
            ctrl[K.C_BEND_W], ctrl[K.C_BEND_ZETA] = bend.frequency, bend.damping
            ctrl[K.C_BEND_GAIN] = bend.gain
        if experiment.compensator is not None:
            ctrl = _pack_compensator(ctrl, experiment)
        u_cmd = np.zeros(1)
    elif isinstance(experiment, OpenLoop):
        u_cmd = _stage_command(experiment, dt, n_steps)
    else:
        raise TypeError(
            f"experiment must be a ClosedLoop or an OpenLoop, got {type(experiment).__name__}"
        )
    return ctrl, u_cmd


def _stage_command(experiment, dt, n_steps):
    """The open-loop command at the RK4 stage times, memoised on the (frozen) experiment.

    A square's stage averages (:meth:`OpenLoop.solver_command`) cost several times the run itself,
    and a search simulates the same test thousands of times (SINDy's simulation stage spent 48 of
    its 102 s rebuilding them on the M000 records). The cache lives in the instance's
    ``__dict__``, outside the dataclass fields (``repr`` does not show it; equality is identity).
    """
    cache = experiment.__dict__.setdefault("_stage_commands", {})
    key = (float(dt), int(n_steps))
    if key not in cache:
        u = np.asarray(experiment.solver_command(0.5 * dt * np.arange(2 * n_steps + 1), dt),
                       dtype=float)
        u.setflags(write=False)
        cache[key] = u
    return cache[key]


def _pack_compensator(ctrl, experiment):
    """``ctrl`` extended with the compensator's order, feedthrough and matrices."""
    comp = experiment.compensator
    if experiment.sample_rate is None:
        a, b, c, d = comp.state_space()
    else:  # the digital controller's difference equation, stepped once per sample
        a, b, c, d = comp.discretise(experiment.sample_rate)
    n = comp.order
    packed = np.zeros(K.control_length(n))
    packed[: K.N_CONTROL] = ctrl
    packed[K.C_N_COMP], packed[K.C_COMP_D] = n, d
    o = K.C_COMP_MATRICES
    packed[o: o + n * n] = np.asarray(a, dtype=float).reshape(-1)
    packed[o + n * n: o + n * n + n] = b
    packed[o + n * n + n: o + n * n + 2 * n] = c
    return packed


def simulate(
    params: ActuatorParams,
    experiment,
    t_end: float,
    dt: float | None = None,
    rate: float | None = DEFAULT_RATE,
    bound: float = DEFAULT_BOUND,
) -> Trajectory:
    """Simulate one hypothesis in one experiment with the numba kernel.

    Parameters
    ----------
    params : ActuatorParams
        The hypothesis (e.g. ``M002()``), noise seed included.
    experiment : ClosedLoop or OpenLoop
    t_end : float
        Duration (s).
    dt : float or None
        RK4 step (s); ``None``: :func:`step_for_rate` of ``rate`` and a held controller's rate
        (:data:`DEFAULT_DT` where they divide it).
    rate : float or None
        Output rate (Hz); must divide ``1/dt``. ``None`` keeps every step.
    bound : float
        Divergence bound (rad) on ``|x|`` and ``|theta|``.

    Raises
    ------
    SimulationDiverged
        When the run becomes non-finite or exceeds ``bound``.
    """
    if dt is None:
        dt = step_for_rate(rate, controller_rate=getattr(experiment, "sample_rate", None))
    n_steps, decimation = _check_grid(t_end, dt, rate)
    p, bp_a, bp_b, bp_c = _pack_params(params, dt)
    ctrl, u_cmd = _pack_experiment(experiment, dt, n_steps, bound)
    out = np.full((K.N_SIGNALS, n_steps // decimation + 1), np.nan)
    p = _initial_conditions(p, experiment)
    code, step = K.simulate_kernel(
        p, ctrl, bp_a, bp_b, bp_c, u_cmd, _noise(params, t_end), dt, n_steps, decimation, out
    )
    if code != K.OK:
        reason = "became non-finite" if code == K.NON_FINITE else f"exceeded the bound {bound} rad"
        raise SimulationDiverged(
            f"{params.name} diverged: the state {reason} at t = {step * dt:.4g} s"
        )
    return Trajectory(*_recorded_command(out, experiment), params=params, experiment=experiment,
                      dt=dt)


def _recorded_command(columns, experiment):
    """Signal rows with ``u`` as commanded (the solver's stage averages are not a recording)."""
    if isinstance(experiment, OpenLoop):
        columns[1] = experiment.command(columns[0])
    return columns


_STATUS_NAMES = {K.OK: "ok", K.NON_FINITE: "non-finite", K.OUT_OF_BOUND: "out of bound"}


def simulate_batch(
    param_sets: Sequence[ActuatorParams],
    experiment,
    t_end: float,
    dt: float = DEFAULT_DT,
    rate: float | None = DEFAULT_RATE,
    bound: float = DEFAULT_BOUND,
) -> BatchResult:
    """Simulate many parameter sets in parallel on all cores (numba ``prange``).

    Parameters
    ----------
    param_sets : sequence of ActuatorParams
    experiment : ClosedLoop, OpenLoop, or a sequence of them (one per set)
    t_end, dt, rate, bound
        As in :func:`simulate`.

    Returns
    -------
    BatchResult
        Diverged runs are flagged in ``status``, never returned silently.
    """
    param_sets = list(param_sets)
    if not param_sets:
        raise ValueError("param_sets is empty")
    n_steps, decimation = _check_grid(t_end, dt, rate)
    n = len(param_sets)
    experiments = list(experiment) if isinstance(experiment, (list, tuple)) else [experiment] * n
    if len(experiments) != n:
        raise ValueError(f"got {len(experiments)} experiments for {n} parameter sets")
    unique, exp_index, ctrl_rows, u_rows = {}, np.zeros(n, dtype=np.int64), [], []
    for i, exp in enumerate(experiments):
        if id(exp) not in unique:
            ctrl, u_cmd = _pack_experiment(exp, dt, n_steps, bound)
            unique[id(exp)] = (len(u_rows), ctrl)
            u_rows.append(u_cmd)
        exp_index[i], ctrl = unique[id(exp)]
        ctrl_rows.append(ctrl)
    width = max(row.size for row in u_rows)
    u_cmd = np.zeros((len(u_rows), width))
    for j, row in enumerate(u_rows):
        u_cmd[j, : row.size] = row
    ctrl = np.zeros((n, max(row.size for row in ctrl_rows)))  # compensators of unequal order
    for i, row in enumerate(ctrl_rows):
        ctrl[i, : row.size] = row
    packed = [_pack_params(ps, dt) for ps in param_sets]
    p = np.array([_initial_conditions(pk[0], exp) for pk, exp in zip(packed, experiments)])
    bp_a = np.array([pk[1] for pk in packed])
    bp_b = np.array([pk[2] for pk in packed])
    bp_c = np.array([pk[3] for pk in packed])
    noises = [_noise(ps, t_end) for ps in param_sets]
    noise = np.zeros((n, max(nz.size for nz in noises)))
    for i, nz in enumerate(noises):
        noise[i, : nz.size] = nz
    out = np.full((n, K.N_SIGNALS, n_steps // decimation + 1), np.nan)
    status = np.zeros((n, 2), dtype=np.int64)
    K.simulate_batch_kernel(
        p, ctrl, bp_a, bp_b, bp_c, u_cmd, exp_index, noise,
        dt, n_steps, decimation, out, status,
    )
    t = dt * decimation * np.arange(out.shape[2])
    commands = {}
    for i, exp in enumerate(experiments):  # u as commanded, as simulate records it
        if isinstance(exp, OpenLoop):
            if id(exp) not in commands:
                commands[id(exp)] = exp.command(t)
            ran = ~np.isnan(out[i, 0])  # samples after a divergence stay NaN
            out[i, 1, ran] = commands[id(exp)][ran]
    names = np.array([_STATUS_NAMES[c] for c in status[:, 0]])
    return BatchResult(t=t, signals=out, status=names, stop_time=status[:, 1] * dt)
