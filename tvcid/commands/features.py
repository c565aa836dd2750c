"""``tvcid features``: limit-cycle features of a recording."""
from __future__ import annotations

from tvcid.models.recording import load_recording

from ._common import about_file, positive_seconds, print_json


def register(sub):
    p = sub.add_parser(
        "features",
        help="limit-cycle features (amplitude, frequency, harmonics) of a recording",
        description="Amplitude (max-min)/2, mean, frequency from mean crossings, period jitter, "
        "harmonics of delta and delta' up to the 11th, and amplitude drift of a recording.",
    )
    p.add_argument("file", metavar="FILE.csv", help="recording (CSV with a JSON sidecar)")
    p.add_argument("--window", type=positive_seconds, default=None, metavar="S", help="use the last S seconds (default: all)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    recording = load_recording(args.file)
    with about_file(args.file):
        feats = recording.features(window=args.window)
    if args.json:
        print_json(feats.to_dict())
    else:
        print(f"amplitude  {feats.amplitude:.6g} rad")
        print(f"frequency  {feats.frequency:.6g} rad/s ({feats.frequency_hz:.6g} Hz)")
        print(f"mean       {feats.mean:.6g} rad")
        print(f"jitter     {feats.period_jitter:.3g}")
        print(f"drift      {feats.amplitude_drift:.3g}")
        for k, (h, hd) in enumerate(zip(feats.harmonics, feats.derivative_harmonics), start=1):
            print(f"H{k:<2d} delta {h:.4g} rad   delta' {hd:.4g} rad/s   ratio {hd / feats.derivative_harmonics[0]:.3f}")
    return 0
