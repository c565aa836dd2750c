"""tvcid.discovery.prediction.set_prediction and ``tvcid predict`` on a set: every member of a set
predicts with its own draws; the band is their mixture, weighted by each member's weight and
oscillating fraction; the output says whether the members agree at a controller."""
import json

import numpy as np
import pytest

from tvcid.cli import main
from tvcid.discovery.calibration.priors import LogUniform
from tvcid.discovery.prediction import PredictionConfig
from tvcid.discovery.prediction.cycles import CycleOutcomes, CyclePrediction
from tvcid.discovery.prediction.draws import PosteriorDraws, load_set_weights
from tvcid.discovery.prediction.set_prediction import (
    SetPrediction,
    members_agree,
    predict_cycle_over_set,
)
from tvcid.discovery.prediction.settings import ControllerSetting
from tvcid.models import M002

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
    assert apart["disagreeing"] == [{"members": ["small", "large"], "why": "amplitudes differ"}]
    assert apart["amplitude"]["q05"] <= small["q50"] and apart["amplitude"]["q95"] >= large["q50"]
    alike = predict_cycle_over_set({"a": _draws(z), "b": _draws(z, seed=1)}, SETTING_A, CONFIG,
                                   describing=False).to_dict()
    assert alike["members_agree"] and alike["disagreeing"] == []


def test_agreement_rule_on_known_bands():
    """Members agree on a quantity when their medians differ by at most sqrt(h_a^2 + h_b^2), the
    90 % half-width of the difference of two measurements (half-widths 1: 1.3 apart agree, 1.6
    apart part, though the bands overlap and the sum of the half-widths, 2, would let them
    agree); the half-widths are those facing each other; one member oscillating where the other
    rests disagrees; two members at rest agree."""
    def band(a, f, osc=1.0):
        return {"amplitude": {"q05": a - 1, "q50": a, "q95": a + 1},
                "frequency": {"q05": f - 1, "q50": f, "q95": f + 1}, "fraction_oscillating": osc}

    assert members_agree({"a": band(5, 8), "b": band(6, 9)})[0]
    assert members_agree({"a": band(5, 8), "b": band(6.3, 8)})[0]
    assert members_agree({"a": band(5, 8), "b": band(6.6, 8)})[1] == [("a", "b",
                                                                       "amplitudes differ")]
    assert members_agree({"a": band(5, 8), "b": band(5, 9.6)})[1] == [("a", "b",
                                                                       "frequencies differ")]
    # facing sides 0.2 and 0.5 (the far sides, 1 and 3, would cover the 1.0 between the medians)
    lopsided = {"a": band(5, 8), "b": band(5, 8)}
    lopsided["a"]["amplitude"] = {"q05": 4.0, "q50": 5.0, "q95": 5.2}
    lopsided["b"]["amplitude"] = {"q05": 5.5, "q50": 6.0, "q95": 9.0}
    assert members_agree(lopsided)[1] == [("a", "b", "amplitudes differ")]
    assert not members_agree({"a": band(5, 8), "b": band(5, 8, osc=0.2)})[0]
    assert members_agree({"a": band(5, 8, osc=0.0), "b": band(50, 80, osc=0.1)})[0]
    # a member the weights decided against (under 5 %) is not counted; at 5 % it is
    apart = {"a": band(5, 8), "b": band(5, 8), "c": band(9, 8)}
    assert not members_agree(apart, weights={"a": 0.5, "b": 0.45, "c": 0.05})[0]
    assert members_agree(apart, weights={"a": 0.5, "b": 0.47, "c": 0.03}) == (True, [])
    # ... unless its weight is not final (its chain stopped at its cap)
    assert not members_agree(apart, weights={"a": 0.5, "b": 0.47, "c": 0.03}, unsure=["c"])[0]
    with pytest.raises(ValueError, match="no member"):
        predict_cycle_over_set({}, SETTING_A)


