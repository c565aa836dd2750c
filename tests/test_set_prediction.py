"""discovery.prediction.set_prediction: every member of a set predicts with its own draws; the
band is their mixture; the output says whether the members agree at a controller."""
import numpy as np
import pytest

from discovery.calibration.priors import LogUniform
from discovery.prediction import PredictionConfig
from discovery.prediction.draws import PosteriorDraws
from discovery.prediction.set_prediction import members_agree, predict_cycle_over_set
from discovery.prediction.settings import ControllerSetting
from models import M002

CONFIG = PredictionConfig(transient=8.0, window=6.0)
SETTING_A = ControllerSetting(kp=5.84, kd=0.062, mu=12.3)


def _draws(dead_zone, spread=0.01, n=6, seed=0):
    """Draws of paper 002's model with its dead zone around ``dead_zone`` (rad)."""
    rng = np.random.default_rng(seed)
    z = dead_zone * np.exp(spread * rng.standard_normal(n))
    return PosteriorDraws(names=("dead_zone",), samples=z[:, None], internal=np.log(z)[:, None],
                          base=M002(), priors={"dead_zone": LogUniform(1e-5, 0.1)}, config={})


def test_members_that_differ_in_the_dead_zone_disagree_and_the_mixture_spans_both():
    """Two members, one with twice the other's dead zone: their amplitude bands lie apart, so the
    output says the structure changes the answer; the mixture's band spans both medians. Two
    members drawn from the same posterior agree."""
    z = M002().dead_zone
    apart = predict_cycle_over_set({"small": _draws(z), "large": _draws(2 * z, seed=1)}, SETTING_A,
                                   CONFIG, describing=False).to_dict()
    small, large = apart["members"]["small"]["amplitude"], apart["members"]["large"]["amplitude"]
    assert large["q05"] > small["q95"]
    assert not apart["members_agree"]
    assert apart["disagreeing"] == [{"members": ["small", "large"], "why": "amplitude bands apart"}]
    assert apart["amplitude"]["q05"] <= small["q50"] and apart["amplitude"]["q95"] >= large["q50"]
    alike = predict_cycle_over_set({"a": _draws(z), "b": _draws(z, seed=1)}, SETTING_A, CONFIG,
                                   describing=False).to_dict()
    assert alike["members_agree"] and alike["disagreeing"] == []


def test_agreement_rule_on_known_bands():
    """Overlapping bands agree; disjoint frequency bands, or one member oscillating where the
    other rests, disagree; two members at rest agree."""
    def band(a, f, osc=1.0):
        return {"amplitude": {"q05": a - 1, "q50": a, "q95": a + 1},
                "frequency": {"q05": f - 1, "q50": f, "q95": f + 1}, "fraction_oscillating": osc}

    assert members_agree({"a": band(5, 8), "b": band(6, 9)})[0]
    assert members_agree({"a": band(5, 8), "b": band(5, 11)})[1] == [("a", "b", "frequency bands apart")]
    assert not members_agree({"a": band(5, 8), "b": band(5, 8, osc=0.2)})[0]
    assert members_agree({"a": band(5, 8, osc=0.0), "b": band(50, 80, osc=0.1)})[0]
    with pytest.raises(ValueError, match="no member"):
        predict_cycle_over_set({}, SETTING_A)


def test_bands_apart_by_less_than_a_recording_resolves_agree():
    """Narrow bands 0.4 % apart: apart on the bands alone, agreeing once each is widened by a
    recording's 0.3 % resolution (1.645 sd each side); 4 % apart they still part."""
    def band(f, half=0.001):
        return {"amplitude": {"q05": 5 - 1e-3, "q50": 5.0, "q95": 5 + 1e-3},
                "frequency": {"q05": f * (1 - half), "q50": f, "q95": f * (1 + half)},
                "fraction_oscillating": 1.0}

    near, far = {"a": band(50.0), "b": band(50.2)}, {"a": band(50.0), "b": band(52.0)}
    resolution = {"amplitude": 0.003, "frequency": 0.003}
    assert not members_agree(near)[0]
    assert members_agree(near, resolution)[0]
    assert members_agree(far, resolution)[1] == [("a", "b", "frequency bands apart")]


def test_a_recording_resolves_a_cycle_to_its_noise_and_wander():
    """The bundled M000 cycles (the band-pass loop's wandering cycle, 1 kHz, sensor noise):
    frequency and first harmonic resolved to 0.01-5 % (a relative sd; the wander dominates), the
    first harmonic less finely than the frequency; no closed-loop recording, no resolution."""
    from pathlib import Path

    from discovery.prediction.set_prediction import measurement_resolution
    from models.recording import load_recording

    data = Path(__file__).resolve().parents[1] / "data"
    closed = [load_recording(data / f"m000_closed_{c}.csv") for c in "AB"]
    res = measurement_resolution(closed)
    assert 1e-4 < res["frequency"] < 0.05 and 1e-4 < res["amplitude"] < 0.05
    assert res["amplitude"] > res["frequency"]
    assert measurement_resolution([load_recording(data / "m000_open_sine.csv")]) is None
