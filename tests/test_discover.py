"""tvcid discover / discovery.structure: bad input, and recovery on a drawn scenario."""
import json

import numpy as np
import pytest

from discovery.structure import StructureDiscovery
from models.recording import save_recording
from studies.bench_discovery import coordinate_errors
from studies.cli import main
from studies.scenarios import draw_scenario, shortened, write_recordings

DATA = "data/m000_closed_A.csv"


def _write(path, delta, kind="closed", **meta):
    t = np.arange(delta.size) / 1000.0
    side = {"kind": kind, **({"kp": 5.84, "kd": 0.062, "mu": 12.3} if kind == "closed" else {}), **meta}
    save_recording(path, {"t": t, "u": np.zeros_like(t), "delta": delta}, side)
    return str(path)


@pytest.mark.parametrize("case, expected", [
    ("none", "the following arguments are required"),
    ("degrees", "degrees"),
    ("units", "expects rad"),
    ("no_cycle", "no limit cycle"),
    ("unknown_fix", "unknown parameter(s) dead_band"),
])
def test_bad_input_is_one_line_error(tmp_path, capsys, case, expected):
    t = np.arange(8000) / 1000.0
    args = ["discover", "--no-mcmc", "--no-progress", "--quick", "--out", str(tmp_path / "out")]
    if case == "degrees":
        args.insert(1, _write(tmp_path / "deg.csv", 0.3 * np.sin(8.6 * t) * 57.3))
    elif case == "units":
        args.insert(1, _write(tmp_path / "mixed.csv", 5e-3 * np.sin(8.6 * t),
                              units={"t": "s", "u": "rad", "delta": "deg"}))
    elif case == "no_cycle":
        args.insert(1, _write(tmp_path / "flat.csv", 1e-3 * np.exp(-t)))
    elif case == "unknown_fix":
        args[1:1] = [DATA, "--fix", "dead_band=1e-3"]
    if case == "none":
        with pytest.raises(SystemExit) as exc:
            main(args)
        assert exc.value.code == 2
    else:
        assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err
    assert "Traceback" not in err and (case == "none" or len(err.splitlines()) == 1)


def test_sidecar_hypothesis_and_parameters_are_ignored(tmp_path):
    """A sidecar's truth keys must not leak into discovery: the same data with and without them
    give the same targets."""
    from discovery.structure.targets import make_target
    from models.recording import load_recording

    rec = load_recording(DATA)
    assert "parameters" in rec.meta
    stripped = tmp_path / "a.csv"
    meta = {k: rec.meta[k] for k in ("kind", "kp", "kd", "mu")}
    save_recording(stripped, {k: rec.columns[k] for k in ("t", "u", "delta")}, meta)
    a, b = make_target(rec, 5e-4), make_target(load_recording(stripped), 5e-4)
    assert a.omega == b.omega and np.allclose(a.harmonics, b.harmonics)


def test_recovers_a_drawn_truth_with_known_positions(tmp_path):
    """A truth drawn by the benchmark's generator (seed 3, paper-002 placement: dead zone on the
    error, delay at the output, backlash), data from the reference path with measured-style
    sidecars; the positions and the absence of the loop are known (--fix), so two structures
    remain (backlash on/off). The generating one must be in the reported set, and every coordinate
    the design identifies (the benchmark's rule, studies.bench_discovery) within 5 %."""
    from models.structures import Structure

    s = Structure("error", "output", friction=False, backlash=True, bandpass=False)
    scenario = shortened(draw_scenario(3, structure=s), closed=12.0, open_=6.0)
    paths = write_recordings(scenario, tmp_path)
    for p in paths:
        side = json.loads(p.with_suffix(".json").read_text())
        assert "parameters" not in side and "hypothesis" not in side and "waveform" not in side
    fixed = {"dead_zone_position": "error", "delay_position": "output", "bandpass_gain": 0.0}
    disc = StructureDiscovery(fixed=fixed, seed=0, quick=True, use_sindy=False).fit(paths)
    assert {f.structure for f in disc.ranking_} == {s, s.without("backlash")}
    fit = next(f for f in disc.ranking_ if f.structure == s)
    assert fit.indistinguishable_from_best
    # what this design pins (local spread at the truth under 2 %) must come back within 5 %;
    # two limit cycles alone do not pin the linear block (MODELS.md), so it is not asserted
    errors = coordinate_errors(disc, scenario.truth, s)
    identified = {k: v["error"] for k, v in errors.items() if v["identifiable"]}
    assert identified, errors
    assert all(e <= 0.05 for e in identified.values()), errors
