"""Batch simulation for the sampler: the experiment packed once, warm starts on the cycle.

:func:`tvcid.models.simulate_batch` packs the experiment and builds every parameter set per call; an
MCMC step calls it thousands of times with the same experiment, so :class:`BatchSimulator` packs the
experiment, the command and the time grid once and calls :func:`tvcid.models.kernel.simulate_batch_kernel`
directly. Each row still goes through :meth:`tvcid.models.ActuatorParams.replace` and the models' own
packing, so every check and convention of :mod:`tvcid.models` applies (nothing is re-implemented here).

Warm start: the dead zone, the play operator and the linear parts are positively homogeneous, so a
cycle state taken from one reference run and scaled lands a walker's run near its own cycle and a
short transient (6 s at controller A) suffices. The scale brings the reference cycle to the recorded
cycle's size (rms), which is the size of every walker that fits; scaling by
``dead_zone / dead_zone_ref`` instead (the fallback) ignores the other parameters that set the size:
from a start 30 % off in the delay a drawn truth's cycle starts 73 % too large and settles with a
~5 s time constant, so that 20 s later its features still miss the data by 1.6 %, which moves the
posterior along the dead zone / friction ridge past the truth. In-loop output noise is never
simulated here: the sensor noise of a calibration is a likelihood parameter (``sigma``), not a
forcing.

Continuation: :class:`Continuation` keeps the cycle state each run ended on, keyed by its
parameters; a later run whose parameters are within a small relative distance of a stored run's
starts from that run's state instead of the shared reference cycle, so a sampler's proposal starts
near its own cycle. It cuts the worst transient errors but not the typical one (a nearby cycle is
approached slowly), so it is off by default (:class:`tvcid.discovery.calibration.Calibration`'s
``continuation``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tvcid.models import kernel as K
from tvcid.models.experiments import ClosedLoop, OpenLoop
from tvcid.models.hypotheses import ActuatorParams
from tvcid.models.simulate import (
    DEFAULT_BOUND,
    SimulationDiverged,
    _check_grid,
    _divides,
    _initial_conditions,
    _pack_experiment,
    _pack_params,
    simulate,
)

__all__ = ["WarmStart", "warm_start_state", "BatchSimulator", "Continuation", "cycle_state_at_end"]


@dataclass(frozen=True)
class WarmStart:
    """A state on a reference limit cycle and the reference scale.

    Attributes
    ----------
    theta, thetad, y, yd, x : float
        State at an upward crossing of the cycle's mean by ``x``.
    dead_zone_ref : float
        Dead zone of the reference run; without a size target, a run with dead zone ``z`` starts
        from the state times ``z / dead_zone_ref`` (1 when either is 0).
    memory : float
        The play operator's memory there (NaN: the kernel's default).
    rms_ref, rms_target : float
        RMS about its mean of the reference cycle's ``x`` (rad), and the size (rad) every run is
        to start at (the recorded cycle's rms); NaN falls back to the dead-zone ratio.
    history : tuple or None
        ``(value, slope)`` of the delayed signal at that instant (rad or rad/s per s), the line
        the delay outputs before t = 0; ``None`` leaves the delay's 0.

    Without the memory and the history a run started on its own cycle is kicked off it (by 2e-6 to
    4e-5 rad over the next 1.5 s, against 1e-8 to 3e-7 rad with them; ``tests/test_warm_start.py``)
    and the 10 s waveform log-likelihood of M002's benchmark record at the truth is 0.34 nats off
    after a 1 s transient (0.01 with them). Neighbours started from the truth's state (1 % in the
    backlash, 0.3 % in the dead zone) are still off by up to 5.6 nats after 1 s and 0.06 after
    6 s: the approach to a nearby cycle is slow, which is why a transient stays.
    """

    theta: float
    thetad: float
    y: float
    yd: float
    x: float
    dead_zone_ref: float
    memory: float = math.nan
    history: tuple | None = None
    rms_ref: float = math.nan
    rms_target: float = math.nan

    def scale(self, params: ActuatorParams) -> float:
        """``rms_target / rms_ref`` when both are known, else the dead-zone ratio."""
        if self.rms_ref > 0 and self.rms_target > 0:
            return self.rms_target / self.rms_ref
        if self.dead_zone_ref > 0 and params.dead_zone > 0:
            return params.dead_zone / self.dead_zone_ref
        return 1.0

    def apply(self, p, ctrl, params):
        """Write the scaled state into packed parameter and control vectors (in place)."""
        k = self.scale(params)
        p[K.P_Y0], p[K.P_YD0], p[K.P_X0] = k * self.y, k * self.yd, k * self.x
        ctrl[K.C_THETA0], ctrl[K.C_THETAD0] = k * self.theta, k * self.thetad
        p[K.P_MEMORY0] = k * self.memory
        if self.history is not None:
            p[K.P_HIST_ON] = 1.0
            p[K.P_HIST_VALUE], p[K.P_HIST_SLOPE] = k * self.history[0], k * self.history[1]


#: A warm start scales the reference run's state by at most this factor; a reference run
#: smaller than the target by more has decayed to rest (:func:`warm_start_state`).
MAX_WARM_SCALE = 1000.0


def warm_start_state(params: ActuatorParams, experiment, dt, t_ref=20.0, rms_target=math.nan):
    """Cycle state of ``params`` in the closed loop ``experiment`` after ``t_ref`` seconds.

    ``rms_target`` (rad): the size runs started from it are scaled to (:class:`WarmStart`).
    Returns ``None`` for an open-loop experiment, a diverging run or one that does not oscillate,
    a run decaying to rest included (its size under ``rms_target / MAX_WARM_SCALE``: scaled up,
    the state of a vanishing transient overflows the run); the caller then starts from the
    hypothesis' own initial conditions.
    """
    if not isinstance(experiment, ClosedLoop):
        return None
    clean = params.replace(noise_power=0.0)
    try:
        tr = simulate(clean, experiment, t_ref, dt=dt, rate=None)
    except (SimulationDiverged, ValueError):
        return None
    fields = _state_at_last_crossing(tr.t, tr.theta, tr.y, tr.x, tr.backlash, params, tr.t.size // 2)
    if fields is None:
        return None
    state, rms_ref = fields
    if math.isfinite(rms_target) and rms_ref * MAX_WARM_SCALE < rms_target:
        return None  # the reference run has decayed to rest: scaling its state is no cycle
    return WarmStart(**state, dead_zone_ref=float(params.dead_zone), rms_ref=rms_ref,
                     rms_target=float(rms_target))


def cycle_state_at_end(t, theta, y, x, memory, params):
    """The state at the last upward mean crossing of ``x`` in a run's second half, as a
    :class:`WarmStart` of scale 1 (a continuation of that run); ``None`` if it does not oscillate.

    ``t`` and the signals are a run's output rows (any uniform spacing); the velocities come from
    central differences at that spacing.
    """
    fields = _state_at_last_crossing(t, theta, y, x, memory, params, t.size // 2)
    if fields is None:
        return None
    return WarmStart(**fields[0], dead_zone_ref=0.0)


def _state_at_last_crossing(t, theta, y, x, memory, params, first):
    """WarmStart fields at the last upward crossing of the mean of ``x[first:]``, and the rms of
    ``x`` about that mean; ``None`` without a crossing."""
    n = t.size
    if n - first < 8:
        return None
    h = float(t[1] - t[0])
    tail = slice(first, n - 2)
    level = float(np.mean(x[tail]))
    amp = 0.5 * float(np.max(x[tail]) - np.min(x[tail]))
    if not amp > 0:
        return None
    k = np.flatnonzero((x[:-1] < level) & (x[1:] >= level))
    k = k[(k > first) & (k < n - 3)]
    if k.size == 0:
        return None
    i = int(k[-1])
    state = dict(
        theta=float(theta[i]),
        thetad=float((theta[i + 1] - theta[i - 1]) / (2 * h)),
        y=float(y[i]),
        yd=float((y[i + 1] - y[i - 1]) / (2 * h)),
        x=float(x[i]),
        memory=float(memory[i]),
        history=_delayed_signal_line(x, y, params, i, h),
    )
    return state, float(np.sqrt(np.mean((x[tail] - level) ** 2)))


def _delayed_signal_line(x, y, params, i, dt):
    """``(value, slope)`` at sample ``i`` of the signal the delay holds (samples ``dt`` apart)."""
    if params.delay <= 0:
        return None
    where = params.delay_position.value
    if where == "output":
        sig = x
    elif where == "before_integrator":
        sig = y
    else:  # before the first integrator: the acceleration y''
        lo, hi = max(i - 3, 0), min(i + 4, y.size)
        sig = np.full(y.size, np.nan)
        sig[lo:hi] = np.gradient(np.gradient(y[lo:hi], dt), dt)
    return float(sig[i]), float((sig[i + 1] - sig[i - 1]) / (2 * dt))


class BatchSimulator:
    """Simulate many parameter sets of one experiment on all cores, experiment packed once.

    Parameters
    ----------
    experiment : ClosedLoop or OpenLoop
    t_end, dt : float
        Duration and RK4 step (s).
    rate : float or None
        Output rate (Hz), dividing ``1/dt``; ``None`` keeps every step.
    warm_start : WarmStart or None
        Start closed-loop runs on the reference cycle (scaled); ``None`` uses each parameter
        set's own initial conditions.
    bound : float
        Divergence bound (rad).
    """

    def __init__(self, experiment, t_end, dt, rate=None, warm_start=None, bound=DEFAULT_BOUND):
        self.experiment = experiment
        self.t_end = float(t_end)
        self.dt = float(dt)
        self.rate = rate
        self.warm_start = warm_start
        self.bound = float(bound)
        self.n_steps, self.decimation = _check_grid(self.t_end, self.dt, rate)
        self._ctrl, u_cmd = _pack_experiment(experiment, self.dt, self.n_steps, self.bound)
        self._u_cmd = np.ascontiguousarray(u_cmd[None, :])
        self.n_out = self.n_steps // self.decimation + 1
        self.t = self.dt * self.decimation * np.arange(self.n_out)

    def __getstate__(self):  # picklable for process pools
        return self.__dict__.copy()

    def run(self, param_sets, starts=None, with_states=False):
        """Simulate ``param_sets`` (a list of ActuatorParams; ``None`` entries are skipped).

        Parameters
        ----------
        starts : list of WarmStart or None, optional
            Per set, a state to start from instead of :attr:`warm_start` (``None``: the shared
            one); closed loop only.
        with_states : bool
            Also return each run's end state (:func:`cycle_state_at_end`; all output signals are
            then recorded, 8 times the memory).

        Returns
        -------
        delta : ndarray, shape (n, n_out)
            Output; rows of skipped, invalid or diverged runs are NaN.
        ok : ndarray of bool, shape (n,)
        states : list of WarmStart or None
            Only with ``with_states``.
        """
        n = len(param_sets)
        closed = isinstance(self.experiment, ClosedLoop)
        rows, keep = [], []
        for i, params in enumerate(param_sets):
            if params is None:
                continue
            try:
                p, bp_a, bp_b, bp_c = _pack_params(params, self.dt)
            except ValueError:  # e.g. a delay shorter than the step
                continue
            p = _initial_conditions(p, self.experiment)
            p[K.P_NOISE_RATE] = 0.0
            ctrl = self._ctrl.copy()
            start = starts[i] if starts is not None and starts[i] is not None else self.warm_start
            if start is not None and closed:
                start.apply(p, ctrl, params)
            rows.append((p, ctrl, bp_a, bp_b, bp_c))
            keep.append(i)
        delta = np.full((n, self.n_out), np.nan)
        ok = np.zeros(n, dtype=bool)
        states = [None] * n
        if not rows:
            return (delta, ok, states) if with_states else (delta, ok)
        m = len(rows)
        p = np.array([r[0] for r in rows])
        ctrl = np.array([r[1] for r in rows])
        bp_a = np.array([r[2] for r in rows])
        bp_b = np.array([r[3] for r in rows])
        bp_c = np.array([r[4] for r in rows])
        # delta alone unless states are wanted: 1/8 of the memory to fill
        out = np.empty((m, K.N_SIGNALS if with_states else 1, self.n_out))
        status = np.zeros((m, 2), dtype=np.int64)
        K.simulate_batch_kernel(
            p, ctrl, bp_a, bp_b, bp_c, self._u_cmd, np.zeros(m, dtype=np.int64),
            np.zeros((m, 1)), self.dt, self.n_steps, self.decimation, out, status,
        )
        idx = np.asarray(keep)
        good = status[:, 0] == K.OK
        row = K.SIGNALS.index("delta") if with_states else 0
        delta[idx[good]] = out[good, row, :]
        ok[idx[good]] = True
        if not with_states:
            return delta, ok
        sig = {name: K.SIGNALS.index(name) for name in ("theta", "y", "x", "backlash")}
        for j in np.flatnonzero(good) if closed else ():
            o = out[j]
            states[idx[j]] = cycle_state_at_end(self.t, o[sig["theta"]], o[sig["y"]],
                                                o[sig["x"]], o[sig["backlash"]], param_sets[idx[j]])
        return delta, ok, states


#: Largest relative difference (any field) at which a run continues a stored run's cycle.
CONTINUATION_RADIUS = 0.01
#: Actuator fields compared to find a stored run near a new parameter set (:class:`Continuation`).
CONTINUATION_FIELDS = ("gain", "damping", "stiffness", "feedback_gain", "dead_zone", "backlash",
                       "delay", "friction_offset", "bandpass_gain", "bandpass_saturation")


class Continuation:
    """End states of recent runs, looked up by the nearest parameter set.

    Parameters
    ----------
    radius : float
        Largest relative difference of any field (:data:`CONTINUATION_FIELDS`) for a stored run
        to be continued; beyond it a run starts from the shared reference cycle.
    capacity : int
        Runs kept (the most recent).
    """

    def __init__(self, radius=CONTINUATION_RADIUS, capacity=256):
        self.radius = float(radius)
        self.capacity = int(capacity)
        self._keys = []
        self._states = []
        #: runs started from a stored state / from the shared start
        self.continued = 0
        self.fresh = 0

    @staticmethod
    def key(params):
        v = np.array([getattr(params, f) for f in CONTINUATION_FIELDS], dtype=float)
        return np.where(np.isfinite(v), v, 0.0)

    def nearest(self, params):
        """The stored state of the run nearest ``params`` within :attr:`radius`, or ``None``."""
        if params is None:
            return None
        if not self._keys:
            self.fresh += 1
            return None
        k = self.key(params)
        keys = np.asarray(self._keys)
        scale = np.maximum(np.maximum(np.abs(keys), np.abs(k)), 1e-300)
        dist = np.max(np.abs(keys - k) / scale, axis=1)
        j = int(np.argmin(dist))
        if dist[j] > self.radius:
            self.fresh += 1
            return None
        self.continued += 1
        return self._states[j]

    def add(self, params, state):
        if params is None or state is None:
            return
        self._keys.append(self.key(params))
        self._states.append(state)
        if len(self._keys) > self.capacity:
            del self._keys[0], self._states[0]


def output_rate_for(dt, data_rate):
    """The data rate when it divides ``1/dt``, else ``None`` (keep every step)."""
    return float(data_rate) if _divides(data_rate, dt) else None


def is_open_loop(experiment) -> bool:
    return isinstance(experiment, OpenLoop)


def _finite(x):
    return x is not None and math.isfinite(x)
