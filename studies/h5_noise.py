"""Study ``h5_noise``: the output noise, its floor, and what it does to the cycle and to identification.

Hypothesis (paper 000 section 4.3): the actuator output carries a small noise, flat between 20 and
100 Hz, that a band-limited white noise added to the output (inside the loop) models; its power can
be read off that floor, and "very small noise levels influence the limit cycle seen on closed loop
analysis, which may influence identification results".

Checks: (1) the noise-floor estimate recovers the power the bundled (synthetic, M000) recordings were
made with; (2) a sweep of noise power on M000 at controller A separates what noise does to the
measured amplitude ``(max-min)/2`` of delta from what it does to the actuator's own cycle (x) and to
the first harmonic; (3) paper 002's describing-function identification (dead zone at the true
backlash, M002 structure) run on noisy cycles shows the bias each amplitude measure carries into
the identified dead zone.

Deciding figure: ``noise.png`` (floor of the closed-loop A record; amplitude measures vs noise;
identified dead zone vs noise). ``summary.json`` holds every number.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvcid.data import path as bundled_path
from tvcid.discovery.describing.inverse import paper002_family
from tvcid.discovery.spectral import noise_floor
from tvcid.figures import pyplot
from tvcid.models import CONTROLLER_A, hypothesis, limit_cycle_features, simulate_batch
from tvcid.models.noise import noise_std
from tvcid.models.recording import load_recording
from tvcid.models.strict_json import write_json

from .common import study_main

NAME = "h5_noise"
DATA = bundled_path()
RECORDINGS = ("m000_closed_A", "m000_closed_B", "m000_open_square", "m000_open_sine")


@dataclass(frozen=True)
class Config:
    powers: tuple = (0.0, 1e-14, 1e-13, 4e-13, 1e-12, 1e-11, 3e-11)
    seeds: int = 8
    t_end: float = 30.0
    window: float = 15.0


QUICK = Config(powers=(0.0, 4e-13, 1e-11), seeds=2, t_end=15.0, window=8.0)


def floor_check():
    """Noise floor of every bundled recording against the power it was generated with."""
    rows = []
    for name in RECORDINGS:
        rec = load_recording(DATA / f"{name}.csv")
        truth = rec.meta["parameters"]["noise_power"]
        floor = noise_floor(rec, noise_band=rec.meta["parameters"]["noise_band"])
        rows.append({"recording": name, "true_power": truth, "estimated_power": floor.power,
                     "error_pct": 100 * (floor.power / truth - 1), "floor_psd": floor.psd,
                     "std": floor.std})
    return rows


def _sweep(name, config, rate=1000.0):
    """Features of ``name`` at controller A for every noise power and seed."""
    base = hypothesis(name)
    sets = [base.replace(noise_power=p, noise_seed=s) for p in config.powers for s in range(config.seeds)]
    res = simulate_batch(sets, CONTROLLER_A, config.t_end, rate=rate)
    tail = res.t >= config.t_end - config.window
    out = []
    for i, params in enumerate(sets):
        if res.diverged[i]:
            out.append(None)
            continue
        t = res.t[tail]
        fd = limit_cycle_features(t, res.signal("delta")[i, tail])
        fx = limit_cycle_features(t, res.signal("x")[i, tail])
        out.append({"power": params.noise_power, "seed": params.noise_seed,
                    "amplitude_delta": fd.amplitude, "h1_delta": fd.harmonics[0],
                    "amplitude_x": fx.amplitude, "frequency": fd.frequency,
                    "jitter": fd.period_jitter, "h7_h1": fd.harmonic_ratio(7)})
    return out


def _by_power(rows, config, key):
    mean, sd = [], []
    for p in config.powers:
        vals = [r[key] for r in rows if r is not None and r["power"] == p]
        mean.append(float(np.mean(vals)) if vals else np.nan)
        sd.append(float(np.std(vals)) if vals else np.nan)
    return mean, sd


def run(config: Config, seed: int, out_dir: Path) -> dict:
    floors = floor_check()
    cycle = _sweep("M000", config)
    effect = {key: _by_power(cycle, config, key)
              for key in ("amplitude_delta", "amplitude_x", "h1_delta", "frequency", "jitter", "h7_h1")}
    # identification: paper 002's DF family on M002 cycles, dead zone at the true backlash
    m002 = hypothesis("M002")
    ident_rows = _sweep("M002", config)
    ident = {}
    for key in ("amplitude_delta", "h1_delta"):
        zm = []
        for p in config.powers:
            vals = []
            for r in ident_rows:
                if r is None or r["power"] != p:
                    continue
                fam = paper002_family(r[key], r["frequency"], CONTROLLER_A, params=m002,
                                      backlash_half_widths=[m002.backlash])
                vals.append(float(fam.dead_zone[0]))
            zm.append((float(np.nanmean(vals)), float(np.nanstd(vals))) if vals else (np.nan, np.nan))
        ident[key] = zm
    noise_free = {k: v[0][0] for k, v in ident.items()}
    summary = {
        "study": NAME, "config": asdict(config), "seed": seed,
        "floor": floors,
        "max_floor_error_pct": float(max(abs(r["error_pct"]) for r in floors)),
        "noise_std": [noise_std(p, 500.0) for p in config.powers],
        "cycle_effect": {k: {"mean": v[0], "sd": v[1]} for k, v in effect.items()},
        "identified_dead_zone": {k: {"mean": [z[0] for z in v], "sd": [z[1] for z in v],
                                     "bias_pct_vs_noise_free": [100 * (z[0] / noise_free[k] - 1) for z in v]}
                                 for k, v in ident.items()},
        "true_dead_zone_m002": m002.dead_zone,
        "paper_numbers": {
            "p000_noise_band_low": {"value": 20.0, "how": "floor band used by tvcid.discovery.spectral.noise_floor (power recovered within "
                                    f"{max(abs(r['error_pct']) for r in floors):.1f} % on the bundled data)"},
            "p000_noise_band_high": {"value": 100.0, "how": "floor band used by tvcid.discovery.spectral.noise_floor"},
        },
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "summary.json", summary)
    plot(summary, config, out_dir / "noise.png")
    return summary


def plot(summary, config, path):
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    noise_floor(load_recording(DATA / f"{RECORDINGS[0]}.csv")).plot(ax=axes[0])
    axes[0].set_title(f"noise floor, {RECORDINGS[0]} (synthetic)")
    std = np.array(summary["noise_std"])
    x = np.where(std > 0, std, np.nan)
    eff = summary["cycle_effect"]
    for key, label in (("amplitude_delta", "(max-min)/2 of delta"), ("amplitude_x", "(max-min)/2 of x"),
                       ("h1_delta", "first harmonic of delta")):
        axes[1].errorbar(1e6 * x, 1e3 * np.array(eff[key]["mean"]), yerr=1e3 * np.array(eff[key]["sd"]),
                         marker="o", ms=3, capsize=2, label=label)
    axes[1].set_xscale("log")
    axes[1].set_xlabel("noise std (micro rad)")
    axes[1].set_ylabel("M000 cycle at controller A (mrad)")
    axes[1].legend(fontsize=8)
    ident = summary["identified_dead_zone"]
    for key, label in (("amplitude_delta", "from (max-min)/2"), ("h1_delta", "from first harmonic")):
        axes[2].plot(1e6 * x, ident[key]["bias_pct_vs_noise_free"], "o-", ms=3, label=label)
    axes[2].set_xscale("log")
    axes[2].set_xlabel("noise std (micro rad)")
    axes[2].set_ylabel("identified dead zone, % vs noise-free")
    axes[2].set_title("paper 002 DF identification (M002, true backlash)")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def describe(summary):
    for r in summary["floor"]:
        print(f"{r['recording']:18s} power {r['estimated_power']:.3e} (true {r['true_power']:.1e}, {r['error_pct']:+.1f} %)")
    eff = summary["cycle_effect"]
    for p, s, ad, ax in zip(summary["config"]["powers"], summary["noise_std"],
                            eff["amplitude_delta"]["mean"], eff["amplitude_x"]["mean"]):
        print(f"power {p:.0e} (std {s:.1e}): amplitude delta {ad:.4e}, x {ax:.4e}")


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