def test_bands_apart_by_less_than_a_recording_resolves_agree():
    """Narrow bands 0.4 % apart: apart on the bands alone, agreeing once each member's measurement
    carries a recording's 0.3 % resolution (1.645 sd, in quadrature); 4 % apart they still
    part."""
    def band(f, half=0.001):
        return {"amplitude": {"q05": 5 - 1e-3, "q50": 5.0, "q95": 5 + 1e-3},
                "frequency": {"q05": f * (1 - half), "q50": f, "q95": f * (1 + half)},
                "fraction_oscillating": 1.0}

    near, far = {"a": band(50.0), "b": band(50.2)}, {"a": band(50.0), "b": band(52.0)}
    resolution = {"amplitude": 0.003, "frequency": 0.003}
    assert not members_agree(near)[0]
    assert members_agree(near, resolution)[0]
    assert members_agree(far, resolution)[1] == [("a", "b", "frequencies differ")]


def test_a_recording_resolves_a_cycle_to_its_noise_and_wander():
    """The bundled M000 cycles (the band-pass loop's wandering cycle, 1 kHz, sensor noise):
    frequency and first harmonic resolved to 0.01-5 % (a relative sd; the wander dominates), the
    first harmonic less finely than the frequency; no closed-loop recording, no resolution."""
    from pathlib import Path

    from tvcid.discovery.prediction.set_prediction import measurement_resolution
    from tvcid.models.recording import load_recording

    data = Path(__file__).resolve().parents[1] / "data"
    closed = [load_recording(data / f"m000_closed_{c}.csv") for c in "AB"]
    res = measurement_resolution(closed)
    assert 1e-4 < res["frequency"] < 0.05 and 1e-4 < res["amplitude"] < 0.05
    assert res["amplitude"] > res["frequency"]
    assert measurement_resolution([load_recording(data / "m000_open_sine.csv")]) is None


# -- the mixture's weights -------------------------------------------------------------------
def _prediction(amplitudes, n_draws):
    """A :class:`CyclePrediction` whose first draws oscillate at ``amplitudes`` (rad, frequency
    8 rad/s) and the rest of its ``n_draws`` rest; no simulation."""
    k = len(amplitudes)
    amp = np.concatenate([amplitudes, np.full(n_draws - k, np.nan)])
    freq = np.where(np.isfinite(amp), 8.0, np.nan)
    outcome = np.array(["cycle"] * k + ["rest"] * (n_draws - k))
    return CyclePrediction(SETTING_A, CycleOutcomes(outcome, amp, amp, freq, np.zeros(n_draws)),
                           describing={})


def test_a_member_oscillating_in_few_draws_holds_its_share_of_the_band():
    """A member oscillating in 5 % of its draws (at 10 rad) beside one oscillating in all (near
    1 rad): with equal weights it holds 0.05 / 1.05 of the band, so the band stays on the other
    member's cycle and the set oscillates with probability 0.525; weighted 0.9 against 0.1, it
    holds 0.045 / 0.145 of the band, which then reaches its cycle."""
    members = {"rare": _prediction(np.linspace(10.0, 10.4, 5), 100),
               "steady": _prediction(np.linspace(0.9, 1.1, 100), 100)}
    equal = SetPrediction(members).to_dict()
    assert equal["amplitude"]["q95"] <= 1.1
    assert equal["amplitude"]["q50"] == pytest.approx(1.0, abs=0.01)
    assert equal["fraction_oscillating"] == pytest.approx(0.525)
    assert equal["weights"] == {"rare": 0.5, "steady": 0.5} and not equal["weights_stored"]
    assert equal["members"]["rare"]["share_of_band"] == pytest.approx(0.05 / 1.05)
    assert equal["members"]["rare"]["fraction_oscillating"] == pytest.approx(0.05)
    tilted = SetPrediction(members, weights={"rare": 9.0, "steady": 1.0}).to_dict()
    assert tilted["weights"] == pytest.approx({"rare": 0.9, "steady": 0.1})
    assert tilted["members"]["rare"]["share_of_band"] == pytest.approx(0.045 / 0.145)
    assert tilted["fraction_oscillating"] == pytest.approx(0.145)
    assert tilted["amplitude"]["q95"] >= 10.0 and tilted["amplitude"]["q50"] <= 1.1
    with pytest.raises(ValueError, match="no weight for member steady"):
        SetPrediction(members, weights={"rare": 1.0}).to_dict()


