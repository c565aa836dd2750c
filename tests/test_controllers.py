"""Compensator and bending mode: the transfer functions, and both simulators running them.

The kernel and the plain-Python reference realise the compensator differently (controllable
canonical form and its Tustin state space in the kernel; observable canonical form and the Tustin
difference equation in the reference), so their agreement checks the realisations as well.
"""
import math

import numpy as np
import pytest

from tvcid.models import CONTROLLER_A, ClosedLoop, hypothesis, simulate, simulate_batch
from tvcid.models.controllers import (
    BendingMode,
    ImproperTransferFunctionError,
    TransferFunction,
)
from tvcid.models.cycle_reading import limit_cycle_features
from tvcid.models.reference import simulate_reference

LEAD = TransferFunction.lead(4.0, 8.0)
NOTCH = TransferFunction.notch(60.0, 0.5, 0.1)
BENDING = BendingMode(60.0, 0.02, 0.002)
W = np.array([0.3, 2.0, 8.6, 45.0, 60.0, 200.0, 600.0])


def _closed(**kwargs):
    a = CONTROLLER_A
    return ClosedLoop(a.kp, a.kd, a.mu, **kwargs)


# -- TransferFunction ---------------------------------------------------------------------------
@pytest.mark.parametrize("tf", [LEAD, NOTCH, TransferFunction.series(LEAD, NOTCH),
                                TransferFunction((2.0, 1.0, 5.0), (1.0, 3.0, 7.0, 11.0))],
                         ids=["lead", "notch", "lead*notch", "generic"])
def test_state_space_and_tustin_realise_the_transfer_function(tf):
    a, b, c, d = tf.state_space()
    eye = np.eye(tf.order)
    continuous = np.array([c @ np.linalg.solve(1j * w * eye - a, b) + d for w in W])
    np.testing.assert_allclose(continuous, tf.response(W), rtol=1e-12, atol=1e-14)
    rate = 200.0
    ad, bd, cd, dd = tf.discretise(rate)
    z = np.exp(1j * W / rate)
    discrete = np.array([cd @ np.linalg.solve(zk * eye - ad, bd) + dd for zk in z])
    np.testing.assert_allclose(discrete, tf.discrete_response(W, rate), rtol=1e-11, atol=1e-13)


def test_static_gain_has_no_states():
    a, b, c, d = TransferFunction((2.5,), (1.0,)).discretise(200.0)
    assert a.shape == (0, 0) and b.size == 0 and c.size == 0 and d == 2.5


def test_improper_transfer_function_is_refused():
    with pytest.raises(ImproperTransferFunctionError, match="improper"):
        TransferFunction((1.0, 0.0, 0.0), (1.0, 1.0))
    assert issubclass(ImproperTransferFunctionError, ValueError)


def test_notch_gain_at_its_centre_is_its_depth():
    for depth in (0.0, 0.1, 0.5):
        notch = TransferFunction.notch(60.0, 0.3, depth)
        assert abs(notch.response(60.0)) == pytest.approx(depth, abs=1e-12)
        assert notch.dc_gain() == pytest.approx(1.0)


def test_lead_peak_phase_is_asin_of_the_corner_ratio():
    zero, pole = 4.0, 16.0
    lead = TransferFunction.lead(zero, pole)
    w = np.geomspace(0.1, 1000.0, 20001)
    phase = np.angle(lead.response(w))
    assert w[np.argmax(phase)] == pytest.approx(math.sqrt(zero * pole), rel=1e-3)
    peak = float(np.angle(lead.response(math.sqrt(zero * pole))))
    assert peak == pytest.approx(math.asin((pole - zero) / (pole + zero)), rel=1e-12)
    assert phase.max() <= peak + 1e-15
    assert lead.dc_gain() == 1.0 and lead.name == "lead"
    assert TransferFunction.lead(pole, zero).name == "lag"


# -- the simulators ---------------------------------------------------------------------------
CASES = {
    "lead": _closed(compensator=LEAD),
    "notch+bending": _closed(compensator=NOTCH, bending=BENDING),
    "lead*notch held 200 Hz": _closed(sample_rate=200.0, compensator=TransferFunction.series(LEAD, NOTCH)),
    "lead+bending held 200 Hz": _closed(sample_rate=200.0, compensator=LEAD, bending=BENDING),
}


