"""The recording format and its one loader."""
import json

import numpy as np
import pytest

from tvcid.models import CONTROLLER_B, M002, ActuatorParams, OpenLoop, hypothesis, params_from_dict, simulate
from tvcid.models.recording import (
    RecordingError,
    load_recording,
    recording_from_trajectory,
    save_recording,
)


def _write(tmp_path, text, meta={"kind": "open"}):
    path = tmp_path / "rec.csv"
    path.write_text(text)
    if meta is not None:
        path.with_suffix(".json").write_text(json.dumps(meta))
    return path


def test_round_trip_keeps_samples_and_provenance(tmp_path):
    tr = simulate(hypothesis("M002", noise_power=1e-11, noise_seed=7), CONTROLLER_B, 3.0)
    path = save_recording(tmp_path / "m002.csv", *recording_from_trajectory(tr))
    rec = load_recording(path)
    np.testing.assert_array_equal(rec.delta, tr.delta)
    np.testing.assert_array_equal(rec.columns["theta"], tr.theta)
    assert rec.kind == "closed" and rec.meta["kp"] == 9.8 and rec.meta["mu"] == 4.5
    assert rec.meta["hypothesis"] == "M002" and rec.meta["seed"] == 7
    assert rec.meta["parameters"]["dead_zone"] == 1.2e-3
    assert rec.sample_rate == pytest.approx(1000.0)
    assert rec.experiment().kp == 9.8
    assert params_from_dict(rec.meta["hypothesis"], rec.meta["parameters"]) == tr.params
    custom = ActuatorParams(**rec.meta["parameters"])
    assert params_from_dict("custom", rec.meta["parameters"]) == custom


def test_minimal_hand_written_sidecar(tmp_path):
    path = _write(tmp_path, "t,u,delta\n0,0,0\n0.005,0.1,0.01\n0.01,0.1,0.02\n")
    rec = load_recording(path)
    assert rec.sample_rate == pytest.approx(200.0)
    assert rec.meta["units"]["delta"] == "rad"


@pytest.mark.parametrize(
    "text, meta, message",
    [
        ("t,u\n0,0\n1,1\n", {"kind": "open"}, "missing column 'delta'"),
        ("t,u,delta\n0,0,0\n1,1,nan\n", {"kind": "open"}, "column 'delta' holds NaN"),
        ("t,u,delta\n0,0,0\n0,1,1\n", {"kind": "open"}, "not strictly increasing"),
        # a 0.5 s gap in a 1 kHz record, and a record whose rate halves midway
        ("t,u,delta\n0,0,0\n0.001,0,0\n0.002,0,0\n0.502,0,0\n0.503,0,0\n", {"kind": "open"},
         "not uniformly sampled: step 0.5 s between data rows 3 and 4"),
        ("t,u,delta\n0,0,0\n0.001,0,0\n0.002,0,0\n0.004,0,0\n0.006,0,0\n", {"kind": "open"},
         "not uniformly sampled"),
        ("t,u,delta\n0,0,0\n1,1\n", {"kind": "open"}, "data row 2 has 2 fields"),
        ("t,u,delta\n0,0,0\n1,x,1\n", {"kind": "open"}, "column 'u': not a number"),
        ("t,u,delta\n", {"kind": "open"}, "empty"),
        ("t,u,delta\n0,0,0\n1,1,1\n", {"kind": "hwil"}, "'kind' must be one of closed, open"),
        ("t,u,delta\n0,0,0\n1,1,1\n", {"kind": "closed", "kp": 1}, "needs a finite number 'kd'"),
        ("t,u,delta\n0,0,0\n1,1,1\n", None, "missing sidecar"),
    ],
)
def test_malformed_recordings_name_the_culprit(tmp_path, text, meta, message):
    path = _write(tmp_path, text, meta)
    with pytest.raises(RecordingError, match=message):
        load_recording(path)


def test_open_loop_sidecar_rebuilds_the_analytic_command(tmp_path):
    from tvcid.models import OpenLoop

    tr = simulate(hypothesis("M002"), OpenLoop.square(5e-3, 1.0), 2.0)
    rec = load_recording(save_recording(tmp_path / "sq.csv", *recording_from_trajectory(tr)))
    replay = simulate(hypothesis("M002"), rec.experiment(), 2.0)
    np.testing.assert_array_equal(replay.delta, tr.delta)  # edges exactly where they were
    hand = _write(tmp_path, "t,u,delta\n0,0,0\n1,0.01,0\n2,0.01,0\n")
    assert load_recording(hand).experiment().waveform == "samples"