# -- tvcid predict on a discover directory with two members -----------------------------------
#: Sampled names of the hand-made chains, and each one's spread (sd of its log).
_SAMPLED = {"dead_zone": 0.02, "delay": 0.1, "gain": 0.05}
#: Paper 002's model, and the same without its backlash, its dead zone shrunk so that both show
#: one cycle amplitude at controller A: they agree on the cycle near the stability boundary
#: (Kd 0.05) and part in frequency at Kd 0.1 (3.5 % apart, their bands about 1 %).
_MEMBERS = {"M002": M002(), "M002 without backlash": M002().replace(backlash=0.0,
                                                                   dead_zone=0.861 * 1.2e-3)}
AGREE = ["--kp", "5.84", "--kd", "0.05", "--mu", "12.3"]
PART = ["--kp", "5.84", "--kd", "0.1", "--mu", "12.3"]


def _write_chain(path, base, seed, walkers=8, steps=40):
    """A tvcid chain file of independent draws around ``base`` (log-normal in each name of
    :data:`_SAMPLED`), with the set-up :func:`tvcid.discovery.prediction.draws.load_chain_draws`
    reads."""
    from emcee import State

    from tvcid.discovery.calibration import CheckpointBackend

    rng = np.random.default_rng(seed)
    names = list(_SAMPLED)
    centre = np.log([getattr(base, n) for n in names])
    backend = CheckpointBackend(str(path), name="mcmc")
    backend.reset(walkers, len(names))
    backend.grow(steps, None)
    # emcee stores its sampler's generator state with every step; nothing is drawn from it
    stored = np.random.RandomState(seed).get_state()
    for _ in range(steps):
        z = centre + np.array(list(_SAMPLED.values())) * rng.standard_normal((walkers, len(names)))
        backend.save_step(State(z, log_prob=np.zeros(walkers), random_state=stored),
                          np.ones(walkers, dtype=bool))
    priors = {n: LogUniform(getattr(base, n) / 10, getattr(base, n) * 10).describe() for n in names}
    config = {"hypothesis": base.name, "base": base.to_dict(), "params": names, "priors": priors}
    with backend.open("a") as f:
        g = f.require_group("tvcid")
        g.attrs["config"] = json.dumps(config)
        g.attrs["sigma"] = 5e-5


@pytest.fixture(scope="module")
def set_dir(tmp_path_factory):
    """A discover directory whose set holds the two members of :data:`_MEMBERS`, weighted 0.75
    and 0.25 (no recordings: the members are compared on their bands alone)."""
    directory = tmp_path_factory.mktemp("set")
    rows = []
    for i, ((name, base), weight) in enumerate(zip(_MEMBERS.items(), (0.75, 0.25))):
        _write_chain(directory / f"chain_{i}.h5", base, seed=i)
        rows.append({"structure": name, "weight": weight, "posterior": {"chain": f"chain_{i}.h5"}})
    (directory / "discovery.json").write_text(json.dumps(
        {"recordings": [], "set_posterior": {"members": rows}}))
    return directory


def _predict_json(directory, controller, capsys, seed="3"):
    code = main(["predict", str(directory), *controller, "--draws", "16", "--seed", seed,
                 "--no-df", "--json"])
    assert code == 0
    return json.loads(capsys.readouterr().out)


def test_cli_members_agree_near_the_stability_boundary(set_dir, capsys):
    """At Kd 0.05 both members oscillate and their cycles differ by less than two measurements
    would: they agree; the mixture weighs them 0.75 and 0.25 as the run stores, and its band
    spans both medians."""
    out = _predict_json(set_dir, AGREE, capsys)
    assert out["members_agree"] and out["disagreeing"] == []
    assert out["weights"] == {"M002": 0.75, "M002 without backlash": 0.25} and out["weights_stored"]
    members = out["members"]
    for name, weight in (("M002", 0.75), ("M002 without backlash", 0.25)):
        assert members[name]["fraction_oscillating"] == 1.0
        assert members[name]["weight"] == weight and members[name]["share_of_band"] == weight
    for q in ("amplitude", "frequency"):
        medians = [m[q]["q50"] for m in members.values()]
        assert out[q]["q05"] <= min(medians) and out[q]["q95"] >= max(medians)


