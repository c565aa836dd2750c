"""The numba kernel against the independent plain-Python reference path."""
import numpy as np
import pytest

from models import (
    CONTROLLER_A,
    ClosedLoop,
    OpenLoop,
    hypothesis,
    simulate,
    simulate_batch,
)
from models.delay import DelayLine, transport_delay
from models.reference import simulate_reference


@pytest.mark.parametrize("name", ["M002", "M001i", "M001f", "M000"])
def test_kernel_matches_reference_closed_loop(name):
    params = hypothesis(name)
    fast = simulate(params, CONTROLLER_A, 10.0)
    slow = simulate_reference(params, CONTROLLER_A, 10.0, rate=1000.0)
    assert np.max(np.abs(fast.delta - slow.delta)) < 1e-5
    assert np.ptp(fast.delta[-2000:]) > 1e-3  # the comparison covers a live cycle


def test_kernel_matches_reference_with_noise_and_200hz_sampling():
    params = hypothesis("M000", noise_power=1e-10, noise_seed=3)
    experiment = ClosedLoop(5.84, 0.062, 12.3, sample_rate=200.0)
    fast = simulate(params, experiment, 5.0)
    slow = simulate_reference(params, experiment, 5.0, rate=1000.0)
    assert np.max(np.abs(fast.delta - slow.delta)) < 1e-5


@pytest.mark.parametrize("position", ["output", "before_integrator", "before_first_integrator"])
def test_kernel_matches_reference_open_loop_square(position):
    params = hypothesis("M001f", delay_position=position, delay=2.3e-3)
    experiment = OpenLoop.square(0.01, 2.0)
    fast = simulate(params, experiment, 2.0)
    slow = simulate_reference(params, experiment, 2.0, rate=1000.0)
    assert np.max(np.abs(fast.delta - slow.delta)) < 1e-5
    assert np.max(np.abs(fast.w - slow.w)) < 1e-5


def test_delay_line_outputs_zero_before_td_and_interpolates():
    line = DelayLine(delay=0.25, dt=0.1)
    for value in (1.0, 2.0, 3.0, 4.0):
        line.write(value)
    assert line.read(0.1) == 0.0
    # the step before Td ramps from the empty line's 0 to the first sample (continuous in Td)
    assert line.read(0.2) == pytest.approx(0.5)
    assert line.read(0.25) == pytest.approx(1.0)
    assert line.read(0.30) == pytest.approx(1.5)
    t = np.arange(4) * 0.1
    np.testing.assert_allclose(transport_delay(t, [1.0, 2.0, 3.0, 4.0], 0.15), [0, 0, 1.5, 2.5])
    with pytest.raises(ValueError, match="delay must be"):
        transport_delay(t, t, -0.1)


def test_transport_delay_in_kernel_shifts_the_output_exactly():
    """Output delay: delta(t) = x(t - Td), zero before Td (open-loop step)."""
    params = hypothesis("M002", delay=5e-3)
    tr = simulate(params, OpenLoop.step(0.01), 0.2, dt=1e-4, rate=10000.0)
    shift = 50  # 5 ms at 10 kHz
    assert np.all(tr.delta[:shift] == 0.0)
    np.testing.assert_allclose(tr.delta[shift:], tr.x[:-shift], atol=1e-15)


def test_batch_equals_single_runs_and_flags_divergence():
    sets = [hypothesis("M002"), hypothesis("M000"), hypothesis("M002", dead_zone=2e-3)]
    unstable = ClosedLoop(kp=400.0, kd=0.062, mu=12.3)
    result = simulate_batch(sets + [hypothesis("M002")], [CONTROLLER_A] * 3 + [unstable], 5.0)
    for i, params in enumerate(sets):
        single = simulate(params, CONTROLLER_A, 5.0)
        np.testing.assert_array_equal(result.signal("delta")[i], single.delta)
    assert list(result.diverged) == [False, False, False, True]
    assert result.status[3] in ("non-finite", "out of bound")
    assert 0 < result.stop_time[3] < 5.0
    assert np.isnan(result.signal("delta")[3, -1])
