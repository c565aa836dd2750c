"""A cycle that is not periodic (M000's band-pass loop): the features likelihood's covariance counts
its wander (and not a periodic M002's), and the waveform likelihood warns."""
import warnings
from pathlib import Path

import numpy as np
import pytest

from discovery.calibration import synthetic_recording
from discovery.calibration.likelihood import FeatureTerm
from models import CONTROLLER_A, M002
from models.recording import load_recording

DATA = Path(__file__).resolve().parents[1] / "data"


def test_m000_cycle_wanders_beyond_its_sensor_noise():
    term = FeatureTerm(load_recording(DATA / "m000_closed_A.csv"), 10.0, 6.0, 5e-4)
    freq = term.features.index("frequency")
    wander_sd = np.sqrt(term.wander_var[freq])
    # M000's band-pass loop leaves the 10 s frequency wandering by a few tenths of a percent
    assert 1e-3 < wander_sd / term.observed[freq] < 1e-2
    assert np.sqrt(term.cov_hat[freq, freq]) > 1.4 * wander_sd


def test_periodic_m002_cycle_has_no_wander(tmp_path):
    rec = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, 3, tmp_path / "m002.csv", keep_last=10.0)
    term = FeatureTerm(rec, 10.0, 6.0, 5e-4)
    assert np.all(term.wander_var == 0.0)



def test_waveform_likelihood_warns_on_a_cycle_that_is_not_periodic(tmp_path):
    from discovery.calibration import Calibration, IllPosedLikelihoodWarning

    m000 = load_recording(DATA / "m000_closed_A.csv")
    with pytest.warns(IllPosedLikelihoodWarning, match="m000_closed_A: the simulated cycle .* not periodic"):
        Calibration("M000", params=("dead_zone",), likelihood="waveform").setup([m000])
    rec = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, 3, tmp_path / "m002.csv", keep_last=10.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", IllPosedLikelihoodWarning)
        cal = Calibration("M002", params=("dead_zone",), likelihood="waveform").setup([rec])
    assert cal.terms_[0].period_mismatch < 0.01 * cal.terms_[0].sigma_hat