def test_cli_members_part_where_the_backlash_shifts_the_cycle(set_dir, capsys):
    """At Kd 0.1 the member without backlash cycles 3.5 % slower, beyond what two measurements
    would differ by: the output says the choice of structure changes the answer, and why. The
    text names each member's weight and oscillating fraction."""
    out = _predict_json(set_dir, PART, capsys)
    assert not out["members_agree"]
    assert out["disagreeing"] == [{"members": ["M002", "M002 without backlash"],
                                   "why": "frequencies differ"}]
    assert main(["predict", str(set_dir), *PART, "--draws", "16", "--seed", "3", "--no-df"]) == 0
    text = capsys.readouterr().out
    assert "the choice of structure changes the answer here" in text
    assert "M002: weight 0.75, oscillating 100% (75% of the band)" in text
    assert "M002 without backlash: weight 0.25, oscillating 100% (25% of the band)" in text
    assert "weights of the set's posterior" in text


def test_cli_set_prediction_is_seeded_from_seed(set_dir, capsys, monkeypatch):
    """``--seed`` selects the draws and seeds every member's in-loop noise; one seed gives one
    answer, another seed other draws."""
    import tvcid.discovery.prediction.set_prediction as sp

    seeds = []
    real = sp.predict_cycle

    def spy(draws, setting, config, **kwargs):
        seeds.append(config.seed)
        return real(draws, setting, config, **kwargs)

    monkeypatch.setattr(sp, "predict_cycle", spy)
    first = _predict_json(set_dir, PART, capsys, seed="7")
    assert seeds == [7, 7]
    assert _predict_json(set_dir, PART, capsys, seed="7") == first
    assert _predict_json(set_dir, PART, capsys, seed="8")["amplitude"] != first["amplitude"]


def test_stored_weights_are_read_and_checked(tmp_path):
    """Weights stored for every member are normalised; none stored gives ``None`` (equal);
    some missing, a negative one or all zero are refused in one line."""
    def run_with(weights):
        rows = [{"structure": n, "posterior": {"chain": f"{n}.h5"}} for n in "ab"]
        for row, w in zip(rows, weights):
            if w is not None:
                row["weight"] = w
        (tmp_path / "discovery.json").write_text(json.dumps({"set_posterior": {"members": rows}}))
        return load_set_weights(tmp_path)

    assert run_with([3.0, 1.0]) == {"a": 0.75, "b": 0.25}
    from tvcid.discovery.prediction.draws import load_unsure_members

    assert load_unsure_members(tmp_path) == ()  # no evidence weighting stored: none unsure
    stored = json.loads((tmp_path / "discovery.json").read_text())
    stored["set_posterior"]["weighting"] = {"method": "evidence", "upper": {"a": 0.8, "b": 0.3},
                                            "evidence": {"a": {"reliable": True},
                                                         "b": {"reliable": False}}}
    stored["set_posterior"]["members"][0]["converged"] = True
    (tmp_path / "discovery.json").write_text(json.dumps(stored))
    assert load_unsure_members(tmp_path) == ("b",)  # worked out where the run stores none
    stored["set_posterior"]["unsure"] = ["a"]
    (tmp_path / "discovery.json").write_text(json.dumps(stored))
    assert load_unsure_members(tmp_path) == ("a",)  # the run's own list where it stores one
    assert run_with([None, None]) is None
    for weights, message in (([0.5, None], "member b stores no weight"),
                             ([0.5, -0.1], "member b's weight -0.1 is not a finite number"),
                             ([0, 0], "every member's weight is 0")):
        with pytest.raises(ValueError, match=message):
            run_with(weights)
