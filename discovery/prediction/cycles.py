"""The limit cycle a calibrated actuator will show under a controller, with its posterior band.

Paper 002 (section 1) motivates the whole identification by the design of the attitude loop: the
lead and notch filters shape the limit cycle, so the designer needs the cycle's amplitude and
frequency, and how sure they are, under a controller that was never tested. Here every posterior
draw is simulated in closed loop through the batch kernel (:func:`tvcid.models.simulate_batch`) and the
cycle measured as ``docs/models.md#conventions`` defines it (:func:`tvcid.models.limit_cycle_features`);
the spread over the draws is the band. The describing function of the median model is given beside
it.

The shortcut: a pilot run of the median model at each setting, ``pilot``
seconds long, gives the state on its cycle; every draw starts there and runs a short ``transient``
before the measured ``window``. ``benchmark`` in :mod:`tvcid.studies.benchmarks.prediction` measures how far
it lands from full-length runs.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from tvcid.models.cycle_reading import InsufficientPeriodsError, limit_cycle_features
from tvcid.models.kernel import SIGNALS
from tvcid.models.simulate import simulate_batch

from .settings import ControllerSetting

__all__ = [
    "CycleMap",
    "CycleOutcomes",
    "CyclePrediction",
    "PredictionConfig",
    "cycle_map",
    "predict_cycle",
    "simulate_cycles",
    "step_under_delays",
]

CYCLE, REST, DIVERGED = "cycle", "rest", "diverged"
#: provisional: grew by over ``max_growth`` across the window, to be confirmed by a longer run
GROWING = "growing"


@dataclass(frozen=True)
class PredictionConfig:
    """How each draw is simulated and measured.

    Parameters
    ----------
    transient : float
        Seconds simulated before the window (s), from the pilot's state.
    window : float
        Seconds measured (s); must hold two periods.
    pilot : float
        Seconds of the median model's pilot run at each setting (0: every draw starts at
        ``theta = start_theta`` at rest, and ``transient`` must then be long).
    start_theta : float
        Initial attitude (rad) when there is no pilot, or the pilot does not oscillate.
    dt : float
        RK4 step (s).
    rate : float
        Output rate (Hz) the cycle is measured at.
    min_amplitude : float
        First-harmonic amplitude (rad) below which the loop counts as at rest.
    max_decay : float
        A window whose amplitude falls by more than this fraction between its halves counts as
        decaying to rest.
    max_growth : float
        A window whose amplitude grows by more than this fraction between its halves may be
        diverging (an unstable loop grows without bound where no saturation is modelled; it
        may not reach ``bound`` within a short run): see ``confirm``.
    confirm : float
        Extra seconds of transient for a run whose window grew by over ``max_growth``: it is
        diverging when it then leaves ``bound`` or has grown by ``confirm_growth`` and still
        grows, else a (wandering) cycle measured there. Without it a quasi-periodic cycle's
        wander (M000: window halves of 1.1 and 1.46 mrad) read as divergence.
    confirm_growth : float
    settled_drift : float
        A cycle whose amplitude changes by more than this fraction across the window counts as
        not settled (near the stability boundary growth is slow; reported, not hidden).
    bound : float
        Divergence bound (rad) on the actuator output and the attitude.
    seed : int
        Seed of the in-loop noise realisations: each draw of a hypothesis with in-loop noise
        (``noise_power > 0``) gets its own, so that the band holds the cycle's own wander from
        window to window (what a measured window shows), not only the parameters' spread.
    chunk : int
        Runs per batch (bounds memory).
    """

    transient: float = 3.0
    window: float = 4.0
    pilot: float = 20.0
    start_theta: float = 0.02
    dt: float = 5e-4
    rate: float = 250.0
    min_amplitude: float = 1e-5
    max_decay: float = 0.5
    max_growth: float = 0.1
    confirm: float = 20.0
    confirm_growth: float = 1.5
    settled_drift: float = 0.02
    bound: float = 1.0
    chunk: int = 1000
    seed: int = 0

    def __post_init__(self):
        for name in ("transient", "pilot"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0 (got {getattr(self, name)})")
        for name in ("window", "dt", "rate", "min_amplitude", "bound"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 (got {getattr(self, name)})")


@dataclass(frozen=True)
class CycleOutcomes:
    """Per-run results of :func:`simulate_cycles`.

    Attributes
    ----------
    outcome : ndarray of str
        ``"cycle"``, ``"rest"`` or ``"diverged"`` (out of bound, non-finite, or growing by more
        than ``max_growth`` over the window).
    amplitude : ndarray
        ``(max - min)/2`` of ``delta`` over the window (rad); NaN unless a cycle.
    first_harmonic : ndarray
        First-harmonic amplitude of ``delta`` (rad), the describing function's amplitude.
    frequency : ndarray
        Fundamental (rad/s); NaN unless a cycle.
    drift : ndarray
        Relative change of the amplitude between the window's halves; NaN unless a cycle.
    """

    outcome: np.ndarray
    amplitude: np.ndarray
    first_harmonic: np.ndarray
    frequency: np.ndarray
    drift: np.ndarray


def _measure(t, delta, config):
    try:
        f = limit_cycle_features(t, delta, n_harmonics=1)
    except (InsufficientPeriodsError, ValueError):
        return REST, math.nan, math.nan, math.nan, math.nan
    h1 = f.harmonics[0]
    if f.amplitude_drift > config.max_growth:
        return GROWING, f.amplitude, h1, f.frequency, f.amplitude_drift
    if not (h1 > config.min_amplitude) or f.amplitude_drift < -config.max_decay:
        return REST, math.nan, math.nan, math.nan, math.nan
    return CYCLE, f.amplitude, h1, f.frequency, f.amplitude_drift


def simulate_cycles(param_sets, loops, config=PredictionConfig(), progress=None) -> CycleOutcomes:
    """Simulate ``param_sets[i]`` in closed loop ``loops[i]`` and classify each run.

    Parameters
    ----------
    param_sets : sequence of ActuatorParams
    loops : sequence of ClosedLoop (same length)
    config : PredictionConfig
    progress : callable, optional
        Called with the number of runs finished after every chunk.
    """
    param_sets, loops = list(param_sets), list(loops)
    if len(param_sets) != len(loops):
        raise ValueError(f"{len(param_sets)} parameter sets for {len(loops)} loops")
    config = step_under_delays(config, param_sets)
    outcome, amp, h1, freq, drift = _run_and_measure(param_sets, loops, config, progress)
    growing = np.flatnonzero(outcome == GROWING)
    if growing.size:
        # a window that grows is either a slow divergence or a wandering cycle (M000's band-pass
        # loop): run those draws longer; divergence is leaving the bound or growing on
        longer = dataclasses.replace(config, transient=config.transient + config.confirm)
        o2, a2, h2, f2, d2 = _run_and_measure([param_sets[i] for i in growing],
                                              [loops[i] for i in growing], longer, None)
        for k, i in enumerate(growing):
            grew = o2[k] == GROWING and a2[k] > config.confirm_growth * amp[i]
            if o2[k] == DIVERGED or grew:
                outcome[i], amp[i], h1[i], freq[i], drift[i] = (DIVERGED, math.nan, math.nan,
                                                                 math.nan, math.nan)
            else:
                outcome[i] = CYCLE if o2[k] == GROWING else o2[k]
                amp[i], h1[i], freq[i], drift[i] = a2[k], h2[k], f2[k], d2[k]
    return CycleOutcomes(outcome=outcome.astype(str), amplitude=amp, first_harmonic=h1,
                         frequency=freq, drift=drift)


def step_under_delays(config, param_sets):
    """``config`` with its step halved until one step fits under the shortest delay of
    ``param_sets`` (:func:`tvcid.discovery.calibration.priors.step_under_delay`; the kernel needs
    ``delay >= dt``), unchanged where every delay is 0 or at least ``config.dt``.

    A member whose delay prior reaches under the default step was calibrated at such a halved
    step (:func:`tvcid.discovery.members.member_calibration.calibrate_member`), and its draws
    are predicted at it."""
    from tvcid.discovery.calibration.priors import step_under_delay

    delays = [p.delay for p in param_sets if p.delay > 0]
    if not delays or min(delays) >= config.dt * (1.0 - 1e-9):
        return config
    return dataclasses.replace(config, dt=step_under_delay(min(delays), config.dt))


def _run_and_measure(param_sets, loops, config, progress):
    n = len(param_sets)
    outcome = np.empty(n, dtype=object)
    amp, h1, freq, drift = (np.full(n, np.nan) for _ in range(4))
    t_end = config.transient + config.window
    for lo in range(0, n, config.chunk):
        hi = min(n, lo + config.chunk)
        res = simulate_batch(param_sets[lo:hi], loops[lo:hi], t_end, dt=config.dt,
                             rate=config.rate, bound=config.bound)
        keep = res.t >= config.transient - 1e-9
        t = res.t[keep]
        delta = res.signal("delta")[:, keep]
        for j in range(hi - lo):
            if res.status[j] != "ok":
                outcome[lo + j] = DIVERGED
                continue
            (outcome[lo + j], amp[lo + j], h1[lo + j], freq[lo + j],
             drift[lo + j]) = _measure(t, delta[j], config)
        if progress is not None:
            progress(hi - lo)
    return outcome, amp, h1, freq, drift


def _pilot_state(params, setting, config):
    """State on the median model's cycle at ``setting``: ``(theta0, thetad0, y0, yd0, x0)``."""
    theta0 = config.start_theta
    if config.pilot <= 0:
        return theta0, 0.0, params.y0, params.yd0, params.x0
    res = simulate_batch([params], [setting.closed_loop(theta0=theta0)], config.pilot,
                         dt=config.dt, rate=None, bound=config.bound)
    if res.status[0] != "ok":
        return theta0, 0.0, params.y0, params.yd0, params.x0
    sig = res.signals[0]
    rows = {name: i for i, name in enumerate(SIGNALS)}
    dt = config.dt

    def end_and_rate(row):
        x = sig[rows[row]]
        return float(x[-1]), float((x[-1] - x[-2]) / dt)

    theta, thetad = end_and_rate("theta")
    y, yd = end_and_rate("y")
    x = float(sig[rows["x"], -1])
    return theta, thetad, y, yd, x


