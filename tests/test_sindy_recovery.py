"""Issue 4: weak-form SINDy recovers known synthetic actuators made by models/ with a seed.

Tolerances are the issue's: M002 open loop (square and sine, 1 kHz, sensor noise 1e-5 rad rms):
exactly the true terms, coefficients within 2 %, z and r within 3 %, Td within 0.5 ms. M002 limit
cycle: the right structure at the true thresholds, static gain K1/K3 within 2 %. Negative
controls: no friction term (inclusion below 0.2) without friction; no backlash without backlash.
"""
import time

import numpy as np
import pytest

from discovery.sindy import WeakSINDyActuator, rank_by_simulation
from models import CONTROLLER_A, ActuatorParams, OpenLoop, hypothesis, simulate
from models.recording import load_recording, recording_from_trajectory, save_recording

NOISE = 1e-5
DZ_TERM = "DZ_z(u(t-Td)-K*play_r(delta))"
M002_TERMS = {"delta''", "delta'", DZ_TERM}


def _record(directory, name, params, experiment, t_end, seed):
    """Simulate, add seeded Gaussian sensor noise to delta, save and load back a recording."""
    trajectory = simulate(params, experiment, t_end, rate=1000)
    columns, meta = recording_from_trajectory(trajectory, seed=seed, extra={"sensor_noise": NOISE})
    rng = np.random.default_rng(seed)
    columns["delta"] = columns["delta"] + NOISE * rng.standard_normal(trajectory.t.size)
    return load_recording(save_recording(directory / f"{name}.csv", columns, meta))


def _open_loop_pair(directory, params, seed, tag):
    return [
        _record(directory, f"{tag}_square", params, OpenLoop.square(2e-2, 1.0), 8.0, seed),
        _record(directory, f"{tag}_sine", params, OpenLoop.sine(2e-2, 2.0), 8.0, seed + 1),
    ]


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("sindy")


@pytest.fixture(scope="module")
def m002_open_fit(data_dir):
    recordings = _open_loop_pair(data_dir, hypothesis("M002"), 11, "m002")
    start = time.perf_counter()
    est = WeakSINDyActuator(forms=["dead_zone_on_error"], noise=NOISE, seed=0).fit(recordings)
    print(f"M002 open-loop fit: {time.perf_counter() - start:.2f} s, {est.n_rows_} weak equations")
    return est


def test_m002_open_loop_exact_terms_and_coefficients(m002_open_fit):
    truth = hypothesis("M002")
    best = m002_open_fit.candidates_[0]
    assert set(best.terms) == M002_TERMS
    assert best.terms[DZ_TERM] == pytest.approx(truth.gain, rel=0.02)
    assert -best.terms["delta''"] == pytest.approx(truth.damping, rel=0.02)
    assert -best.terms["delta'"] == pytest.approx(truth.stiffness, rel=0.02)
    print("M002 open loop:", best.terms, best.thresholds)


def test_m002_open_loop_thresholds_and_delay(m002_open_fit):
    truth = hypothesis("M002")
    thr = m002_open_fit.candidates_[0].thresholds
    assert thr["dead_zone"] == pytest.approx(truth.dead_zone, rel=0.03)
    assert thr["backlash"] == pytest.approx(truth.backlash, rel=0.03)
    assert abs(thr["delay"] - truth.delay) < 0.5e-3


def test_m002_open_loop_candidate_is_a_model_and_replays_the_data(m002_open_fit):
    best = m002_open_fit.candidates_[0]
    params = best.to_params()
    assert isinstance(params, ActuatorParams)
    assert params.dead_zone_position.value == "error"
    ranked = rank_by_simulation([best], m002_open_fit.recordings_)
    # the open-loop replay of the fitted model follows the data within 2 % rms
    assert ranked[0].score < 0.02


def test_negative_control_no_friction_term(m002_open_fit):
    # M002 has no friction offset: the friction term is not selected
    best = m002_open_fit.candidates_[0]
    assert "L[sign(delta')]" not in best.terms
    assert best.inclusion["L[sign(delta')]"] < 0.2


