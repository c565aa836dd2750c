"""Limit-cycle prediction under other controllers from a calibrated posterior.

The case is the prediction benchmark's (:func:`tvcid.studies.benchmarks.prediction.prediction_case`): a truth
drawn by the shared scenario generator (seeded), calibrated on closed-loop records at two
controller settings (made at dt = 2e-4, sensor noise 5e-5 rad, features likelihood), and its cycle
predicted at a third setting never used in the fit. The chain is cheaper than the benchmark's
(16 walkers to convergence, 420 steps on this seed): 8 walkers, the least for four sampled
parameters, capped at the benchmark's ``--quick`` 300 steps.
The band must bracket the generating model's own cycle, measured the same way; the tolerance
``SHORTCUT_TOL`` is the largest shortcut error ``tvcid.studies.benchmarks.prediction`` measured against
full-length runs (0.4 % in amplitude), doubled.
"""
import json

import numpy as np
import pytest

from tvcid.cli import main
from tvcid.discovery.prediction import (
    ControllerSetting,
    NoPosteriorError,
    PosteriorDraws,
    PredictionConfig,
    cycle_map,
    load_posterior_draws,
    parse_grid,
    predict_cycle,
)
from tvcid.discovery.prediction.design import (
    laplace_update,
    load_candidates,
    weighted_covariance,
)
from tvcid.models import ClosedLoop, SimulationDiverged, simulate
from tvcid.studies.benchmarks.prediction import THIRD as BENCH_THIRD
from tvcid.studies.benchmarks.prediction import measured_cycle, prediction_case

SEED = 11
THIRD = ControllerSetting(*BENCH_THIRD)
SHORTCUT_TOL = 0.01


@pytest.fixture(scope="module")
def posterior_dir(tmp_path_factory):
    return prediction_case(SEED, tmp_path_factory.mktemp("predict"), steps=300, walkers=8)


def test_prediction_at_an_unfitted_setting_brackets_the_generating_cycle(posterior_dir):
    directory, truth = posterior_dir
    draws = load_posterior_draws(directory, n_draws=200, seed=0)
    assert set(draws.physical_names) <= {"dead_zone", "backlash", "delay"}
    pred = predict_cycle(draws, THIRD).to_dict()
    f = measured_cycle(truth, THIRD)
    amp, freq = pred["amplitude"], pred["frequency"]
    assert pred["fraction_oscillating"] > 0.95
    assert amp["q05"] * (1 - SHORTCUT_TOL) <= f.amplitude <= amp["q95"] * (1 + SHORTCUT_TOL), (amp, f)
    assert freq["q05"] * (1 - SHORTCUT_TOL) <= f.frequency <= freq["q95"] * (1 + SHORTCUT_TOL), (freq, f)
    # the describing function of the median model is an approximation (DF_CAVEAT): within 15 %
    df = pred["describing_function"]
    assert df["frequency"] == pytest.approx(f.frequency, rel=0.15)


def test_divergence_predicted_where_the_generating_model_diverges(posterior_dir):
    directory, truth = posterior_dir
    draws = load_posterior_draws(directory, n_draws=60, seed=1)
    # a too small derivative time destabilises the loop (the actuator's lag eats the phase lead)
    diverging = None
    for kd in (0.02, 0.01, 0.005, 0.0):
        try:
            simulate(truth, ClosedLoop(3.0, kd, 12.3), 30.0, bound=1.0)
        except SimulationDiverged:
            diverging = kd
            break
    assert diverging is not None, "no diverging setting found for the drawn truth"
    pred = predict_cycle(draws, ControllerSetting(3.0, diverging, 12.3), describing=False)
    assert pred.fraction_diverging > 0.9
    stable = predict_cycle(draws, THIRD, describing=False)
    assert stable.fraction_diverging == 0.0


