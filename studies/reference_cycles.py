"""Study ``reference_cycles``: do the four reconstructed hypotheses reproduce the papers' cycles?

Hypothesis: M002, M001i, M001f and M000 (as ``docs/models.md`` reconstructs them from papers 002,
001 and 000) each produce a limit cycle at controller A (Kp 5.84, Kd 0.062, mu 12.3) close to the
HWIL measurement of paper 002 (4.89e-3 rad at 8.57 rad/s), and at controller B (Kp 9.8, Kd 0.06, mu
4.5) the cycles ``docs/models.md#reference-limit-cycles`` lists.

Deciding figure: ``cycles.png``, the last two seconds of each hypothesis' output at controllers A
and B, with the HWIL amplitude marked; ``summary.json`` holds amplitude, frequency and the
derivative's H7/H1 of every run beside the reference numbers, and how much holding the PD output
at 200 Hz (the HWIL rate) changes each cycle.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvcid.figures import pyplot
from tvcid.models import (
    CONTROLLER_A,
    CONTROLLER_B,
    HYPOTHESES,
    M000,
    ClosedLoop,
    M001f,
    M001i,
    SimulationDiverged,
    hypothesis,
    simulate,
)
from tvcid.models.hypotheses import gains_from_abc
from tvcid.models.strict_json import write_json

from .common import study_main

NAME = "reference_cycles"

#: ``docs/models.md#reference-limit-cycles`` (the tvcid columns): (amplitude rad, frequency rad/s)
REFERENCE = {
    ("M002", "A"): (4.991e-3, 8.597),
    ("M001i", "A"): (5.60e-3, 8.535),
    ("M001f", "A"): (5.73e-3, 8.589),
    ("M000", "A"): (5.43e-3, 8.49),
    ("M002", "B"): (6.73e-3, 6.67),
    ("M001i", "B"): (7.40e-3, 6.57),
    ("M000", "B"): (7.02e-3, 6.54),
}
HWIL_A = (4.89e-3, 8.57)  # paper 002 section 6


@dataclass(frozen=True)
class Config:
    t_end: float = 40.0
    window: float = 20.0


QUICK = Config(t_end=12.0, window=6.0)


def run(config: Config, seed: int, out_dir: Path) -> dict:
    """Simulate every hypothesis at both controllers; write json, npz and png; return the summary."""
    controllers = {"A": CONTROLLER_A, "B": CONTROLLER_B}
    rows, traces = [], {}
    for name in HYPOTHESES:
        for label, ctrl in controllers.items():
            tr = simulate(hypothesis(name, noise_seed=seed), ctrl, config.t_end)
            f = tr.features(window=config.window)
            ref = REFERENCE.get((name, label))
            rows.append({
                "hypothesis": name, "controller": label, "amplitude": f.amplitude,
                "frequency": f.frequency, "h7_over_h1_derivative": f.harmonic_ratio(7),
                "period_jitter": f.period_jitter,
                "reference_amplitude": ref[0] if ref else None,
                "reference_frequency": ref[1] if ref else None,
                "amplitude_error_pct": 100 * (f.amplitude / ref[0] - 1) if ref else None,
                "frequency_error_pct": 100 * (f.frequency / ref[1] - 1) if ref else None,
            })
            keep = tr.t >= tr.t[-1] - 2.0
            traces[f"{name}_{label}_t"] = tr.t[keep]
            traces[f"{name}_{label}_delta"] = tr.delta[keep]
    sampled = controller_sampling(rows, config, seed)
    summary = {"study": NAME, "config": asdict(config), "seed": seed, "hwil_controller_a": HWIL_A,
               "runs": rows, "sampled_200hz": sampled, "paper_numbers": paper_numbers(rows, sampled)}
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "summary.json", summary)
    np.savez_compressed(out_dir / "cycles.npz", **traces)
    plot(traces, out_dir / "cycles.png")
    return summary


def controller_sampling(rows, config, seed):
    """Each hypothesis at controller A with the PD output held at 200 Hz (paper 002's HWIL rate),
    beside the continuous controller's cycle in ``rows``."""
    sampled_a = ClosedLoop(CONTROLLER_A.kp, CONTROLLER_A.kd, CONTROLLER_A.mu, sample_rate=200.0)
    continuous = {r["hypothesis"]: r for r in rows if r["controller"] == "A"}
    out = []
    for name in HYPOTHESES:
        f = simulate(hypothesis(name, noise_seed=seed), sampled_a, config.t_end).features(window=config.window)
        out.append({"hypothesis": name, "amplitude": f.amplitude, "frequency": f.frequency,
                    "amplitude_raise_pct": 100 * (f.amplitude / continuous[name]["amplitude"] - 1),
                    "frequency_change_pct": 100 * (f.frequency / continuous[name]["frequency"] - 1)})
    return out


def paper_numbers(rows, sampled):
    """The papers' printed numbers this study reproduces, keyed as in ``data/papers.json``."""
    run = {(r["hypothesis"], r["controller"]): r for r in rows}
    m002, m000, m001f = run[("M002", "A")], run[("M000", "A")], run[("M001f", "A")]
    raise_pct = next(r["amplitude_raise_pct"] for r in sampled if r["hypothesis"] == "M002")
    a, _, c = M000().abc
    try:
        simulate(hypothesis("M000", **dict(zip(("gain", "damping", "stiffness"),
                                               gains_from_abc(15116.0, 202.1, 0.0475)))),
                 CONTROLLER_A, 5.0)
        printed_a = "the printed 15116 runs without diverging"
    except SimulationDiverged as exc:
        printed_a = f"the printed 15116 diverges ({exc})"
    k_k1 = M001i().feedback_gain * M001i().gain
    return {
        "p002_sim_amplitude_A": {"value": m002["amplitude"], "how": "M002 simulated at controller A"},
        "p002_sim_frequency_A": {"value": m002["frequency"], "how": "M002 simulated at controller A"},
        "p002_hwil_amplitude_A": {"value": m000["amplitude"], "how": "M000 (paper 000's final model) simulated at controller A"},
        "p002_hwil_frequency_A": {"value": m000["frequency"], "how": "M000 simulated at controller A"},
        "p002_hwil_rate": {"value": 200.0, "how": f"ClosedLoop(sample_rate=200) option: raises the M002 cycle by {raise_pct:.1f} % (the paper calls it negligible)"},
        "p001_h7_frequency": {"value": 7 * m001f["frequency"] / (2 * np.pi), "how": f"7th harmonic of M001f at controller A (H7/H1 of delta' = {m001f['h7_over_h1_derivative']:.2f})"},
        "p001_tf_s0": {"value": k_k1, "how": "K*K1 of M001i (K = 1.0697 as printed)"},
        "p001_bandpass_order": {"value": 2 * M001f().bandpass_order, "how": "poles of butter(2, band, 'bandpass')"},
        "p000_gain_A": {"value": a, "how": f"M000 uses 1511.6 (= 305500/202.1): {printed_a}"},
        "p000_gain_C": {"value": c, "how": "K3/K1 of M000"},
    }


def plot(traces, path):
    plt = pyplot()

    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=False)
    for ax, label in zip(axes, ("A", "B")):
        for name in HYPOTHESES:
            t = traces[f"{name}_{label}_t"]
            ax.plot(t - t[0], 1e3 * traces[f"{name}_{label}_delta"], label=name)
        if label == "A":
            for sign in (1, -1):
                ax.axhline(sign * 1e3 * HWIL_A[0], color="k", ls=":", lw=1)
        ax.set_title(f"controller {label}" + (" (dotted: HWIL amplitude, paper 002)" if label == "A" else ""))
        ax.set_ylabel("delta (mrad)")
    axes[-1].set_xlabel("t (s), last two seconds")
    axes[0].legend(ncol=4, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def describe(summary):
    for r in summary["runs"]:
        ref = ""
        if r["reference_amplitude"]:
            ref = f"  ref {r['reference_amplitude']:.3e} at {r['reference_frequency']:.3f}"
        print(f"{r['hypothesis']:6s} {r['controller']}  {r['amplitude']:.3e} rad at "
              f"{r['frequency']:.3f} rad/s  H7/H1 {r['h7_over_h1_derivative']:.2f}{ref}")
    for r in summary["sampled_200hz"]:
        print(f"{r['hypothesis']:6s} A, PD held at 200 Hz: amplitude {r['amplitude_raise_pct']:+.1f} %, "
              f"frequency {r['frequency_change_pct']:+.1f} %")


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