def test_negative_control_no_backlash(data_dir):
    recordings = _open_loop_pair(data_dir, hypothesis("M002", backlash=0.0), 21, "m002_nob")
    est = WeakSINDyActuator(forms=["dead_zone_on_error"], noise=NOISE, seed=0).fit(recordings)
    best = est.candidates_[0]
    assert best.thresholds["backlash"] == 0.0
    assert best.inclusion["backlash"] < 0.2
    assert set(best.terms) == M002_TERMS
    assert best.thresholds["dead_zone"] == pytest.approx(1.2e-3, rel=0.03)


@pytest.fixture(scope="module")
def m002_cycle(data_dir):
    return _record(data_dir, "m002_cycle", hypothesis("M002"), CONTROLLER_A, 30.0, 31)


def test_m002_limit_cycle_structure_at_true_thresholds(m002_cycle):
    truth = hypothesis("M002")
    fixed = {"dead_zone": truth.dead_zone, "backlash": truth.backlash, "delay": truth.delay}
    est = WeakSINDyActuator(noise=NOISE, thresholds=fixed, seed=0).fit([m002_cycle])
    best = est.candidates_[0]
    assert best.form == "dead_zone_on_error"
    assert set(best.terms) == M002_TERMS
    assert best.static_gain == pytest.approx(truth.gain / truth.stiffness, rel=0.02)
    assert best.inclusion["L[sign(delta')]"] < 0.2
    ranked = rank_by_simulation(est.candidates_, est.recordings_)
    assert ranked[0].form == "dead_zone_on_error"
    assert ranked[0].score_details["recording_0"]["amplitude_error"] < 0.05
    assert ranked[0].score_details["recording_0"]["frequency_error"] < 0.02
    print("M002 limit cycle at true thresholds:", best.terms, "static gain", best.static_gain)


def test_m002_limit_cycle_free_scan_ranks_the_error_form_first(m002_cycle):
    # thresholds and delay scanned, not given; the dead-zone-on-error form wins the ranking
    est = WeakSINDyActuator(forms=["dead_zone_on_error", "dead_zone_on_velocity"], noise=NOISE,
                            n_bootstrap=10, seed=0).fit([m002_cycle])
    ranked = rank_by_simulation(est.candidates_, est.recordings_)
    best = ranked[0]
    assert best.form == "dead_zone_on_error"
    assert set(best.terms) == M002_TERMS
    assert best.static_gain == pytest.approx(37.0, rel=0.02)
    assert best.score < ranked[1].score
    print("M002 limit cycle, free scan:", best.thresholds, "static gain", best.static_gain,
          f"fit {est.fit_time_:.1f} s")


def test_m002_open_loop_at_200_hz(data_dir):
    truth = hypothesis("M002")
    recordings = []
    for seed, command in ((51, OpenLoop.square(2e-2, 1.0)), (52, OpenLoop.sine(2e-2, 2.0))):
        trajectory = simulate(truth, command, 8.0, rate=200)
        columns, meta = recording_from_trajectory(trajectory, seed=seed)
        rng = np.random.default_rng(seed)
        columns["delta"] = columns["delta"] + NOISE * rng.standard_normal(trajectory.t.size)
        path = save_recording(data_dir / f"m002_200hz_{seed}.csv", columns, meta)
        recordings.append(load_recording(path))
    est = WeakSINDyActuator(forms=["dead_zone_on_error"], noise=NOISE, seed=0).fit(recordings)
    best = est.candidates_[0]
    assert set(best.terms) == M002_TERMS
    # no tolerance in the issue at 200 Hz: 5 % on the gain, 10 % and 15 % on z and r
    assert best.terms[DZ_TERM] == pytest.approx(truth.gain, rel=0.05)
    assert best.thresholds["dead_zone"] == pytest.approx(truth.dead_zone, rel=0.10)
    assert best.thresholds["backlash"] == pytest.approx(truth.backlash, rel=0.15)
    assert abs(best.thresholds["delay"] - truth.delay) < 0.5e-3
    print("M002 open loop at 200 Hz:", best.terms, best.thresholds, f"fit {est.fit_time_:.1f} s")
