"""The transient each waveform record is simulated with, chosen by the accuracy it gives.

Once the walkers are placed, the calibration tries shorter transients and keeps the shortest
whose log-likelihood at the walkers (and as many points twice as far out) stays within
``TRANSIENT_TOLERANCE`` nats of a long one.
"""
import numpy as np
import pytest

from tvcid.discovery.calibration import Calibration
from tvcid.discovery.calibration import record_choices as calibration_module
from tvcid.models import CONTROLLER_A, M002
from tvcid.models.synthetic import synthetic_recording

NAMES = ("backlash", "dead_zone", "delay", "sigma")


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """M002, controller A, the last 10 s of a 20 s run, sensor noise 1e-4 rad (seed 1)."""
    path = tmp_path_factory.mktemp("transient") / "m002_A.csv"
    return synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, 1, path, keep_last=10.0)


def _started(record, **kw):
    cal = Calibration("M002", params=NAMES, n_walkers=10, seed=1, **kw).setup([record])
    walkers = cal._initial(np.random.default_rng(1))
    return cal, walkers


def test_the_shortest_accurate_transient_is_chosen_and_checked_against_a_long_one(record):
    cal, walkers = _started(record)
    (name, chosen), = cal.transients_.items()
    term = cal.terms_[0]
    assert chosen < cal.transient  # M002's cycle settles: 2 s is chosen on seeds 1-7
    assert term.transient == chosen and term.simulator.t_end == pytest.approx(term.sim_t_end)
    errors = cal.transient_errors_[name]
    assert errors[chosen] <= calibration_module.TRANSIENT_TOLERANCE
    assert all(e > calibration_module.TRANSIENT_TOLERANCE for t, e in errors.items() if t < chosen)
    # independently: a calibration simulating 12 s before the window agrees at the walkers
    long = Calibration("M002", params=NAMES, n_walkers=10, seed=1, transient=12.0,
                       choose_transient=False).setup([record])
    long.terms_[0].inflation = term.inflation
    lp, lp_long = cal.log_posterior_, long.log_posterior_
    assert np.max(np.abs(lp(walkers) - lp_long(walkers))) <= calibration_module.TRANSIENT_TOLERANCE


def test_no_transient_within_tolerance_falls_back_to_the_reference(record, monkeypatch):
    monkeypatch.setattr(calibration_module, "TRANSIENT_TOLERANCE", 1e-12)
    cal, _ = _started(record)
    assert list(cal.transients_.values()) == [calibration_module.TRANSIENT_REFERENCE]
    assert cal.terms_[0].transient == calibration_module.TRANSIENT_REFERENCE


def test_the_given_transient_is_kept_when_not_chosen(record):
    cal, _ = _started(record, choose_transient=False)
    assert cal.terms_[0].transient == cal.transient == 6.0
    assert cal.transients_ == {}
