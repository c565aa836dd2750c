"""Study ``h1_deadzone_backlash``: paper 002's describing-function identification of the dead zone
and the backlash, and what one limit cycle really pins down.

Hypothesis (paper 002): the HWIL cycle at controller A (4.89e-3 rad at 8.57 rad/s) and the
describing functions of the dead zone (eq. 3) and the backlash (eqs. 4-5) determine (f, zm) through
eqs. 13-18; the printed pair is f = 4.364e-4, zm = 1.2e-3. tvcid checks the equations as printed
and corrected (three slips, ``docs/models.md#errata``), the exact harmonic balance, how far the DF
prediction is from the simulated cycle, what the family members do when simulated, and where an
MCMC posterior on one cycle lies relative to the family and how controller B and open-loop tests
shrink it (the chains are run by ``calibration_ridge`` into ``mcmc_ridge/``).

Deciding figure: ``family.png``: the corrected and printed families, the printed pair, and the cycle
each family member produces in simulation; ``df_vs_simulation.png``; ``mcmc_ridge/ridge.png``:
posterior samples of (f, zm) over the family, one cycle against controller B, open-loop tests and
the waveform. ``summary.json`` holds the numbers, including the exact solve's "no solution"
statement and the ridge's correlations and widths.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from tvcid.discovery.describing import (
    NoHarmonicBalanceSolution,
    compare_with_simulation,
    paper002_family,
    solve_backlash_and_dead_zone,
)
from tvcid.figures import pyplot
from tvcid.models import (
    CONTROLLER_A,
    CONTROLLER_B,
    M002,
    M001i,
    limit_cycle_features,
    simulate_batch,
)
from tvcid.models.strict_json import write_json

from . import calibration_ridge
from .common import study_main

NAME = "h1_deadzone_backlash"
HWIL_A = (4.89e-3, 8.57)  # paper 002 section 6
PRINTED_PAIR = (4.364e-4, 1.2e-3)  # paper 002 section 6: (f, zm)


@dataclass(frozen=True)
class Config:
    family_widths: tuple = tuple(np.round(np.geomspace(5e-5, 1.2e-3, 15), 8))
    t_end: float = 40.0
    window: float = 20.0
    ridge: calibration_ridge.Config = calibration_ridge.Config()


# the quick ridge's M002-M001i comparison is a smoke run: 20 steps from each hypothesis' local
# maximum, without the global search (no quick check reads it)
QUICK = Config(family_widths=tuple(np.round(np.geomspace(5e-5, 1.2e-3, 5), 8)), t_end=15.0, window=8.0,
               ridge=replace(calibration_ridge.QUICK, compare_steps=20, compare_global_search=False))


def simulate_family(family, config):
    """Each (backlash half width, dead zone) of ``family`` simulated as M002 at controller A."""
    pairs = [(f, z) for f, z in zip(family.backlash_half_width, family.dead_zone) if np.isfinite(z)]
    sets = [M002().replace(backlash=float(f), dead_zone=float(z)) for f, z in pairs]
    res = simulate_batch(sets, CONTROLLER_A, config.t_end)
    tail = res.t >= config.t_end - config.window
    rows = []
    for i, (f, z) in enumerate(pairs):
        feats = None if res.diverged[i] else limit_cycle_features(res.t[tail], res.signal("delta")[i, tail])
        rows.append({"backlash_half_width": float(f), "dead_zone": float(z),
                     "amplitude": feats.amplitude if feats else None,
                     "frequency": feats.frequency if feats else None})
    return rows


def run(config: Config, seed: int, out_dir: Path) -> dict:
    amp, freq = HWIL_A
    corrected = paper002_family(amp, freq, CONTROLLER_A, params=M002(), backlash_half_widths=config.family_widths)
    printed = paper002_family(amp, freq, CONTROLLER_A, params=M002(), backlash_half_widths=config.family_widths,
                              variant="printed")
    at_printed_f = paper002_family(amp, freq, CONTROLLER_A, params=M002(),
                                   backlash_half_widths=[PRINTED_PAIR[0], PRINTED_PAIR[0] / 2])
    ok = np.isfinite(corrected.dead_zone)
    # the corrected family's backlash where its dead zone equals the printed 1.2e-3
    f_at_printed_zm = float(np.interp(PRINTED_PAIR[1], corrected.dead_zone[ok], corrected.backlash_half_width[ok]))
    try:
        exact = [p.to_dict() for p in solve_backlash_and_dead_zone(amp, freq, CONTROLLER_A, M002())]
        exact_message = None
    except NoHarmonicBalanceSolution as exc:
        exact, exact_message = [], str(exc)
    paper001 = [p.to_dict() for p in solve_backlash_and_dead_zone(amp, freq, CONTROLLER_A, M001i())]
    comparisons = []
    for params in (M002(), M001i()):
        for label, ctrl in (("A", CONTROLLER_A), ("B", CONTROLLER_B)):
            c = compare_with_simulation(params, ctrl, t_end=config.t_end, window=config.window)
            comparisons.append({"hypothesis": params.name, "controller": label, **c.to_dict(),
                                "amplitude_error_pct": 100 * c.amplitude_error,
                                "frequency_error_pct": 100 * c.frequency_error})
    simulated = simulate_family(corrected, config)
    ridge = calibration_ridge.run(config.ridge, seed, out_dir / "mcmc_ridge")
    summary = {
        "study": NAME, "config": asdict(config), "seed": seed,
        "hwil_cycle": {"amplitude": amp, "frequency": freq},
        "family_corrected": corrected.to_dict(), "family_printed": printed.to_dict(),
        "dead_zone_at_printed_f": {"f_as_half_width": float(at_printed_f.dead_zone[0]),
                                   "f_as_full_width": float(at_printed_f.dead_zone[1])},
        "backlash_at_printed_zm": f_at_printed_zm,
        "exact_solution": exact, "exact_solution_message": exact_message,
        "paper001_exact": paper001,
        "df_vs_simulation": comparisons,
        "family_simulated": simulated,
        "mcmc_ridge": {"rows": ridge["ridge"]["rows"], "comparison": ridge["comparison"]["table"],
                       "details": "mcmc_ridge/summary.json"},
        "paper_numbers": {
            "p002_backlash": {"value": f_at_printed_zm,
                              "how": "corrected paper 002 family at zm = 1.2e-3 (f as half width); "
                                     "the printed pair lies between the width conventions"},
            "p002_dead_zone": {"value": float(at_printed_f.dead_zone[0]),
                               "how": "corrected paper 002 family at f = 4.364e-4 as half width "
                                      f"({at_printed_f.dead_zone[1]:.4g} with f as full width)"},
        },
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "summary.json", summary, default=float)
    plot_family(corrected, printed, simulated, out_dir / "family.png")
    plot_comparison(comparisons, out_dir / "df_vs_simulation.png")
    return summary


def plot_family(corrected, printed, simulated, path):
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    corrected.plot(ax=axes[0], label="corrected (docs/models.md errata)")
    printed.plot(ax=axes[0], label="as printed")
    axes[0].plot(*PRINTED_PAIR, "k*", ms=12, label="printed pair (f, zm)")
    axes[0].plot(PRINTED_PAIR[0] / 2, PRINTED_PAIR[1], "kx", ms=9, label="printed pair, f as full width")
    axes[0].set_xscale("log")
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"paper 002 family for {HWIL_A[0]:.3g} rad at {HWIL_A[1]:g} rad/s, Td 7 ms")
    ok = [r for r in simulated if r["amplitude"] is not None]
    f = [r["backlash_half_width"] for r in ok]
    ax = axes[1]
    ax.plot(f, [1e3 * r["amplitude"] for r in ok], "o-", label="amplitude (mrad)")
    ax.axhline(1e3 * HWIL_A[0], color="C0", ls=":")
    ax.set_xscale("log")
    ax.set_xlabel("backlash half width r of the family member (rad)")
    ax.set_ylabel("simulated amplitude (mrad)")
    twin = ax.twinx()
    twin.plot(f, [r["frequency"] for r in ok], "s-", color="C1", label="frequency")
    twin.axhline(HWIL_A[1], color="C1", ls=":")
    twin.set_ylabel("simulated frequency (rad/s)")
    ax.set_title("family members simulated (dotted: the HWIL cycle)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_comparison(rows, path):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    labels = [f"{r['hypothesis']} {r['controller']}" for r in rows]
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["amplitude_error_pct"] for r in rows], 0.4, label="first-harmonic amplitude")
    ax.bar(x + 0.2, [r["frequency_error_pct"] for r in rows], 0.4, label="frequency")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(x)
    ax.set_xticklabels(labels)
    ax.set_ylabel("DF prediction vs simulation (%)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def describe(summary):
    d = summary["dead_zone_at_printed_f"]
    print(f"corrected family: zm = {d['f_as_half_width']:.4e} at f = 4.364e-4 (half width), "
          f"{d['f_as_full_width']:.4e} (full width); f = {summary['backlash_at_printed_zm']:.4e} at zm = 1.2e-3")
    print(f"exact harmonic balance: {summary['exact_solution_message'] or summary['exact_solution']}")
    print(f"paper 001 exact: {summary['paper001_exact']}")
    for r in summary["df_vs_simulation"]:
        print(f"{r['hypothesis']} {r['controller']}: DF {r['amplitude_error_pct']:+.1f} % amplitude, "
              f"{r['frequency_error_pct']:+.1f} % frequency")
    for r in summary["mcmc_ridge"]["rows"]:
        print(f"MCMC {r['label']}: corr(ln f, ln zm) {r['corr_log_pair']:.3f}, "
              f"90 % widths f {r['width90_relative']['backlash']:.3g}, zm {r['width90_relative']['dead_zone']:.3g}, "
              f"truth inside: {all(r['truth_inside_90'].values())}")


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
