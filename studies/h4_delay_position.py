"""Study ``h4_delay_position``: where does the transport delay sit?

Hypothesis (paper 000 section 4.2, paper 001 section 5.2): the delay acts before the first
integrator of the second-order block (paper 000's choice from the phase plane), not inside the loop
before the output integrator (paper 001's final model) nor at the output (papers 002, 001 initial).
Each position is given its best delay by a scan that matches the limit cycles at controllers A and
B and the open-loop square-wave response of the bundled (synthetic, M000) data; the positions are
then compared on those three constraints.

Deciding figure: ``comparison.png``: per position, the misfit of the best delay on each constraint,
beside the phase planes (delta, delta') of the data and of each position at controller A and the
square-wave responses. ``summary.json`` holds the scans and the ranking.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvcid.data import path as bundled_path
from tvcid.discovery.spectral import lowpass_reconstruction, noise_floor
from tvcid.figures import pyplot
from tvcid.models import (
    DelayPosition,
    InsufficientPeriodsError,
    hypothesis,
    limit_cycle_features,
    simulate_batch,
)
from tvcid.models.recording import load_recording
from tvcid.models.strict_json import write_json

from .common import study_main

NAME = "h4_delay_position"
DATA = bundled_path()


@dataclass(frozen=True)
class Config:
    closed_a: str = "m000_closed_A"
    closed_b: str = "m000_closed_B"
    square: str = "m000_open_square"
    delays_ms: tuple = tuple(np.round(np.linspace(0.2, 8.0, 40), 3))
    window: float = 15.0
    lowpass_hz: float = 10.0
    square_lowpass_hz: float = 50.0


QUICK = Config(delays_ms=tuple(np.round(np.linspace(0.2, 8.0, 9), 3)), window=10.0)


def _features(t, x):
    try:
        return limit_cycle_features(t, x)
    except InsufficientPeriodsError:
        return None


def scan_position(position, config, recs, noise):
    """Misfits of every delay of the scan for one delay position.

    Closed-loop runs carry the output noise matched to the data's floor (it enters the loop and
    raises the cycle); the square-wave responses are compared below ``square_lowpass_hz`` so the
    sensor noise does not dominate the misfit.
    """
    base = hypothesis("M000", delay_position=position, noise_power=noise.power,
                      noise_band=noise.noise_band)
    sets = [base.replace(delay=1e-3 * d, noise_seed=k) for k, d in enumerate(config.delays_ms)]
    rows = [dict(delay=1e-3 * d) for d in config.delays_ms]
    for label in ("A", "B"):
        rec = recs[label]
        t_end = float(rec.t[-1])
        res = simulate_batch(sets, rec.experiment(), t_end)
        data_f = rec.features(window=config.window)
        tail = res.t >= t_end - config.window
        for i, row in enumerate(rows):
            f = None if res.diverged[i] else _features(res.t[tail], res.signal("delta")[i, tail])
            row[f"amplitude_{label}_pct"] = np.nan if f is None else 100 * (f.amplitude / data_f.amplitude - 1)
            row[f"frequency_{label}_pct"] = np.nan if f is None else 100 * (f.frequency / data_f.frequency - 1)
    square = recs["square"]
    quiet = [p.replace(noise_power=0.0) for p in sets]
    res = simulate_batch(quiet, square.experiment(), float(square.t[-1]), rate=square.sample_rate)
    n = min(res.t.size, square.t.size)
    data = lowpass_reconstruction(square.t[:n], square.delta[:n], config.square_lowpass_hz).delta
    scale = np.sqrt(np.mean(data**2))
    for i, row in enumerate(rows):
        if res.diverged[i]:
            row["square_rms_pct"] = np.nan
            continue
        sim = lowpass_reconstruction(res.t[:n], res.signal("delta")[i, :n], config.square_lowpass_hz).delta
        row["square_rms_pct"] = 100 * np.sqrt(np.mean((sim - data) ** 2)) / scale
    keys = ("amplitude_A_pct", "frequency_A_pct", "amplitude_B_pct", "frequency_B_pct", "square_rms_pct")
    for row in rows:
        row["score"] = float(np.sqrt(np.mean([row[k] ** 2 for k in keys])))
    return rows


def run(config: Config, seed: int, out_dir: Path) -> dict:
    recs = {"A": load_recording(DATA / f"{config.closed_a}.csv"),
            "B": load_recording(DATA / f"{config.closed_b}.csv"),
            "square": load_recording(DATA / f"{config.square}.csv")}
    noise = noise_floor(recs["A"])
    positions, arrays = {}, {}
    for position in DelayPosition:
        rows = scan_position(position.value, config, recs, noise)
        finite = [r for r in rows if np.isfinite(r["score"])]
        best = min(finite, key=lambda r: r["score"]) if finite else None
        positions[position.value] = {"scan": rows, "best": best}
        if best is None:
            continue
        params = hypothesis("M000", delay_position=position, delay=best["delay"])  # noise-free view
        for label, rec in (("A", recs["A"]), ("square", recs["square"])):
            res = simulate_batch([params], rec.experiment(), float(rec.t[-1]), rate=rec.sample_rate)
            arrays[f"{position.value}_{label}_t"] = res.t
            arrays[f"{position.value}_{label}_delta"] = res.signal("delta")[0]
    ranking = sorted((p for p in positions if positions[p]["best"]),
                     key=lambda p: positions[p]["best"]["score"])
    summary = {"study": NAME, "config": asdict(config), "seed": seed, "positions": positions,
               "ranking": ranking, "winner": ranking[0] if ranking else None,
               "noise_floor": noise.to_dict(),
               "truth": recs["A"].meta["parameters"]["delay_position"]}
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "summary.json", summary, default=float)
    np.savez_compressed(out_dir / "traces.npz", **arrays)
    plot(summary, arrays, recs, config, out_dir / "comparison.png")
    return summary


def plot(summary, arrays, recs, config, path):
    plt = pyplot()
    fig, grid = plt.subplots(2, 2, figsize=(12, 8.5))
    axes = [grid[0, 0], grid[1, 0], grid[1, 1]]
    for name, pos in summary["positions"].items():
        delays = [1e3 * r["delay"] for r in pos["scan"]]
        grid[0, 1].plot(delays, [r["score"] for r in pos["scan"]], "o-", ms=3, label=name)
    grid[0, 1].set_xlabel("delay Td (ms)")
    grid[0, 1].set_ylabel("rms misfit over the five constraints (%)")
    grid[0, 1].set_yscale("log")
    grid[0, 1].set_title("delay scan per position")
    grid[0, 1].legend(fontsize=7)
    keys = ("amplitude_A_pct", "frequency_A_pct", "amplitude_B_pct", "frequency_B_pct", "square_rms_pct")
    names = list(summary["positions"])
    width = 0.8 / len(names)
    for j, name in enumerate(names):
        best = summary["positions"][name]["best"]
        if best is None:
            continue
        values = [abs(best[k]) for k in keys]
        axes[0].bar(np.arange(len(keys)) + j * width, values, width,
                    label=f"{name} (Td {1e3 * best['delay']:.2f} ms)")
    axes[0].set_xticks(np.arange(len(keys)) + 0.4 - width / 2)
    axes[0].set_xticklabels(["amp A", "freq A", "amp B", "freq B", "square"], fontsize=8)
    axes[0].set_ylabel("|misfit| (%) at the best delay")
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=7)
    rec = recs["A"]
    # two seconds away from the record's end, where the IFFT reconstruction rings
    keep = (rec.t >= rec.t[-1] - 3.0) & (rec.t < rec.t[-1] - 1.0)
    d = lowpass_reconstruction(rec, cutoff_hz=config.lowpass_hz).derivative
    axes[1].plot(1e3 * rec.delta[keep], 1e3 * d[keep], "k", lw=2, alpha=0.4, label="data")
    axes[2].plot(recs["square"].t, 1e3 * recs["square"].delta, "k", lw=2, alpha=0.4, label="data")
    for name in names:
        if f"{name}_A_t" not in arrays:
            continue
        t, x = arrays[f"{name}_A_t"], arrays[f"{name}_A_delta"]
        dx = lowpass_reconstruction(t, x, config.lowpass_hz).derivative
        k = (t >= t[-1] - 3.0) & (t < t[-1] - 1.0)
        axes[1].plot(1e3 * x[k], 1e3 * dx[k], lw=0.8, label=name)
        axes[2].plot(arrays[f"{name}_square_t"], 1e3 * arrays[f"{name}_square_delta"], lw=0.8, label=name)
    axes[1].set_xlabel("delta (mrad)")
    axes[1].set_ylabel(f"delta' below {config.lowpass_hz:g} Hz (mrad/s)")
    axes[1].set_title("phase plane, controller A")
    axes[2].set_xlim(0, 2.0)
    axes[2].set_xlabel("t (s)")
    axes[2].set_ylabel("delta (mrad)")
    axes[2].set_title("open-loop square wave")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def describe(summary):
    for name in summary["ranking"]:
        best = summary["positions"][name]["best"]
        print(f"{name:24s} Td {1e3 * best['delay']:.2f} ms  score {best['score']:.3f}  "
              f"A {best['amplitude_A_pct']:+.2f}/{best['frequency_A_pct']:+.2f} %  "
              f"B {best['amplitude_B_pct']:+.2f}/{best['frequency_B_pct']:+.2f} %  "
              f"square {best['square_rms_pct']:.2f} %")
    print(f"winner {summary['winner']} (truth of the synthetic data: {summary['truth']})")


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
