"""Rebuild the bundled recordings byte for byte: ``python data/generate.py [--out DIR] [--check]``.

The papers' HWIL recordings are not public, so the reference set is SYNTHETIC: paper 000's final
model (M000, Table 1 with gain A corrected to 1511.6) with its output-noise model (band-limited white
noise added to the actuator output inside the loop), at the two controller settings of paper 002 and
in two open-loop bench tests (square and sine, as paper 001 section 5.2 and paper 000 Figs. 14-15).
Every sidecar says ``"source": "simulated"`` and records the hypothesis, every parameter and the
seed. ``SHA256SUMS`` beside this file holds the checksums ``--check`` compares against.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

from tvcid.models import CONTROLLER_A, CONTROLLER_B, OpenLoop, hypothesis, simulate
from tvcid.models.recording import recording_from_trajectory, save_recording

HERE = Path(__file__).resolve().parent

#: Output noise of the synthetic set: PSD 4e-13 rad^2/Hz held at 1 kHz (band 500 Hz), i.e. a
#: 2e-5 rad rms floor, 0.4 % of the cycle amplitude. The papers print no noise power.
NOISE = dict(noise_power=4e-13, noise_band=500.0)


@dataclass(frozen=True)
class RecordingSpec:
    name: str
    experiment: object
    t_end: float
    seed: int
    columns: tuple
    description: str


SPECS = (
    RecordingSpec("m000_closed_A", CONTROLLER_A, 30.0, 1, ("t", "u", "delta", "theta"),
                  "HWIL-like limit cycle, controller A (Kp 5.84, Kd 0.062, mu 12.3)"),
    RecordingSpec("m000_closed_B", CONTROLLER_B, 30.0, 2, ("t", "u", "delta", "theta"),
                  "HWIL-like limit cycle, controller B (Kp 9.8, Kd 0.06, mu 4.5)"),
    RecordingSpec("m000_open_square", OpenLoop.square(2e-2, 1.0), 8.0, 3, ("t", "u", "delta"),
                  "open-loop square wave, +-20 mrad at 1 Hz, actuator starting at rest"),
    RecordingSpec("m000_open_sine", OpenLoop.sine(2e-2, 2.0), 8.0, 4, ("t", "u", "delta"),
                  "open-loop sine, 20 mrad at 2 Hz, actuator starting at rest"),
)
RATE = 1000.0


def build(out_dir: Path) -> list:
    """Simulate and write every recording; return the written paths (CSV and sidecar)."""
    written = []
    for spec in SPECS:
        params = hypothesis("M000", noise_seed=spec.seed, **NOISE)
        tr = simulate(params, spec.experiment, spec.t_end, rate=RATE)
        columns, meta = recording_from_trajectory(
            tr, extra={"description": spec.description, "generator": "data/generate.py"}
        )
        columns = {k: columns[k] for k in spec.columns}
        meta["units"] = {k: meta["units"][k] for k in spec.columns}
        path = save_recording(out_dir / f"{spec.name}.csv", columns, meta)
        written += [path, path.with_suffix(".json")]
    return written


def checksums(paths) -> dict:
    return {Path(p).name: hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in paths}


def read_sums(path: Path) -> dict:
    sums = {}
    for line in path.read_text().splitlines():
        digest, name = line.split()
        sums[name] = digest
    return sums


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=HERE, help="output directory (default: data/)")
    parser.add_argument("--check", action="store_true", help="compare with data/SHA256SUMS")
    parser.add_argument("--write-sums", action="store_true", help="(re)write data/SHA256SUMS")
    args = parser.parse_args(argv)
    sums = checksums(build(args.out))
    if args.write_sums:
        (HERE / "SHA256SUMS").write_text("".join(f"{d}  {n}\n" for n, d in sorted(sums.items())))
    if args.check:
        expected = read_sums(HERE / "SHA256SUMS")
        bad = sorted(n for n in expected if sums.get(n) != expected[n])
        if bad:
            print(f"MISMATCH: {', '.join(bad)}", file=sys.stderr)
            return 1
        print(f"all {len(expected)} files match data/SHA256SUMS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
