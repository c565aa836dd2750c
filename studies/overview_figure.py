"""The README's figure: what tvcid works from. ``python -m tvcid.studies.overview_figure [--out PNG]``.

Left, the limit cycle the HWIL loop shows at controller A (the bundled M000 recording, its last
3 s); right, an open-loop square test of the same actuator, where the dead zone, backlash and delay
show in the response's lag and corners. Written to ``docs/figures/overview.png``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tvcid.data import path as bundled_path
from tvcid.figures import pyplot
from tvcid.models.recording import load_recording

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "figures" / "overview.png"


def draw(path=OUT) -> Path:
    """Draw the figure from the bundled recordings into ``path``."""
    plt = pyplot()
    cycle = load_recording(bundled_path("m000_closed_A.csv"))
    square = load_recording(bundled_path("m000_open_square.csv"))
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 2.8))
    keep = cycle.t >= cycle.t[-1] - 3.0
    left.plot(cycle.t[keep], 1e3 * cycle.delta[keep], lw=0.8)
    left.set(xlabel="t (s)", ylabel="nozzle angle delta (mrad)",
             title="limit cycle in closed loop (controller A)")
    keep = square.t <= 4.0
    right.plot(square.t[keep], 1e3 * square.u[keep], lw=0.8, color="0.6", label="command u")
    right.plot(square.t[keep], 1e3 * square.delta[keep], lw=0.8, label="response delta")
    right.set(xlabel="t (s)", ylabel="mrad", title="open-loop square test")
    right.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default=str(OUT), help="PNG to write")
    args = parser.parse_args(argv)
    print(f"wrote {draw(args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
