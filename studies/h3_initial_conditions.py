"""Study ``h3_initial_conditions``: paper 000's limit-cycle bifurcation by initial conditions.

Hypothesis (paper 000 section 4.1): the model's second-order block hides two integrators whose
initial conditions, with that of the output integrator, select between coexisting limit cycles;
changing the output integrator's initial condition x(0) alone does not reach the second cycle.
Tested on M000 with the band-pass loop that locks the cycle (F 48, saturation 0.015,
``docs/models.md#m000``).

Deciding figure: ``basins.png``, the attractor reached from each initial condition on three slices
of (y(0), y'(0), x(0)); the small cycle's basin must exist on slices that move y(0) or y'(0) and be
absent from the x(0) axis. ``phase_planes.png`` shows the two coexisting cycles.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvcid.figures import pyplot
from tvcid.models import CONTROLLER_A, hypothesis, simulate, simulate_batch
from tvcid.models.strict_json import write_json

from .common import study_main

NAME = "h3_initial_conditions"

#: Attractor classes by the amplitude (rad) of the last seconds of a run.
LARGE_MIN, REST_MAX = 2e-3, 1e-5
CLASSES = ("rest", "small", "large", "diverged")


@dataclass(frozen=True)
class Config:
    grid: int = 41
    t_end: float = 15.0
    tail: float = 3.0
    y_range: float = 0.2          # y(0) in [-y_range, y_range] (rad/s)
    yd_range: float = 50.0        # y'(0) in [-yd_range, yd_range] (rad/s^2)
    x_range: float = 0.01         # x(0) in [-x_range, x_range] (rad)
    bandpass_gain: float = 48.0
    bandpass_saturation: float = 0.015


QUICK = Config(grid=11, t_end=10.0, tail=2.0)


def model(config):
    return hypothesis("M000", bandpass_gain=config.bandpass_gain,
                      bandpass_saturation=config.bandpass_saturation)


def classify(amplitude, diverged):
    """Attractor class index (into :data:`CLASSES`) from the tail amplitude."""
    cls = np.where(amplitude > LARGE_MIN, 2, np.where(amplitude > REST_MAX, 1, 0))
    return np.where(diverged, 3, cls)


def basin_slice(config, base, axes):
    """Classes on a grid over two of (y0, yd0, x0); the third is held at ``axes['fixed']``."""
    (name_a, range_a), (name_b, range_b) = axes["vary"]
    a = np.linspace(-range_a, range_a, config.grid)
    b = np.linspace(-range_b, range_b, config.grid)
    A, B = np.meshgrid(a, b)
    fixed = axes["fixed"]
    sets = [base.replace(**{name_a: va, name_b: vb}, **fixed) for va, vb in zip(A.ravel(), B.ravel())]
    result = simulate_batch(sets, CONTROLLER_A, config.t_end, rate=500.0)
    tail = result.t >= config.t_end - config.tail
    delta = result.signal("delta")[:, tail]
    amp = 0.5 * (np.nanmax(delta, axis=1) - np.nanmin(delta, axis=1))
    amp = np.where(result.diverged, np.nan, amp)
    return a, b, classify(amp, result.diverged).reshape(A.shape), amp.reshape(A.shape)


SLICES = (
    {"title": "y'(0) = 0", "vary": (("y0", "y_range"), ("x0", "x_range")), "fixed": {"yd0": 0.0}},
    {"title": "x(0) = 0", "vary": (("y0", "y_range"), ("yd0", "yd_range")), "fixed": {"x0": 0.0}},
    {"title": "y(0) = 0", "vary": (("yd0", "yd_range"), ("x0", "x_range")), "fixed": {"y0": 0.0}},
)
LABELS = {"y0": "y(0) (rad/s)", "yd0": "y'(0) (rad/s^2)", "x0": "x(0) (rad)"}


def run(config: Config, seed: int, out_dir: Path) -> dict:
    base = model(config)
    slices, arrays = [], {}
    for i, spec in enumerate(SLICES):
        vary = tuple((n, getattr(config, r)) for n, r in spec["vary"])
        a, b, cls, amp = basin_slice(config, base, {"vary": vary, "fixed": spec["fixed"]})
        counts = {c: int(np.sum(cls == k)) for k, c in enumerate(CLASSES)}
        slices.append({"title": spec["title"], "axes": [n for n, _ in vary], "counts": counts})
        arrays.update({f"slice{i}_a": a, f"slice{i}_b": b, f"slice{i}_class": cls, f"slice{i}_amp": amp})
    # x(0) alone (y(0) = y'(0) = 0): the output integrator's condition by itself
    x_axis = np.linspace(-config.x_range, config.x_range, 2 * config.grid + 1)
    x_axis = x_axis[x_axis != 0.0]
    res = simulate_batch([base.replace(y0=0.0, yd0=0.0, x0=v) for v in x_axis], CONTROLLER_A,
                         config.t_end, rate=500.0)
    tail = res.t >= config.t_end - config.tail
    d = res.signal("delta")[:, tail]
    x_only = classify(0.5 * (np.nanmax(d, 1) - np.nanmin(d, 1)), res.diverged)
    # the two coexisting cycles, from the paper's conditions and from y(0) = 0.1 alone
    large = simulate(base, CONTROLLER_A, 40.0)
    small = simulate(base.replace(y0=0.1, yd0=0.0, x0=0.0), CONTROLLER_A, 40.0)
    fl, fs = large.features(window=15), small.features(window=15)
    for label, tr in (("large", large), ("small", small)):
        keep = tr.t >= tr.t[-1] - 3.0
        arrays[f"{label}_x"], arrays[f"{label}_w"] = tr.x[keep], tr.w[keep]
    summary = {
        "study": NAME, "config": asdict(config), "seed": seed,
        "model": base.to_dict(), "slices": slices,
        "x0_alone_classes": {c: int(np.sum(x_only == k)) for k, c in enumerate(CLASSES)},
        "large_cycle": {"amplitude": fl.amplitude, "frequency": fl.frequency,
                        "initial_conditions": {"y0": base.y0, "yd0": base.yd0, "x0": base.x0}},
        "small_cycle": {"amplitude": fs.amplitude, "frequency": fs.frequency,
                        "period_jitter": fs.period_jitter,
                        "initial_conditions": {"y0": 0.1, "yd0": 0.0, "x0": 0.0}},
    }
    summary["small_basin_off_x_axis"] = any(s["counts"]["small"] > 0 for s in slices)
    summary["x0_alone_reaches_small"] = summary["x0_alone_classes"]["small"] > 0
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "summary.json", summary)
    np.savez_compressed(out_dir / "basins.npz", **arrays)
    plot_basins(arrays, out_dir / "basins.png")
    plot_phase_planes(arrays, summary, out_dir / "phase_planes.png")
    return summary


def plot_basins(arrays, path):
    plt = pyplot()
    from matplotlib.colors import ListedColormap

    cmap = ListedColormap(["#dddddd", "#d62728", "#1f77b4", "#000000"])
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2))
    for i, (ax, spec) in enumerate(zip(axes, SLICES)):
        a, b, cls = arrays[f"slice{i}_a"], arrays[f"slice{i}_b"], arrays[f"slice{i}_class"]
        ax.pcolormesh(a, b, cls, cmap=cmap, vmin=-0.5, vmax=3.5, shading="nearest")
        ax.set_xlabel(LABELS[spec["vary"][0][0]])
        ax.set_ylabel(LABELS[spec["vary"][1][0]])
        ax.set_title(spec["title"])
    handles = [plt.Rectangle((0, 0), 1, 1, color=cmap(k)) for k in range(4)]
    fig.legend(handles, ["rest", "small cycle", "large cycle", "diverged"], loc="lower center", ncol=4)
    fig.suptitle("M000 (F 48, sat 0.015), controller A: attractor by initial condition")
    fig.tight_layout(rect=(0, 0.07, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_phase_planes(arrays, summary, path):
    plt = pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, label in zip(axes, ("large", "small")):
        ax.plot(1e3 * arrays[f"{label}_x"], 1e3 * arrays[f"{label}_w"], lw=0.8)
        c = summary[f"{label}_cycle"]
        ax.set_title(f"{label} cycle: {c['amplitude']:.2e} rad at {c['frequency']:.2f} rad/s")
        ax.set_xlabel("x (mrad)")
        ax.set_ylabel("x' (mrad/s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def describe(summary):
    for s in summary["slices"]:
        print(f"slice {s['title']:10s} {s['counts']}")
    print(f"x(0) alone: {summary['x0_alone_classes']}")
    for label in ("large", "small"):
        c = summary[f"{label}_cycle"]
        print(f"{label} cycle: {c['amplitude']:.3e} rad at {c['frequency']:.3f} rad/s")


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