def _quantiles(values, mask):
    v = values[mask]
    if v.size == 0:
        return {"q05": None, "q50": None, "q95": None}
    q = np.quantile(v, [0.05, 0.5, 0.95])
    return {"q05": float(q[0]), "q50": float(q[1]), "q95": float(q[2])}


def _describing_prediction(params, setting, fast=False):
    """Stable cycle of the median model by harmonic balance, or the reason there is none."""
    from ..describing import predict_limit_cycles
    from ..describing.errors import DescribingFunctionError

    kwargs = {"n_amplitudes": 40, "n_frequencies": 60} if fast else {}
    try:
        result = predict_limit_cycles(params, setting.closed_loop(), **kwargs)
    except DescribingFunctionError as exc:
        return {"amplitude": None, "frequency": None, "note": str(exc)}
    stable = result.stable_cycles
    if not stable:
        return {"amplitude": None, "frequency": None, "note": "no stable cycle predicted"}
    c = max(stable, key=lambda c: c.amplitude)
    return {"amplitude": float(c.amplitude), "frequency": float(c.frequency),
            "note": "first-harmonic amplitude of delta"}


@dataclass(frozen=True)
class CyclePrediction:
    """The cycle at one controller setting over the posterior draws.

    Attributes
    ----------
    setting : ControllerSetting
    outcomes : CycleOutcomes
        One per draw.
    describing : dict
        The median model's harmonic-balance cycle (``amplitude`` as a first harmonic).
    solver_error : dict
        ``amplitude`` and ``frequency``: the change of the median model's cycle when the step is
        halved (step doubling; rad and rad/s), added to each side of the band.
    config : PredictionConfig
    """

    setting: ControllerSetting
    outcomes: CycleOutcomes = field(repr=False)
    describing: dict
    solver_error: dict = field(default_factory=dict)
    config: PredictionConfig = PredictionConfig()

    @property
    def fraction_oscillating(self) -> float:
        return float(np.mean(self.outcomes.outcome == CYCLE))

    @property
    def fraction_diverging(self) -> float:
        return float(np.mean(self.outcomes.outcome == DIVERGED))

    def to_dict(self) -> dict:
        """Quantiles over the oscillating draws, ``q05`` and ``q95`` moved out by the solver
        error; the fractions; the DF cycle of the median model."""
        mask = self.outcomes.outcome == CYCLE
        bands = {}
        for name in ("amplitude", "frequency", "first_harmonic"):
            q = _quantiles(getattr(self.outcomes, name), mask)
            e = self.solver_error.get(name, 0.0)
            if q["q05"] is not None and np.isfinite(e):
                q["q05"], q["q95"] = q["q05"] - e, q["q95"] + e
            bands[name] = q
        unsettled = mask & (np.abs(self.outcomes.drift) > self.config.settled_drift)
        return {
            **bands,
            "solver_error": self.solver_error,
            "fraction_not_settled": float(np.mean(unsettled)),
            "fraction_oscillating": self.fraction_oscillating,
            "fraction_diverging": self.fraction_diverging,
            "fraction_at_rest": float(np.mean(self.outcomes.outcome == REST)),
            "n_draws": int(mask.size),
            "describing_function": self.describing,
            "setting": self.setting.to_dict(),
            "units": {"amplitude": "rad, (max-min)/2 of delta", "frequency": "rad/s"},
        }

    def plot(self, ax=None):
        """Draws in the (frequency, amplitude) plane with the median model's DF cycle."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(5, 4))
        o = self.outcomes
        mask = o.outcome == CYCLE
        ax.scatter(o.frequency[mask], o.first_harmonic[mask] * 1e3, s=8, alpha=0.5,
                   label="posterior draws (first harmonic)")
        if self.describing.get("amplitude") is not None:
            ax.plot(self.describing["frequency"], self.describing["amplitude"] * 1e3, "r*",
                    ms=12, label="DF of the median model")
        ax.set_xlabel("frequency (rad/s)")
        ax.set_ylabel("amplitude of delta (mrad)")
        ax.set_title(f"{100 * self.fraction_oscillating:.0f} % oscillate, "
                     f"{100 * self.fraction_diverging:.0f} % diverge")
        ax.legend(fontsize=8)
        return ax


def predict_cycle(draws, setting: ControllerSetting, config=PredictionConfig(),
                  describing=True) -> CyclePrediction:
    """The cycle at one ``setting`` for every posterior draw.

    Parameters
    ----------
    draws : PosteriorDraws
    setting : ControllerSetting
    config : PredictionConfig
    describing : bool
        Add the median model's describing-function prediction.
    """
    median = draws.median_params()
    config = step_under_delays(_settling(config, [setting]), draws.param_sets())
    theta, thetad, y, yd, x = _pilot_state(median, setting, config)
    loop = setting.closed_loop(theta0=theta, thetad0=thetad)
    params = _own_noise([p.replace(y0=y, yd0=yd, x0=x) for p in draws.param_sets()],
                        np.random.default_rng(config.seed))
    outcomes = simulate_cycles(params, [loop] * len(params), config)
    df = _describing_prediction(median, setting) if describing else {}
    return CyclePrediction(setting=setting, outcomes=outcomes, describing=df,
                           solver_error=_solver_error(median.replace(y0=y, yd0=yd, x0=x), loop,
                                                      config),
                           config=config)


def _settling(config, settings):
    """``config`` with a transient long enough for the slowest filter or bending state: each
    draw starts from the pilot's actuator and attitude state, those states from zero (behind a
    notch of damping 0.02 at 60 rad/s a 3 s transient left M000's cycle 26 % large)."""
    need = max(s.settling_time() for s in settings)
    if need <= config.transient:
        return config
    return dataclasses.replace(config, transient=need)


