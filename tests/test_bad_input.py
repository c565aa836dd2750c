"""Bad input raises an error whose message names the culprit."""
import math

import pytest

from tvcid.models import (
    CONTROLLER_A,
    ClosedLoop,
    OpenLoop,
    SimulationDiverged,
    UnknownHypothesisError,
    hypothesis,
    simulate,
)


@pytest.mark.parametrize("field", ["dead_zone", "backlash", "delay", "noise_power"])
def test_negative_width_is_named(field):
    with pytest.raises(ValueError, match=f"{field} must be >= 0"):
        hypothesis("M002", **{field: -1e-3})


def test_nan_parameter_is_named():
    with pytest.raises(ValueError, match="backlash is NaN"):
        hypothesis("M001f", backlash=math.nan)
    with pytest.raises(ValueError, match="kp must be finite"):
        ClosedLoop(kp=math.nan, kd=0.06, mu=4.5)


@pytest.mark.parametrize("dt", [0.0, -1e-4, math.nan])
def test_nonpositive_dt(dt):
    with pytest.raises(ValueError, match="dt must be a finite number > 0"):
        simulate(hypothesis("M002"), CONTROLLER_A, 1.0, dt=dt)


def test_unknown_hypothesis_lists_the_known_ones():
    with pytest.raises(UnknownHypothesisError, match="'M003'.*M002, M001i, M001f, M000"):
        hypothesis("M003")
    assert hypothesis("m001F").name == "M001f"  # case-insensitive


def test_unknown_parameter_and_enum_value_are_named():
    with pytest.raises(ValueError, match="unknown parameter.*dead_zonee"):
        hypothesis("M002", dead_zonee=1e-3)
    with pytest.raises(ValueError, match="delay_position must be one of"):
        hypothesis("M002", delay_position="somewhere")


def test_delay_shorter_than_step_and_rate_not_dividing():
    with pytest.raises(ValueError, match="delay .* shorter than the step"):
        simulate(hypothesis("M001f", delay=5e-5), CONTROLLER_A, 1.0, dt=1e-4)
    # a step given explicitly is checked against the rates; without one, a step is chosen that
    # they divide (tests/test_recording.py)
    with pytest.raises(ValueError, match="output rate 300"):
        simulate(hypothesis("M002"), CONTROLLER_A, 1.0, dt=2e-4, rate=300.0)
    with pytest.raises(ValueError, match="sample_rate 300"):
        simulate(hypothesis("M002"), ClosedLoop(5.84, 0.062, 12.3, sample_rate=300.0), 1.0,
                 dt=2e-4)


def test_unknown_waveform_and_bad_experiment():
    with pytest.raises(ValueError, match="waveform 'triangle'"):
        OpenLoop("triangle", amplitude=1.0)
    with pytest.raises(TypeError, match="ClosedLoop or an OpenLoop"):
        simulate(hypothesis("M002"), "closed", 1.0)


def test_divergence_is_reported_not_returned():
    with pytest.raises(SimulationDiverged, match="M002 diverged.*t ="):
        simulate(hypothesis("M002"), ClosedLoop(kp=400.0, kd=0.062, mu=12.3), 5.0)