def test_compensator_and_bending_round_trip_through_the_sidecar(tmp_path):
    from tvcid.models import ClosedLoop
    from tvcid.models.controllers import BendingMode, TransferFunction

    comp = TransferFunction.series(TransferFunction.lead(4.0, 8.0), TransferFunction.notch(60.0, 0.5, 0.1))
    exp = ClosedLoop(5.84, 0.062, 12.3, sample_rate=200.0, compensator=comp,
                     bending=BendingMode(60.0, 0.02, 0.002))
    tr = simulate(hypothesis("M002"), exp, 3.0)
    path = save_recording(tmp_path / "comp.csv", *recording_from_trajectory(tr))
    rec = load_recording(path)
    assert rec.meta["compensator"]["name"] == "lead*notch"
    assert rec.experiment() == exp
    np.testing.assert_array_equal(simulate(hypothesis("M002"), rec.experiment(), 3.0).delta, tr.delta)
    # the hand-written forms of TransferFunction.from_dict
    short = {"kind": "closed", "kp": 5.84, "kd": 0.062, "mu": 12.3,
             "compensator": [{"lead": [4.0, 8.0]}, {"notch": [60.0, 0.5, 0.1]}]}
    hand = _write(tmp_path, "t,u,delta\n0,0,0\n0.001,0,0\n0.002,0,0\n", short)
    assert load_recording(hand).experiment().compensator.num == comp.num


@pytest.mark.parametrize(
    "extra, message",
    [
        ({"compensator": {"num": [1, 0, 0], "den": [1, 1]}},
         r"rec\.json: sidecar 'compensator': controller transfer function is improper"),
        ({"compensator": {"lead": [4.0]}}, r"sidecar 'compensator': .*lead"),
        ({"compensator": {"zeros": [1]}}, r"sidecar 'compensator': .*expected keys num and den"),
        ({"bending": {"frequency": -60, "damping": 0.02, "gain": 0.001}},
         r"rec\.json: sidecar 'bending': bending frequency must be > 0 \(got -60\)"),
        ({"bending": [60, 0.02, 0.001]}, r"sidecar 'bending': bending must be an object"),
        ({"compensater": {"lead": [4, 8]}}, r"unknown sidecar key 'compensater' \(did you mean 'compensator'\?\)"),
    ],
)
def test_bad_compensator_or_bending_in_the_sidecar_is_one_line_naming_the_key(tmp_path, extra, message):
    meta = {"kind": "closed", "kp": 5.84, "kd": 0.062, "mu": 12.3, **extra}
    path = _write(tmp_path, "t,u,delta\n0,0,0\n0.001,0,0\n0.002,0,0\n", meta)
    with pytest.raises(RecordingError, match=message) as info:
        load_recording(path)
    assert len(str(info.value).splitlines()) == 1
    with pytest.raises(RecordingError, match=message.replace(r"rec\.json", r"again\.json")):
        save_recording(tmp_path / "again.csv",
                       {"t": np.arange(3) * 1e-3, "u": np.zeros(3), "delta": np.zeros(3)},
                       {**meta})


#: 2 kHz as read off a record's timestamps, and rates drawn over 200 Hz-2 kHz.
DRAWN_RATES = (2000.0000000046612, *np.round(np.random.default_rng(64).uniform(200.0, 2000.0, 3), 3))


@pytest.mark.parametrize("rate", DRAWN_RATES)
def test_a_synthetic_record_at_any_rate_is_simulated_at_a_step_that_rate_divides(tmp_path, rate):
    """Acquisition rates the default 2e-4 s step does not divide (2 kHz read off timestamps,
    rates drawn over 200 Hz-2 kHz) are recorded at the longest step under it that they divide;
    rates that divide it keep it."""
    from tvcid.models.simulate import DEFAULT_DT, step_for_rate
    from tvcid.models.synthetic import synthetic_recording

    dt = step_for_rate(rate)
    assert dt <= DEFAULT_DT and step_for_rate(rate, dt) == dt
    k = round(1.0 / (rate * dt))  # steps per sample: whole, and one fewer would exceed 2e-4 s
    assert abs(1.0 / (rate * dt) - k) < 1e-6 and (k == 1 or 1.0 / (rate * (k - 1)) > DEFAULT_DT)
    assert step_for_rate(1000.0) == step_for_rate(200.0) == DEFAULT_DT
    rec = synthetic_recording(M002(), OpenLoop.sine(5e-3, 2.0), 2.0, 1e-5, 0, tmp_path / "r.csv",
                              rate=rate)
    assert rec.sample_rate == pytest.approx(rate, rel=1e-6)
    assert rec.t[-1] == pytest.approx(2.0, abs=1.5 / rate)


@pytest.mark.parametrize("rate", [2000.0000000046612, 300.0, 1500.0])
def test_a_record_of_a_held_controller_is_simulated_at_a_step_both_rates_divide(tmp_path, rate):
    """A controller held at 200 Hz and an acquisition rate the default step does not divide: the
    step is one both rates divide; two rates that share none within reach are one line."""
    from tvcid.models import ClosedLoop
    from tvcid.models.simulate import step_for_rate
    from tvcid.models.synthetic import synthetic_recording

    held = ClosedLoop(CONTROLLER_B.kp, CONTROLLER_B.kd, CONTROLLER_B.mu, sample_rate=200.0)
    rec = synthetic_recording(M002(), held, 3.0, 1e-5, 0, tmp_path / "r.csv", rate=rate)
    assert rec.sample_rate == pytest.approx(rate, rel=1e-6)
    hold = 1.0 / (200.0 * step_for_rate(rate, controller_rate=200.0))
    assert abs(hold - round(hold)) < 1e-6
    with pytest.raises(ValueError, match=r"^the output rate 318.28 Hz and the controller's 200.0 Hz "
                                         r"share no simulation step between [^\n]*$"):
        step_for_rate(318.28, controller_rate=200.0)