def test_map_marks_the_stability_boundary(posterior_dir, tmp_path):
    directory, _ = posterior_dir
    draws = load_posterior_draws(directory, n_draws=20, seed=2)
    cmap = cycle_map(draws, ControllerSetting(5.84, 0.062, 12.3),
                     {"kp": np.linspace(3.0, 9.0, 3), "kd": np.array([0.0, 0.06, 0.1])},
                     describing=False)
    div = cmap.summary["fraction_diverging"]
    assert cmap.shape == (3, 3)
    assert div[:, 0].max() > 0.5 and div[:, 1:].max() == 0.0
    cmap.to_csv(tmp_path / "map.csv")
    rows = (tmp_path / "map.csv").read_text().splitlines()
    assert len(rows) == 10 and rows[0].startswith("kp,kd,amplitude_q05")
    d = cmap.to_dict()
    assert d["shape"] == [3, 3] and len(d["amplitude_q50"]) == 9


def test_cli_predict_prints_the_documented_json(posterior_dir, capsys):
    directory, _ = posterior_dir
    code = main(["predict", str(directory), "--kp", "7.5", "--kd", "0.075", "--mu", "8",
                 "--draws", "30", "--json", "--no-df"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("amplitude", "frequency"):
        assert set(out[key]) == {"q05", "q50", "q95"}
        assert out[key]["q05"] <= out[key]["q50"] <= out[key]["q95"]
    assert out["fraction_oscillating"] + out["fraction_diverging"] + out["fraction_at_rest"] == 1.0


def test_cli_predict_grid_writes_map_files(posterior_dir, tmp_path):
    directory, _ = posterior_dir
    out = tmp_path / "map"
    code = main(["predict", str(directory), "--grid", "kp=4:8:2", "--grid", "kd=0.05:0.08:2",
                 "--draws", "10", "--no-df", "--no-progress", "--out", str(out)])
    assert code == 0
    assert {p.name for p in out.iterdir()} == {"map.json", "map.csv", "map.png"}
    assert json.loads((out / "map.json").read_text())["keys"] == ["kp", "kd"]


# -- bad input -------------------------------------------------------------------------------
def test_directory_without_a_chain_is_refused(tmp_path):
    with pytest.raises(NoPosteriorError, match="holds no chain"):
        load_posterior_draws(tmp_path)


@pytest.mark.parametrize("text, message", [
    ("kp=3:9:1", "at least 2 points"),
    ("kq=3:9:4", "KEY one of"),
    ("kp=3:9", "KEY=LO:HI:N"),
    ("kp=3:3:4", "different"),
])
def test_bad_grid_is_refused(text, message):
    with pytest.raises(ValueError, match=message):
        parse_grid(text)


def test_half_a_lead_is_refused():
    with pytest.raises(ValueError, match="both lead_zero and lead_pole"):
        ControllerSetting(5.84, 0.062, 12.3, lead_zero=5.0)


@pytest.mark.parametrize("spec, message", [
    ([{"kind": "closed", "kp": 5}], "missing key kd"),
    ([{"kind": "bench"}], "kind must be"),
    ([{"kind": "open", "waveform": "saw", "amplitude": 0.01}], "unknown open-loop waveform"),
    ([{"kind": "open", "waveform": "sine", "amplitude": 0.01, "frequency": 1, "colour": 1}],
     "unknown key"),
    ([], "non-empty list"),
])
def test_bad_candidates_are_refused(spec, message):
    with pytest.raises(ValueError, match=message):
        load_candidates(spec)


# -- the design's building blocks on known answers -----------------------------------------
def test_weighted_covariance_and_laplace_update_on_known_answers():
    rng = np.random.default_rng(0)
    z = rng.standard_normal((20000, 2)) * [1.0, 3.0]
    cov, ess = weighted_covariance(z, np.zeros(len(z)))
    assert ess == pytest.approx(len(z))
    assert np.sqrt(np.diag(cov)) == pytest.approx([1.0, 3.0], rel=0.03)
    # a unit-noise observation of the first coordinate halves its variance (prior variance 1)
    log_w = -0.5 * (z[:, 0] - 0.0) ** 2
    cov, ess = weighted_covariance(z, log_w)
    assert cov[0, 0] == pytest.approx(0.5, rel=0.05) and cov[1, 1] == pytest.approx(9.0, rel=0.05)
    post = laplace_update(np.diag([1.0, 9.0]), np.array([[1.0, 0.0]]))
    assert post == pytest.approx(np.diag([0.5, 9.0]))


def test_posterior_draws_helpers():
    from tvcid.discovery.calibration.priors import LogUniform
    from tvcid.models import M002

    x = np.column_stack([np.full(5, 1e-3), [1e-4, 2e-4, 3e-4, 4e-4, 5e-4]])
    draws = PosteriorDraws(names=("dead_zone", "sigma"), samples=x, internal=np.log(x),
                           base=M002(), priors={"dead_zone": LogUniform(1e-4, 1e-2),
                                                "sigma": LogUniform(1e-6, 1e-2)}, config={})
    assert draws.params(2).dead_zone == 1e-3 and draws.sigma() == pytest.approx(3e-4)
    assert draws.physical_names == ("dead_zone",)
    assert draws.widths()["sigma"] == pytest.approx(0.9 * 4e-4)
    assert PredictionConfig().window > 0


def test_shortcut_agrees_with_full_length_runs(posterior_dir):
    """The shortcut (pilot on the median model's cycle, 3 s transient) against 30 s transients
    from the hypothesis' own initial state: same outcome for every draw, quantiles within 0.5 %."""
    from tvcid.studies.benchmarks.prediction import shortcut_accuracy

    directory, _ = posterior_dir
    draws = load_posterior_draws(directory, n_draws=30, seed=3)
    acc = shortcut_accuracy(draws, [THIRD, ControllerSetting(5.0, 0.09, 12.3)],
                            PredictionConfig(), full_transient=30.0)
    assert acc["outcome_agreement_min"] == 1.0
    assert acc["amplitude"]["quantile_max"] < 0.005
    assert acc["frequency"]["quantile_max"] < 0.005


def test_draws_with_a_delay_under_the_default_step_are_predicted_at_a_halved_step():
    """A member whose delay prior reaches under 0.5 ms (a fit under 1 ms halves the floor) has
    draws with delays the default step cannot hold: they are predicted, and measured by the
    closure's tests, at the step halved until one step fits under the shortest delay, as the
    member was calibrated; delays of at least the step leave it alone."""
    from tvcid.discovery.calibration.priors import Uniform
    from tvcid.discovery.prediction.closure import set_closure
    from tvcid.discovery.prediction.cycles import step_under_delays
    from tvcid.discovery.prediction.discrimination import default_candidates
    from tvcid.discovery.prediction.settings import ControllerSetting
    from tvcid.models import M002

    delays = np.array([[4.2e-4], [4.6e-4], [5.5e-4], [7e-4]])
    draws = PosteriorDraws(names=("delay",), samples=delays, internal=delays, base=M002(),
                           priors={"delay": Uniform(3e-4, 2e-2)}, config={})
    config = PredictionConfig(transient=2.0, window=3.0, pilot=3.0)
    assert step_under_delays(config, draws.param_sets()).dt == pytest.approx(2.5e-4)
    assert step_under_delays(config, [M002()]) is config
    with pytest.raises(ValueError, match="shorter than the step"):
        simulate(draws.params(0), ClosedLoop(5.84, 0.062, 12.3), 0.1, dt=5e-4)
    pred = predict_cycle(draws, ControllerSetting(5.84, 0.062, 12.3, sample_rate=200.0), config,
                         describing=False)
    assert pred.config.dt == pytest.approx(2.5e-4)
    assert np.count_nonzero(pred.outcomes.outcome == "cycle") == len(delays)
    setting = ControllerSetting(8.0, 0.06, 9.0, sample_rate=200.0)
    closure = set_closure({"a": draws, "b": draws}, default_candidates(2000.0)[:1], [setting],
                          1e-5, n_draws=4, config=config)
    assert closure.closed and [t["name"] for t in closure.tests] == [
        default_candidates(2000.0)[0].name]
