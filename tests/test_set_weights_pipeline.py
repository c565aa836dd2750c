"""The set's weights on the pipeline: ``tvcid discover``'s set stage
(:func:`tvcid.set_stage.calibrate_set`) calibrates four members on recordings of a drawn truth and
weighs them by their evidence. The truth (dead zone on the velocity signal, delay at the output,
a backlash; the linear block and thresholds drawn by the shared generator) is recorded by the
plain-Python reference path and read back as measured recordings: a limit cycle and an open-loop
square. The members: its own structure; the same with the band-pass loop at gain 0 (the same
model, one more parameter the recordings cannot see); the same with a friction offset (a nested
superset that fits as well: the offset folds into the threshold ``z - off``); and the same
without the backlash (clearly worse)."""
import json
import math

import numpy as np
import pytest

from tvcid.models.structures import Structure
from tvcid.studies.benchmarks.scenarios import (
    Acquisition,
    RecordingDesign,
    Scenario,
    draw_truth,
    write_recordings,
)

TRUTH = "dz_velocity+delay_output+backlash"
MEMBERS = {"truth": TRUTH, "bandpass at 0": TRUTH + "+bandpass",
           "friction": "dz_velocity+delay_output+friction+backlash",
           "no backlash": "dz_velocity+delay_output"}


@pytest.mark.slow
def test_discover_weighs_its_members_by_their_evidence(tmp_path, out=None):
    """discovery.json holds the evidence weights and their rule: the member without the backlash
    near 0 (under 2 %), and screened; the band-pass member at gain 0 within a factor 3 of the
    truth's own (equal models, the importance noise apart); the friction superset comparable
    (over 5 %). The next test leaves out the screened member, and the summary never calls the
    backlash both present-or-absent and decided."""
    from tvcid.discovery.structure import validate_recordings
    from tvcid.run_record import RunRecord
    from tvcid.set_stage import _write, calibrate_set

    rng = np.random.default_rng(2024)
    truth = draw_truth(rng, Structure.parse(TRUTH), ranges="papers").replace(backlash=4e-4)
    scenario = Scenario(truth, Structure.parse(TRUTH),
                        (RecordingDesign("closed", 12.0, 1000.0, 5.84, 0.062, 12.3),
                         RecordingDesign("open", 8.0, 1000.0, waveform="square",
                                         amplitude=0.01, frequency=0.5)),
                        Acquisition(2e-5, 0.0, 0.0), 2024)
    recs = validate_recordings(write_recordings(scenario, tmp_path / "data", reuse=True))
    # the linear block known (a shorter test); the band-pass loop's gain 0, its saturation free
    fixed = {"gain": truth.gain, "damping": truth.damping, "stiffness": truth.stiffness,
             "feedback_gain": truth.feedback_gain, "bandpass_gain": 0.0}
    rows = []
    for i, name in enumerate(MEMBERS.values()):
        s = Structure.parse(name)
        params = s.to_params(base=truth, bandpass_gain=0.0, bandpass_saturation=0.01)
        if s.friction:
            params = params.replace(friction_offset=-0.3 * truth.dead_zone,
                                    dead_zone=0.7 * truth.dead_zone)
        rows.append({"structure": name, "params": params.to_dict(), "score": 1.0 + 0.01 * i,
                     "cost": 1.0, "criterion": "given", "coordinate_sd": {},
                     "margin": None if i == 0 else 0.2, "margin_se": None if i == 0 else 0.1,
                     "indistinguishable_from_best": True, "merged_into": None,
                     "components": s.to_dict()})
    names = list(MEMBERS.values())
    summary = {"structures": rows, "indistinguishable": names, "timings": {},
               "decided": {"dead_zone_position": "velocity", "delay_position": "output",
                           "friction": None, "backlash": None, "bandpass": None},
               "recordings": [str(r.path) for r in recs], "fixed": fixed,
               "sensor_offset": {r.path.stem: 0.0 for r in recs},
               "sensor_noise": {r.path.stem: 2e-5 for r in recs},
               "estimated": {"sensor_offset": "-", "sensor_noise": "-"}}
    out = tmp_path / "run"
    out.mkdir(exist_ok=True)
    record = calibrate_set(RunRecord.from_dict(summary), recs, fixed, seed=1, quick=False,
                           max_steps=400, progress=False, out=out)
    _write(out, record)
    sp = json.loads((out / "discovery.json").read_text())["set_posterior"]
    w = sp["weighting"]
    assert w["method"] == "evidence" and sp["criterion"] == w["rule"]
    weights = w["weights"]
    assert math.isclose(sum(weights.values()), 1.0)
    assert weights[MEMBERS["no backlash"]] < 0.02, weights
    assert MEMBERS["no backlash"] in sp["screened"]
    ratio = weights[MEMBERS["bandpass at 0"]] / weights[MEMBERS["truth"]]
    assert 1 / 3 < ratio < 3, weights
    assert weights[MEMBERS["friction"]] > 0.05, weights
    screened = next(m for m in sp["members"] if m["structure"] == MEMBERS["no backlash"])
    assert screened["posterior"]["screened"]["steps"] == 300
    assert sp["choices"]["backlash"] == {"value": "on", "by": "weights",
                                         "weights": pytest.approx({"on": 1 - weights[MEMBERS["no backlash"]],
                                                                   "off": weights[MEMBERS["no backlash"]]})}
    report = (out / "report.md").read_text()
    row = next(li for li in report.splitlines() if li.startswith("| backlash |"))
    assert "present or absent" not in row and "Not decided:" in report
    assert "backlash on (" in report.split("Not decided:")[0]