@pytest.mark.parametrize("name", ["M002", "M000"])
@pytest.mark.parametrize("case", list(CASES))
def test_kernel_matches_reference_with_compensator_and_bending(name, case):
    params, experiment = hypothesis(name), CASES[case]
    fast = simulate(params, experiment, 3.0)
    slow = simulate_reference(params, experiment, 3.0, rate=1000.0)
    assert np.max(np.abs(fast.delta - slow.delta)) < 1e-10
    assert np.max(np.abs(fast.u - slow.u)) < 1e-10
    assert np.ptp(fast.delta[-1000:]) > 5e-4  # the comparison covers a live cycle
    plain = simulate(params, _closed(sample_rate=experiment.sample_rate), 3.0)
    assert np.max(np.abs(fast.delta - plain.delta)) > 1e-4  # the compensator did something


@pytest.mark.parametrize("sample_rate", [None, 200.0])
def test_unit_compensator_and_null_bending_are_the_plain_loop_bit_for_bit(sample_rate):
    params = hypothesis("M000")
    plain = simulate(params, _closed(sample_rate=sample_rate), 4.0, rate=None)
    unit = simulate(params, _closed(sample_rate=sample_rate,
                                    compensator=TransferFunction((1.0,), (1.0,))), 4.0, rate=None)
    # a bending mode of gain 0 runs the extended code path with q = 0
    null_bend = simulate(params, _closed(sample_rate=sample_rate, bending=BendingMode(60.0, 0.02, 0.0)),
                         4.0, rate=None)
    for other in (unit, null_bend):
        for row in ("u", "delta", "theta", "x", "y", "w", "backlash"):
            np.testing.assert_array_equal(getattr(other, row), getattr(plain, row))


def test_batch_pads_compensators_of_different_orders():
    experiments = [CONTROLLER_A, _closed(compensator=LEAD), _closed(compensator=NOTCH, bending=BENDING),
                   _closed(sample_rate=200.0, compensator=TransferFunction.series(LEAD, NOTCH))]
    params = hypothesis("M002")
    batch = simulate_batch([params] * len(experiments), experiments, 3.0)
    assert not batch.diverged.any()
    for i, exp in enumerate(experiments):
        np.testing.assert_array_equal(batch.signal("delta")[i], simulate(params, exp, 3.0).delta)


def test_calibration_batch_simulator_runs_a_compensated_loop():
    from tvcid.models.batch import BatchSimulator

    experiment = _closed(compensator=LEAD, bending=BENDING)
    params = hypothesis("M002")
    delta, ok = BatchSimulator(experiment, 3.0, 2e-4, rate=1000.0).run([params, None])
    assert list(ok) == [True, False]
    np.testing.assert_array_equal(delta[0], simulate(params, experiment, 3.0).delta)


def _phase_crossing(params, experiment, w):
    """Lowest frequency where the linear part seen by M002's dead zone on the error,
    ``A(s) (1 + C(s) V(s) exp(-s Td))`` with ``A = K1/(s (s^2 + K2 s + K3))``, has phase -180 deg:
    the first-harmonic balance with a real describing function."""
    s = 1j * w
    actuator = params.gain / (s * (s * s + params.damping * s + params.stiffness))
    loop = actuator * (1.0 + experiment.controller_response(w) * experiment.vehicle_response(w)
                       * np.exp(-s * params.delay))
    k = np.flatnonzero((np.sign(loop.imag[:-1]) != np.sign(loop.imag[1:])) & (loop.real[:-1] < 0))
    return w[k[0]]


@pytest.mark.parametrize("name", ["M002", "M000"])
def test_lead_filter_raises_the_cycle_frequency_as_its_phase_lead_implies(name):
    """A lead with its peak phase (19.5 deg at 5.7 rad/s) just below the cycle: the first-harmonic
    phase crossing of the loop moves up (computed on M002's structure from the loop's frequency
    responses), and so does the simulated cycle, for M002 and for M000.

    (Not every lead does this in simulation: with its peak above the cycle, (1 + s/8)/(1 + s/16),
    M002's cycle slows from 8.60 to 8.34 rad/s while the crossing rises to 9.2; the amplitude falls
    to a quarter and the waveform is far from a sine.)"""
    params = hypothesis(name)
    plain, lead = _closed(), _closed(compensator=LEAD)
    w = np.linspace(3.0, 30.0, 5401)
    m002 = hypothesis("M002")
    assert _phase_crossing(m002, lead, w) > 1.1 * _phase_crossing(m002, plain, w)
    f_plain = limit_cycle_features(*_tail(simulate(params, plain, 30.0)))
    f_lead = limit_cycle_features(*_tail(simulate(params, lead, 30.0)))
    assert f_lead.frequency > 1.1 * f_plain.frequency


def _tail(tr, seconds=15.0):
    sel = tr.t >= tr.t[-1] - seconds
    return tr.t[sel], tr.delta[sel]
