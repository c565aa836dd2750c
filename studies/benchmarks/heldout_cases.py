"""Three held-out cases, rerun as a user ran them: does ``tvcid discover`` name their structure?

``python -m tvcid.studies.benchmarks.heldout_cases [--case NAME ...] [--seed N] [--quick] [--no-mcmc] [--out DIR]``

Hypothesis: on these three recordings sets, each a paper's model recorded with a design a user
ran, the discovery names the generating structure, or reports a set of structures it cannot tell
apart with the truth inside, and fits the coordinates the recordings pin within 5 %. Deciding
numbers: per case, ``truth_in_set``, ``right_winner`` and the relative errors of the truth
structure's fit in ``results/heldout_cases/summary.json``.

The recordings are made by the plain-Python reference path
(:func:`tvcid.studies.benchmarks.scenarios.write_recordings`, a second implementation at 5e-5 s) and
written with measured-style sidecars (no hypothesis, no parameters, commands only as samples);
2e-5 rad of white sensor noise where the design gives none:

* ``m001f_no_bandpass``: paper 001's placement without the band-pass loop (M001f, gain 0): limit
  cycles at A and B (40 s, 1 kHz), an open-loop square +-10 mrad at 0.5 Hz and a sine of 10 mrad at
  1 Hz, 12 s each (the dead-zone position and a damping ``K2`` a fit can drive to 0);
* ``m000_hwil``: paper 000's placement (M000) recorded as the HWIL did: controller held at 200 Hz,
  records at 200 Hz, sensor offset 1.5e-4 rad, quantisation 2e-5 rad, limit cycles at A and B
  (every structural choice and the linear block under the acquisition's distortions);
* ``m002_cycles``: paper 002's placement (M002), limit cycles at A and B only (``K1``-``K3`` and
  the delay from two cycles).

This is a check on three cases, not the measure of the method: the discovery benchmark
(:mod:`tvcid.studies.benchmarks.discovery`) draws truths and designs at random.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from tvcid.models import hypothesis
from tvcid.models.strict_json import write_json
from tvcid.models.structures import Structure

from ..common import code_commit
from tvcid.models.synthetic import Acquisition

from .scenarios import CONTROLLERS, RecordingDesign, Scenario, write_recordings

OUT = Path("results/heldout_cases")
#: Coordinates compared with the truth (the natural parameters; the friction split is shown as the
#: threshold ``dead_zone - friction_offset`` the limit cycle pins, ``docs/models.md#structures``).
COMPARED = ("gain", "damping", "stiffness", "feedback_gain", "dead_zone", "backlash", "delay",
            "friction_offset", "bandpass_gain", "bandpass_saturation")


def _cycles(duration, rate, controller_rate=None):
    return tuple(RecordingDesign("closed", duration, rate, *c, controller_rate=controller_rate)
                 for c in CONTROLLERS)


def cases() -> dict:
    """The three scenarios by name (frozen designs)."""
    m001f = hypothesis("M001f", bandpass_gain=0.0)
    m000 = hypothesis("M000")
    m002 = hypothesis("M002")
    quiet = Acquisition(2e-5, 0.0, 0.0)
    return {
        "m001f_no_bandpass": Scenario(
            m001f, Structure.of_params(m001f),
            _cycles(40.0, 1000.0) + (
                RecordingDesign("open", 12.0, 1000.0, waveform="square", amplitude=0.01,
                                frequency=0.5),
                RecordingDesign("open", 12.0, 1000.0, waveform="sine", amplitude=0.01,
                                frequency=1.0)),
            quiet, 1101),
        "m000_hwil": Scenario(m000, Structure.of_params(m000),
                              _cycles(40.0, 200.0, controller_rate=200.0),
                              Acquisition(2e-5, 1.5e-4, 2e-5), 1102),
        "m002_cycles": Scenario(m002, Structure.of_params(m002), _cycles(40.0, 1000.0), quiet,
                                1103),
    }


def compared(fit_params: dict, truth) -> dict:
    """Relative error of each compared coordinate (absolute for a zero truth), and of the
    threshold the cycle pins when a friction offset is present."""
    truth_d = truth.to_dict()
    out = {}
    for k in COMPARED:
        t, f = float(truth_d[k]), float(fit_params[k])
        if not (math.isfinite(t) and math.isfinite(f)):
            continue
        out[k] = (f - t) / t if t != 0 else f - t
    if truth_d["friction_offset"] != 0:
        t = truth_d["dead_zone"] - truth_d["friction_offset"]
        f = float(fit_params["dead_zone"]) - float(fit_params["friction_offset"])
        out["dead_zone_minus_friction_offset"] = (f - t) / t
    return out


def run_case(name, scenario, out_dir, seed, quick, mcmc):
    from tvcid.pipeline import discover

    paths = write_recordings(scenario, out_dir / name / "recordings", reuse=True)
    t0 = time.perf_counter()
    summary = discover(paths, out_dir / name / "discover", seed=seed, quick=quick, mcmc=mcmc,
                       progress=False).summary
    wall = time.perf_counter() - t0
    truth_s = scenario.structure.name
    structures = summary["structures"]
    in_set = [s for s in structures if s["indistinguishable_from_best"]]
    own = next((s for s in structures if s["structure"] == truth_s), None)
    row = {
        "truth_structure": truth_s,
        "winner": structures[0]["structure"],
        "right_winner": structures[0]["structure"] == truth_s,
        "truth_in_set": any(s["structure"] == truth_s for s in in_set),
        "set": [s["structure"] for s in in_set if s.get("merged_into") is None],
        "decided": summary.get("decided"),
        "truth_structure_rank": None if own is None else structures.index(own),
        "errors_of_truth_structure_fit": None if own is None else compared(own["params"],
                                                                           scenario.truth),
        "errors_of_winner": compared(structures[0]["params"], scenario.truth),
        "coordinate_sd_of_winner": structures[0]["coordinate_sd"],
        "seconds": wall,
    }
    if mcmc:
        truth_d = scenario.truth.to_dict()
        row["posterior_90"] = {
            k: {"q05": v["q05"], "q95": v["q95"], "truth": truth_d.get(k),
                "inside": v["q05"] <= truth_d.get(k, math.nan) <= v["q95"]}
            for k, v in summary["posterior"]["parameters"].items()}
    return row


def main(argv=None) -> int:
    all_cases = cases()
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--case", action="append", choices=tuple(all_cases),
                        help="run this case (repeatable; default all)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="the chain stops at 150 steps")
    parser.add_argument("--no-mcmc", action="store_true", help="ranking only")
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "summary.json"
    summary = json.loads(path.read_text()) if path.exists() else {}
    for name in args.case or list(all_cases):
        row = run_case(name, all_cases[name], out, args.seed, args.quick, not args.no_mcmc)
        row["commit"] = code_commit()
        summary[name] = row
        write_json(path, summary, default=str)
        errs = {k: f"{v:+.1%}" for k, v in (row["errors_of_truth_structure_fit"] or {}).items()
                if k in ("gain", "damping", "stiffness", "delay", "dead_zone", "backlash",
                         "dead_zone_minus_friction_offset")}
        print(f"{name}: truth {row['truth_structure']}\n  winner {row['winner']} "
              f"(right {row['right_winner']}, truth in set {row['truth_in_set']}, set of "
              f"{len(row['set'])}); truth structure's fit: {errs} [{row['seconds']:.0f} s]",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
