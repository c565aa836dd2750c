"""Weak-form SINDy on drawn actuators of paper 001's final placement (M001f: dead zone on the
velocity signal, delay before the integrator, friction offset, backlash, band-pass loop), from
open-loop tests.

Truths and sensors come from the shared generator (:func:`tvcid.studies.benchmarks.scenarios.draw_scenario` with
M001f's structure); the records are made by the numba kernel at the generator's 5e-5 s step in
place of the plain-Python reference path and written as measured-style recordings. The tests are
the specified ones: square 2e-2 rad at 1 Hz, sine 2e-2 rad at 2 Hz (they pin the block, K, r and the
delay) and a slow sine 3e-3 rad at 0.5 Hz whose speed stays near paper 001's dead zone (it splits z
from the friction offset, which the moving test functions only see as z - off), 8 s each at 1 kHz.
The draws are the offset-free ones of seeds 0-39 (the forms have no sensor offset).

Tolerances are the specified ones: exactly the true terms, coefficients within 10 %, K within 1 %, z within
8 %, friction offset within 10 %, r within 25 %, the delay within 1 ms. Paper 001's own truth meets
them at 1e-5 rad of noise (largest error 5.5 %, the friction offset). Over the drawn truths the
method does not: measured per draw (relative errors),

* draws 0, 9, 12, 33 (noise 7.2e-5, 5.1e-5, 3.5e-5, 6.4e-5): the dead-zone-on-error form ranks
  first (gain -49 % to -68 % in its own terms);
* draw 6 (noise 1.1e-5): the right terms, gain -15 %, friction offset +50 %, band-pass gain -17 %;
* draw 16 (4.6e-5): the right terms, damping -88 %, delay +16 ms;
* draw 29 (1.1e-5): the right terms, gain +155 %, delay +3.9 ms;
* draw 35 (3.8e-5): the right terms, band-pass gain +203 %, dead zone -69 %;
* draws 8 and 39 (1.8e-5, 1.6e-5): within the tolerances (largest 1.5 % and 8.0 %).

No property of the draw (noise, thresholds) separates the two that pass from the rest, so the
tests are expected to fail (slow: about 2 CPU-min).
"""
from dataclasses import replace
from unittest import mock

import pytest

from tvcid.discovery.sindy import discover_structure
from tvcid.models import M001f, simulate
from tvcid.models.recording import load_recording
from tvcid.models.structures import Structure
from tvcid.studies.benchmarks import scenarios
from tvcid.studies.benchmarks.scenarios import RecordingDesign, draw_scenario

M001F_TERMS = {
    "delta''", "delta'", "u(t-Td)", "play_r(delta)(t-Td)", "L[sign(delta')]",
    "L[sat_1(G/s*BP(delta'))]",
}
PLACEMENT = Structure.of_params(M001f())
#: The offset-free draws of seeds 0-39.
SEEDS = (0, 6, 8, 9, 12, 16, 29, 33, 35, 39)
TESTS = (RecordingDesign("open", 8.0, 1000.0, waveform="square", amplitude=2e-2, frequency=1.0),
         RecordingDesign("open", 8.0, 1000.0, waveform="sine", amplitude=2e-2, frequency=2.0),
         RecordingDesign("open", 8.0, 1000.0, waveform="sine", amplitude=3e-3, frequency=0.5))
REASON = ("weak SINDy misses M001f's structure or its coefficients on 8 of the 10 offset-free "
          "draws of seeds 0-39 (module docstring); no property of the draw marks the two it gets")


def _ranked(seed, directory):
    scenario = draw_scenario(seed, structure=PLACEMENT)
    assert scenario.acquisition.offset == 0.0, "outside the domain: a sensor offset"
    scenario = replace(scenario, recordings=TESTS)
    with mock.patch.object(scenarios, "simulate_reference", simulate):
        recordings = [load_recording(p) for p in scenarios.write_recordings(scenario, directory)]
    est = discover_structure(
        recordings, noise=scenario.acquisition.noise_sd,
        forms=("dead_zone_on_error", "dead_zone_on_velocity_bandpass"), n_bootstrap=10,
    )
    return scenario.truth, est


@pytest.fixture(scope="module")
def drawn_ranked(tmp_path_factory):
    """``{seed: (truth, fitted and ranked estimator)}`` over :data:`SEEDS`."""
    return {seed: _ranked(seed, tmp_path_factory.mktemp(f"m001f_{seed}")) for seed in SEEDS}


def _relative(value, truth):
    return abs(value / truth - 1.0)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError, reason=REASON)
def test_m001f_structure_ranked_first_with_exactly_the_true_terms(drawn_ranked):
    for seed, (_, est) in drawn_ranked.items():
        best = est.candidates_[0]
        assert best.form == "dead_zone_on_velocity_bandpass", (seed, best.form)
        assert set(best.terms) == M001F_TERMS, (seed, best.terms)
        assert all(best.inclusion[name] >= 0.8 for name in M001F_TERMS), (seed, best.inclusion)
        assert est.candidates_[1].score > 3 * best.score, seed


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError, reason=REASON)
def test_m001f_coefficients(drawn_ranked):
    for seed, (truth, est) in drawn_ranked.items():
        p = est.candidates_[0].params
        for name, tol in (("gain", 0.10), ("damping", 0.10), ("stiffness", 0.10),
                          ("feedback_gain", 0.01), ("bandpass_saturation", 0.10)):
            assert name in p and _relative(p[name], getattr(truth, name)) < tol, (seed, name, p)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError, reason=REASON)
def test_m001f_thresholds(drawn_ranked):
    for seed, (truth, est) in drawn_ranked.items():
        p = est.candidates_[0].params
        for name, tol in (("dead_zone", 0.08), ("friction_offset", 0.10), ("backlash", 0.25)):
            assert name in p and _relative(p[name], getattr(truth, name)) < tol, (seed, name, p)
        assert abs(p["delay"] - truth.delay) < 1e-3, (seed, p["delay"], truth.delay)
        params = est.candidates_[0].to_params()
        assert params.dead_zone_position.value == "velocity", seed
        assert params.delay_position.value == "before_integrator", seed
        assert params.has_bandpass_loop, seed
