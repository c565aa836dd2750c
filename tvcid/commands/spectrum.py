"""``tvcid spectrum``: FFT analysis of a recording as papers 001 and 000 did it."""
from __future__ import annotations

from tvcid.discovery.spectral import harmonic_table, lowpass_reconstruction, noise_floor
from tvcid.models.recording import load_recording

from ._common import about_file, positive_seconds, print_json


def register(sub):
    p = sub.add_parser(
        "spectrum",
        help="harmonic table (raised harmonics flagged) and noise floor of a recording",
        description="Harmonics of delta' (paper 001 Fig. 7) with those raised above the smooth decay "
        "of their neighbours flagged, and the noise floor over a band with the band-limited white "
        "noise power that matches it (paper 000 section 4.3).",
    )
    p.add_argument("file", metavar="FILE.csv", help="recording (CSV with a JSON sidecar)")
    p.add_argument("--window", type=positive_seconds, default=None, metavar="S", help="use the last S seconds (default: all)")
    p.add_argument("--n-harmonics", type=int, default=11, help="harmonics in the table")
    p.add_argument("--signal", choices=("derivative", "delta"), default="derivative", help="signal of the harmonic table")
    p.add_argument("--raise-factor", type=float, default=3.0, help="flag harmonics this many times above their neighbours")
    p.add_argument("--band", type=float, nargs=2, default=(20.0, 100.0), metavar=("LOW", "HIGH"), help="noise-floor band, Hz")
    p.add_argument("--noise-band", type=float, default=500.0, help="band of the matched noise, Hz")
    p.add_argument("--cutoff", type=float, default=10.0, help="cut-off of the low-pass reconstruction plot, Hz")
    p.add_argument("--plot", metavar="FILE.png", help="save spectrum, reconstruction and harmonic plots")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    recording = load_recording(args.file)
    source = recording if args.window is None else recording.window(args.window)
    source_args = (source,) if args.window is None else source
    with about_file(args.file):
        table = harmonic_table(*source_args, n_harmonics=args.n_harmonics,
                               derivative=args.signal == "derivative", raise_factor=args.raise_factor)
        floor = noise_floor(*source_args, band_hz=tuple(args.band), noise_band=args.noise_band)
    out = {
        "file": str(args.file),
        "signal": table.signal,
        "fundamental_hz": table.fundamental_hz,
        "n_periods": table.n_periods,
        "raised": list(table.raised_harmonics),
        "harmonics": table.rows(),
        "noise_floor": floor.to_dict(),
    }
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from tvcid.discovery.spectral import amplitude_spectrum

        fig, axes = plt.subplots(2, 2, figsize=(11, 7))
        amplitude_spectrum(*source_args, derivative=True).plot(ax=axes[0, 0], max_hz=50)
        lowpass_reconstruction(*source_args, cutoff_hz=args.cutoff).plot(ax=axes[0, 1], signal="derivative")
        table.plot(ax=axes[1, 0])
        floor.plot(ax=axes[1, 1])
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        plt.close(fig)
    if args.json:
        print_json(out)
        return 0
    print(f"fundamental {table.fundamental_hz:.4g} Hz over {table.n_periods} periods; harmonics of {table.signal}:")
    for row in out["harmonics"]:
        flag = "  raised" if row["raised"] else ""
        print(f"  H{row['harmonic']:<2d} {row['frequency_hz']:7.3f} Hz  {row['amplitude']:.4g}  ratio {row['ratio']:.3f}{flag}")
    print(f"noise floor {args.band[0]:g}-{args.band[1]:g} Hz: PSD {floor.psd:.4g} rad^2/Hz, "
          f"matched power {floor.power:.4g} rad^2/Hz (band {floor.noise_band:g} Hz, std {floor.std:.3g} rad)")
    return 0
