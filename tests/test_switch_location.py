"""The friction offset's jump located inside the RK4 step: no limit cycle locked to the step grid."""
import numpy as np
import pytest

from tvcid.models import simulate
from tvcid.models.cycle_reading import limit_cycle_features
from tvcid.models.kernel import _sign_switch_average
from tvcid.models.nonlinearities import sign_switch_average


def _brute_force_mean(q0, q1, z, n=200_001):
    q = np.linspace(q0, q1, n)
    dz = np.where(np.abs(q) <= z, 0.0, q)
    return float(np.mean(np.sign(dz)))


def test_sign_switch_average_is_the_mean_sign_along_the_step():
    rng = np.random.default_rng(11)
    for _ in range(200):
        q0, q1 = rng.normal(0.0, 1.0, 2)
        z = rng.choice([0.0, abs(rng.normal(0.0, 0.5))])
        expected = _brute_force_mean(q0, q1, z)
        assert sign_switch_average(q0, q1, z) == pytest.approx(expected, abs=2e-5)
        assert _sign_switch_average(q0, q1, z) == sign_switch_average(q0, q1, z)  # kernel twin
    assert sign_switch_average(0.3, 0.3, 0.0) == 1.0 and sign_switch_average(0.1, -0.1, 0.2) == 0.0


@pytest.fixture(scope="module")
def locked_cycle():
    """Coverage draw 2, second limit cycle: friction offset at a velocity dead zone; with the jump
    at a step boundary instead of located, its frequency would be identical at 5e-4 and 2.5e-4 s
    and flat in the offset."""
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    scenario = coverage_scenario(2, Config())
    design = [d for d in scenario.recordings if d.kind == "closed"][1]
    assert scenario.truth.friction_offset != 0 and scenario.truth.dead_zone_position.value == "velocity"
    return scenario.truth, design.experiment()


def _frequency(params, experiment, dt):
    tr = simulate(params, experiment, 30.0, dt=dt)
    keep = tr.t > 15.0
    return limit_cycle_features(tr.t[keep], tr.delta[keep]).frequency


def test_cycle_frequency_is_smooth_in_the_friction_offset(locked_cycle):
    truth, experiment = locked_cycle
    f = np.array([_frequency(truth.replace(friction_offset=truth.friction_offset * (1 + 2e-4 * k)),
                             experiment, 5e-4) for k in range(5)])
    steps = np.diff(f)
    # locked, the frequency sat still (changes ~1e-11) and then jumped by ~1e-6
    assert np.all(steps < 0) and np.all(np.abs(steps) > 1e-6)
    assert np.max(np.abs(np.diff(steps))) < 0.2 * np.min(np.abs(steps))


def test_cycle_frequency_converges_with_the_step(locked_cycle):
    truth, experiment = locked_cycle
    f = np.array([_frequency(truth, experiment, 5e-4 / 2**j) for j in range(3)])
    first, second = abs(f[1] - f[0]), abs(f[2] - f[1])
    assert first > 0 and second < 0.7 * first  # locked: first == 0 exactly