def _own_noise(param_sets, rng) -> list:
    """Each parameter set with in-loop noise gets its own noise realisation."""
    return [p.replace(noise_seed=int(rng.integers(2**31))) if p.noise_power > 0 else p
            for p in param_sets]


def _solver_error(params, loop, config) -> dict:
    """Step-doubling change of one model's cycle (amplitude, first harmonic, frequency)."""
    runs = [simulate_cycles([params], [loop], dataclasses.replace(config, dt=h))
            for h in (config.dt, 0.5 * config.dt)]
    if not all(r.outcome[0] == CYCLE for r in runs):
        return {"amplitude": math.nan, "frequency": math.nan, "first_harmonic": math.nan}
    return {name: float(abs(getattr(runs[0], name)[0] - getattr(runs[1], name)[0]))
            for name in ("amplitude", "frequency", "first_harmonic")}


@dataclass(frozen=True)
class CycleMap:
    """Cycle predictions over a grid of controller values.

    Attributes
    ----------
    keys : tuple of str
        The varied values (one or two of :data:`settings.GRID_KEYS`).
    values : tuple of ndarray
        Grid of each key.
    summary : dict
        Arrays over the grid: ``amplitude_q05/q50/q95``, ``frequency_q05/q50/q95``,
        ``fraction_oscillating``, ``fraction_diverging``, ``fraction_not_settled``,
        ``df_amplitude``, ``df_frequency``.
    base : ControllerSetting
    """

    keys: tuple
    values: tuple
    summary: dict = field(repr=False)
    base: ControllerSetting

    @property
    def shape(self) -> tuple:
        return tuple(v.size for v in self.values)

    def point_bands(self, index) -> dict:
        """The bands at one grid point (``index`` into :attr:`shape`), in the form of
        :meth:`CyclePrediction.to_dict`: ``amplitude`` and ``frequency`` quantiles (``None``
        where no draw oscillates) and ``fraction_oscillating``."""
        def q(name):
            v = [float(self.summary[f"{name}_{k}"][index]) for k in ("q05", "q50", "q95")]
            if not all(np.isfinite(v)):
                return {"q05": None, "q50": None, "q95": None}
            return dict(zip(("q05", "q50", "q95"), v))

        return {"amplitude": q("amplitude"), "frequency": q("frequency"),
                "fraction_oscillating": float(self.summary["fraction_oscillating"][index])}

    def to_dict(self) -> dict:
        def clean(a):
            return [None if not np.isfinite(v) else float(v) for v in np.ravel(a)]

        return {
            "keys": list(self.keys),
            "values": [v.tolist() for v in self.values],
            "shape": list(self.shape),
            "base": self.base.to_dict(),
            "layout": "row-major over keys (the last key varies fastest)",
            **{k: clean(v) for k, v in self.summary.items()},
        }

    def to_csv(self, path):
        """One row per grid point: the keys' values then every summary column."""
        cols = list(self.summary)
        grid = list(itertools.product(*self.values))
        with open(path, "w", encoding="utf-8") as f:
            f.write(",".join(list(self.keys) + cols) + "\n")
            flat = {k: np.ravel(v) for k, v in self.summary.items()}
            for i, point in enumerate(grid):
                row = [f"{v:.8g}" for v in point] + [f"{flat[c][i]:.8g}" for c in cols]
                f.write(",".join(row) + "\n")

    def plot(self, axes=None):
        """Heatmaps of the median amplitude, the band's relative width, the median frequency and
        the fraction of draws that diverge; the stability boundary (half the draws diverge) is
        drawn on each."""
        import matplotlib.pyplot as plt

        if len(self.keys) != 2:
            return self._plot_line(axes)
        if axes is None:
            _, axes = plt.subplots(2, 2, figsize=(11, 8.5), constrained_layout=True)
        axes = np.ravel(axes)
        s = self.summary
        x, y = self.values[1], self.values[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            width = (s["amplitude_q95"] - s["amplitude_q05"]) / s["amplitude_q50"]
        panels = [
            (s["amplitude_q50"] * 1e3, "median amplitude of delta (mrad)", "viridis"),
            (100 * width, "90 % band width of the amplitude (% of median)", "magma"),
            (s["frequency_q50"], "median frequency (rad/s)", "cividis"),
            (s["fraction_diverging"], "fraction of draws diverging", "Reds"),
        ]
        for ax, (z, title, cmap) in zip(axes, panels):
            mesh = ax.pcolormesh(x, y, z, shading="nearest", cmap=cmap)
            plt.colorbar(mesh, ax=ax)
            if np.nanmin(s["fraction_diverging"]) < 0.5 < np.nanmax(s["fraction_diverging"]):
                ax.contour(x, y, s["fraction_diverging"], levels=[0.5], colors="k",
                           linewidths=1.5)
            ax.set_xlabel(self.keys[1])
            ax.set_ylabel(self.keys[0])
            ax.set_title(title, fontsize=10)
        return axes

    def _plot_line(self, axes=None):
        import matplotlib.pyplot as plt

        if axes is None:
            _, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
        s, x = self.summary, self.values[0]
        for ax, name, scale, unit in ((axes[0], "amplitude", 1e3, "mrad"),
                                      (axes[1], "frequency", 1.0, "rad/s")):
            ax.fill_between(x, s[f"{name}_q05"] * scale, s[f"{name}_q95"] * scale, alpha=0.3,
                            label="90 % band")
            ax.plot(x, s[f"{name}_q50"] * scale, label="median")
            ax.plot(x, s[f"df_{name}"] * scale, "r--", label="DF of the median model")
            unstable = s["fraction_diverging"] > 0.5
            if unstable.any():
                ax.plot(x[unstable], np.zeros(unstable.sum()), "rx", label="diverges")
            ax.set_xlabel(self.keys[0])
            ax.set_ylabel(f"{name} ({unit})")
            ax.legend(fontsize=8)
        return axes


def cycle_map(draws, base: ControllerSetting, grid: dict, config=PredictionConfig(),
              describing=True, progress=False) -> CycleMap:
    """Cycle predictions over a one- or two-dimensional grid of controller values.

    Parameters
    ----------
    draws : PosteriorDraws
    base : ControllerSetting
        The values not varied.
    grid : dict key -> 1-D array
        One or two of :data:`settings.GRID_KEYS`, each with at least two values.
    """
    if not 1 <= len(grid) <= 2:
        raise ValueError(f"a map varies one or two controller values (got {len(grid)})")
    keys = tuple(grid)
    values = tuple(np.asarray(grid[k], dtype=float) for k in keys)
    for k, v in zip(keys, values):
        if v.ndim != 1 or v.size < 2:
            raise ValueError(f"grid of {k} needs at least 2 points (got {v.size})")
    median = draws.median_params()
    param_sets = draws.param_sets()
    points = list(itertools.product(*values))
    settings = [base.replace(**dict(zip(keys, pt))) for pt in points]
    config = step_under_delays(_settling(config, settings), param_sets)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(points) * (len(param_sets) + 1), desc="map", unit="run")
    all_params, all_loops = [], []
    rng = np.random.default_rng(config.seed)
    for s in settings:
        theta, thetad, y, yd, x = _pilot_state(median, s, config)
        if bar is not None:
            bar.update(1)
        loop = s.closed_loop(theta0=theta, thetad0=thetad)
        all_params.extend(_own_noise([p.replace(y0=y, yd0=yd, x0=x) for p in param_sets], rng))
        all_loops.extend([loop] * len(param_sets))
    outcomes = simulate_cycles(all_params, all_loops, config,
                               progress=None if bar is None else bar.update)
    if bar is not None:
        bar.close()
    n = len(param_sets)
    shape = tuple(v.size for v in values)
    names = ("amplitude_q05", "amplitude_q50", "amplitude_q95", "frequency_q05",
             "frequency_q50", "frequency_q95", "fraction_oscillating", "fraction_diverging",
             "fraction_not_settled", "df_amplitude", "df_frequency")
    summary = {k: np.full(len(points), np.nan) for k in names}
    for i, s in enumerate(settings):
        sl = slice(i * n, (i + 1) * n)
        o = outcomes.outcome[sl]
        mask = o == CYCLE
        summary["fraction_oscillating"][i] = mask.mean()
        summary["fraction_diverging"][i] = np.mean(o == DIVERGED)
        summary["fraction_not_settled"][i] = np.mean(
            mask & (np.abs(outcomes.drift[sl]) > config.settled_drift))
        for name, arr in (("amplitude", outcomes.amplitude[sl]),
                          ("frequency", outcomes.frequency[sl])):
            if mask.any():
                q = np.quantile(arr[mask], [0.05, 0.5, 0.95])
                for qn, v in zip(("q05", "q50", "q95"), q):
                    summary[f"{name}_{qn}"][i] = v
        if describing:
            df = _describing_prediction(median, s, fast=True)
            if df["amplitude"] is not None:
                summary["df_amplitude"][i] = df["amplitude"]
                summary["df_frequency"][i] = df["frequency"]
    summary = {k: v.reshape(shape) for k, v in summary.items()}
    return CycleMap(keys=keys, values=values, summary=summary, base=base)

