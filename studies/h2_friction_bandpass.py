"""Study ``h2_friction_bandpass``: paper 001's FFT argument for the friction offset and the
band-pass feedback loop.

Hypothesis (paper 001 sections 3-4): the output's derivative, rebuilt from the FFT below 10 Hz,
shows spikes where it crosses zero (an offset opposing the motion: a negative Coulomb friction
before the integrator), and its spectrum rises between 9 and 10 Hz around the 7th harmonic
(9.57 Hz) where the describing-function model (M002, M001i) decays smoothly; a 9-10 Hz band-pass
feedback loop with a saturation (M001f) reproduces it. tvcid compares the spectra of the bundled
(synthetic, M000 with Table 1) record at controller A with those of M002, M001i and M001f, flags
raised harmonics, and asks SINDy which structure the record supports.

Deciding figure: ``spectra.png``: the derivative's amplitude spectra below 15 Hz with flagged
harmonics, and the reconstructed derivative of the record against the hypotheses'.
``summary.json`` holds the harmonic tables and the SINDy proposals.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvcid.data import path as bundled_path
from tvcid.discovery.spectral import (
    amplitude_spectrum,
    harmonic_table,
    lowpass_reconstruction,
)
from tvcid.figures import pyplot
from tvcid.models import CONTROLLER_A, hypothesis, simulate
from tvcid.models.recording import load_recording
from tvcid.models.strict_json import write_json

from .common import study_main

NAME = "h2_friction_bandpass"
DATA = bundled_path()
MODELS_COMPARED = ("M002", "M001i", "M001f")


@dataclass(frozen=True)
class Config:
    recording: str = "m000_closed_A"
    window: float = 20.0
    t_end: float = 40.0
    cutoff_hz: float = 10.0
    max_hz: float = 15.0


QUICK = Config(window=20.0, t_end=30.0)  # shorter windows leak the periodic models into 9-10 Hz


def _tail(t, x, seconds):
    keep = t >= t[-1] - seconds
    return t[keep], x[keep]


def band_energy_ratio(spectrum, band_hz=(9.0, 10.0), fundamental_hz=None):
    """RMS of the derivative spectrum over ``band_hz`` over that around the fundamental.

    Unlike the 7th harmonic's own bin, this counts 9-10 Hz energy that is not phase-locked to the
    cycle (M000 with Table 1 is not periodic: its loop's oscillation drifts against the 7th
    harmonic and smears over the band).
    """
    f, a = spectrum.frequency_hz, spectrum.amplitude
    in_band = (f >= band_hz[0]) & (f <= band_hz[1])
    near = np.abs(f - fundamental_hz) <= 0.3 * fundamental_hz
    return float(np.sqrt(np.sum(a[in_band] ** 2) / np.sum(a[near] ** 2)))


def run(config: Config, seed: int, out_dir: Path) -> dict:
    rec = load_recording(DATA / f"{config.recording}.csv")
    signals = {"data": _tail(rec.t, rec.delta, config.window)}
    for name in MODELS_COMPARED:
        tr = simulate(hypothesis(name, noise_seed=seed), CONTROLLER_A, config.t_end)
        signals[name] = _tail(tr.t, tr.delta, config.window)
    tables, spectra, recon = {}, {}, {}
    for label, (t, x) in signals.items():
        table = harmonic_table(t, x, derivative=True)
        tables[label] = {"fundamental_hz": table.fundamental_hz, "rows": table.rows(),
                         "raised": list(table.raised_harmonics)}
        spectra[label] = amplitude_spectrum(t, x, derivative=True)
        recon[label] = lowpass_reconstruction(t, x, config.cutoff_hz)
    band = {label: band_energy_ratio(spectra[label], fundamental_hz=tables[label]["fundamental_hz"])
            for label in signals}
    seventh = {label: next(r for r in tab["rows"] if r["harmonic"] == 7) for label, tab in tables.items()}
    summary = {
        "study": NAME, "config": asdict(config), "seed": seed,
        "harmonic_tables": tables,
        "seventh_harmonic": {k: {"frequency_hz": v["frequency_hz"], "ratio": v["ratio"]} for k, v in seventh.items()},
        "band_9_10_hz_ratio": band,
        "paper_numbers": {
            "p001_lowpass_cutoff": {"value": config.cutoff_hz,
                                    "how": "cut-off of the IFFT reconstruction (tvcid.discovery.spectral default)"},
        },
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "summary.json", summary, default=float)
    plot(spectra, recon, tables, config, out_dir / "spectra.png")
    return summary


def plot(spectra, recon, tables, config, path):
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(10, 8))
    for label, spec in spectra.items():
        f = spec.frequency_hz
        keep = f <= config.max_hz
        axes[0].semilogy(f[keep], spec.amplitude[keep], lw=0.9, label=label + (" (synthetic record)" if label == "data" else ""))
        for k in tables[label]["raised"]:
            row = next(r for r in tables[label]["rows"] if r["harmonic"] == k)
            axes[0].plot(row["frequency_hz"], row["amplitude"], "v", ms=9, color="k")
    axes[0].axvspan(9, 10, color="0.9", zorder=0, label="9-10 Hz (paper 001)")
    axes[0].set_xlabel("frequency (Hz)")
    axes[0].set_ylabel("|FFT| of delta' (rad/s)")
    axes[0].set_title("derivative spectra at controller A (triangles: flagged raised harmonics)")
    axes[0].legend(fontsize=8)
    for label, rc in recon.items():
        keep = rc.t >= rc.t[0] + 2.0
        keep &= rc.t < rc.t[0] + 4.0
        axes[1].plot(rc.t[keep] - rc.t[keep][0], rc.derivative[keep], lw=1.2 if label == "data" else 0.8, label=label)
    axes[1].set_xlabel("t (s)")
    axes[1].set_ylabel(f"delta' rebuilt below {config.cutoff_hz:g} Hz (rad/s)")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def describe(summary):
    for label, v in summary["seventh_harmonic"].items():
        raised = summary["harmonic_tables"][label]["raised"]
        print(f"{label:6s} 7th harmonic {v['frequency_hz']:.3f} Hz, ratio {v['ratio']:.3f}; raised: {raised}; "
              f"9-10 Hz band / fundamental {summary['band_9_10_hz_ratio'][label]:.3f}")


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
