"""Study ``discover``: the whole tvcid pipeline on the bundled recordings, as ``tvcid discover``.

Hypothesis: given only the four bundled recordings (synthetic, M000: limit cycles at controllers A
and B, open-loop square and sine) and no hypothesis, fitting every structure of the model's grammar
by closed- and open-loop simulation and ranking them by leave-one-recording-out error names M000's
structure (dead zone on the velocity signal, delay before the first integrator, backlash, band-pass
loop; the friction offset merges with the dead zone into one threshold ``z - off``), with
``z - off`` within 10 %, the backlash within 30 % and the delay within 0.5 ms of the generating
values; the MCMC calibration of the winner shows the ``z``/``off`` ridge instead of hiding it.

This is the same function as ``tvcid discover`` (:func:`studies.commands.discover.discover`); the
sidecars' ``hypothesis``/``parameters`` keys are ignored by it and used here only to score.

Deciding figures: ``report.md`` (ranking table), ``corner.png`` (posterior of the winner),
``predictive.png``. ``summary.json`` holds the ranking, the posterior and the errors against the
generating values.
"""
from __future__ import annotations

import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from models.recording import load_recording
from models.structures import Structure

from .commands.discover import discover
from .common import study_main

NAME = "discover"
DATA = Path(__file__).resolve().parents[1] / "data"


@dataclass(frozen=True)
class Config:
    recordings: tuple = ("m000_closed_A", "m000_closed_B", "m000_open_square", "m000_open_sine")
    quick: bool = False
    max_steps: int = 2000


QUICK = Config(quick=True, max_steps=100)


def run(config: Config, seed: int, out_dir: Path) -> dict:
    files = [DATA / f"{name}.csv" for name in config.recordings]
    result = discover(files, out_dir, seed=seed, quick=config.quick, max_steps=config.max_steps,
                      progress=False)
    truth = load_recording(files[0]).meta["parameters"]
    from models import params_from_dict

    true_params = params_from_dict("custom", truth)
    true_structure = Structure.of_params(true_params)
    best = result["structures"][0]
    p = best["params"]
    generating = {
        "structure": true_structure.name,
        "threshold": truth["dead_zone"] - truth["friction_offset"],
        "backlash": truth["backlash"],
        "delay": truth["delay"],
    }
    errors = {
        "threshold_relative": (p["dead_zone"] - p["friction_offset"]) / generating["threshold"] - 1.0,
        "backlash_relative": p["backlash"] / generating["backlash"] - 1.0,
        "delay_seconds": p["delay"] - generating["delay"],
    }
    in_set = [s["structure"] for s in result["structures"] if s["indistinguishable_from_best"]]
    summary = {
        "study": NAME, "config": asdict(config), "seed": seed,
        "best": best["structure"], "indistinguishable": in_set,
        "generating": generating, "errors_of_best": errors,
        "names_generating_structure": best["structure"] == true_structure.name,
        "generating_structure_in_set": true_structure.name in in_set,
        "posterior": result.get("posterior"), "timings": result["timings"],
    }
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary


def describe(summary):
    print(f"best: {summary['best']} (generating {summary['generating']['structure']})")
    print("indistinguishable: " + ", ".join(summary["indistinguishable"]))
    e = summary["errors_of_best"]
    print(f"z - off {e['threshold_relative']:+.1%}, backlash {e['backlash_relative']:+.1%}, "
          f"delay {e['delay_seconds'] * 1e3:+.2f} ms")
    print("time: " + ", ".join(f"{k} {v:.0f} s" for k, v in summary["timings"].items()))


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
