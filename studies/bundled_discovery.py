"""Study ``discover``: the whole tvcid pipeline on the bundled recordings, as ``tvcid discover``.

Hypothesis: given only the four bundled recordings (synthetic, M000: limit cycles at controllers A
and B, open-loop square and sine) and no hypothesis, fitting every structure of the model's grammar
by closed- and open-loop simulation and ranking them out of sample (two folds: each half of every
recording) names M000's structure (dead zone on the velocity signal, delay before the first
integrator, backlash, band-pass loop) as the winner or inside a reported set of at most three
structures the data cannot tell apart, and M000's structure, fitted, has ``z - off`` within 10 %,
the backlash within 30 % and the delay within 0.5 ms of the generating values. The friction offset
merges with the dead zone into one threshold ``z - off`` (the structure with it is reported merged
into the one without); the MCMC calibration of the winner shows what the data leave open.

The delay before the first integrator (inside the second-order block's own loop) and before the
integrator (after the block) differ only by how the block's effective K1, K2, K3 read; with the
linear block free both fit these four recordings about equally (inside one margin of each other
in ``summary.json``'s ranking), so the reported set holds both.

This is the same function as ``tvcid discover`` (:func:`tvcid.pipeline.discover`); the
sidecars' ``hypothesis``/``parameters`` keys are ignored by it and used here only to score.

Deciding figures: ``report.md`` (ranking table), ``corner.png`` (posterior of the winner),
``predictive.png``. ``summary.json`` holds the ranking, the posterior and the errors of the winner
and of the generating structure's fit against the generating values.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from tvcid.data import path as bundled_path
from tvcid.models.recording import load_recording
from tvcid.models.strict_json import write_json
from tvcid.models.structures import Structure
from tvcid.pipeline import discover

from .common import study_main

NAME = "discover"
#: Started first by ``tvcid study all --jobs N`` (the structure search takes most of the time).
LONG_RUNNING = True
DATA = bundled_path()


@dataclass(frozen=True)
class Config:
    recordings: tuple = ("m000_closed_A", "m000_closed_B", "m000_open_square", "m000_open_sine")
    quick: bool = False
    max_steps: int = 2000


QUICK = Config(quick=True, max_steps=100)
#: The discovery goal's tolerances on the generating structure's fit, and the largest set that still
#: names it.
THRESHOLD_TOL = 0.10
BACKLASH_TOL = 0.30
DELAY_TOL = 0.5e-3
MAX_SET = 3


def errors_against(p, generating):
    """Relative errors of ``z - off`` and the backlash, the delay's error in seconds."""
    return {
        "threshold_relative": (p["dead_zone"] - p["friction_offset"]) / generating["threshold"] - 1.0,
        "backlash_relative": p["backlash"] / generating["backlash"] - 1.0,
        "delay_seconds": p["delay"] - generating["delay"],
    }


def within_tolerances(errors):
    return (abs(errors["threshold_relative"]) <= THRESHOLD_TOL
            and abs(errors["backlash_relative"]) <= BACKLASH_TOL
            and abs(errors["delay_seconds"]) <= DELAY_TOL)


def run(config: Config, seed: int, out_dir: Path) -> dict:
    files = [DATA / f"{name}.csv" for name in config.recordings]
    result = discover(files, out_dir, seed=seed, quick=config.quick, max_steps=config.max_steps,
                      progress=False).summary
    truth = load_recording(files[0]).meta["parameters"]
    from tvcid.models import params_from_dict

    true_params = params_from_dict("custom", truth)
    true_structure = Structure.of_params(true_params)
    best = result["structures"][0]
    generating = {
        "structure": true_structure.name,
        "threshold": truth["dead_zone"] - truth["friction_offset"],
        "backlash": truth["backlash"],
        "delay": truth["delay"],
    }
    own = next(s for s in result["structures"] if s["structure"] == true_structure.name)
    in_set = [s["structure"] for s in result["structures"] if s["indistinguishable_from_best"]]
    distinct = [s["structure"] for s in result["structures"]
                if s["indistinguishable_from_best"] and not s["merged_into"]]
    own_errors = errors_against(own["params"], generating)
    named = best["structure"] == true_structure.name or (true_structure.name in in_set
                                                        and len(distinct) <= MAX_SET)
    summary = {
        "study": NAME, "config": asdict(config), "seed": seed,
        "best": best["structure"], "indistinguishable": in_set, "distinct_in_set": distinct,
        "generating": generating, "errors_of_best": errors_against(best["params"], generating),
        "errors_of_generating_structure": own_errors,
        "names_generating_structure": best["structure"] == true_structure.name,
        "generating_structure_in_set": true_structure.name in in_set,
        "meets_goal": named and within_tolerances(own_errors),
        "posterior": result.get("posterior"), "timings": result["timings"],
    }
    write_json(out_dir / "summary.json", summary, default=str)
    return summary


def describe(summary):
    print(f"best: {summary['best']} (generating {summary['generating']['structure']})")
    print("indistinguishable: " + ", ".join(summary["indistinguishable"]))
    for label, key in (("winner", "errors_of_best"), ("generating structure's fit",
                                                      "errors_of_generating_structure")):
        e = summary[key]
        print(f"{label}: z - off {e['threshold_relative']:+.1%}, backlash "
              f"{e['backlash_relative']:+.1%}, delay {e['delay_seconds'] * 1e3:+.2f} ms")
    print(f"goal (named, in a set of <= {MAX_SET}, within tolerances): "
          f"{'met' if summary['meets_goal'] else 'NOT met'}")
    print("time: " + ", ".join(f"{k} {v:.0f} s" for k, v in summary["timings"].items()))


def main(argv=None):
    return study_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
