"""SINDy's components: the pysindy feature library, the weak form, the estimator's checks, the
CLI."""
import json

import numpy as np
import pysindy as ps
import pytest

from tvcid.cli import main
from tvcid.discovery.sindy import (
    ActuatorLibrary,
    BumpTestFunctions,
    RecordingTooShortError,
    UnknownFormError,
    WeakSINDyActuator,
    play_along,
)
from tvcid.discovery.sindy.library import command_jumps, delayed_command
from tvcid.discovery.sindy.weak import prepare_signals, weak_integrals
from tvcid.models import OpenLoop, hypothesis, simulate
from tvcid.models.nonlinearities import dead_zone, play_operator
from tvcid.models.recording import load_recording, recording_from_trajectory, save_recording


def test_play_along_matches_the_models_play_operator():
    x = np.sin(np.linspace(0, 20, 2001)) * np.linspace(0, 1, 2001)
    assert np.allclose(play_along(x, 0.1, initial=0.0), play_operator(x, 0.1, initial=0.0))


def test_delayed_square_command_keeps_its_edges():
    t = np.arange(0, 2, 1e-3)
    u = OpenLoop.square(1.0, 1.0).command(t)
    assert command_jumps(u).sum() == 3
    fine = np.arange(0, 1.99, 1e-4)
    exact = OpenLoop.square(1.0, 1.0).command(fine - 7.3e-3) * (fine >= 7.3e-3) + (
        u[0] * (fine < 7.3e-3))
    got = delayed_command(fine, t, u, 7.3e-3)
    # wrong only within one coarse sample of an edge
    assert np.mean(np.abs(got - exact) > 1e-9) < 2e-3


def test_actuator_library_with_pysindy_optimizers():
    rng = np.random.default_rng(0)
    t = np.arange(0, 4, 1e-3)
    delta = 0.01 * np.sin(2 * np.pi * 1.3 * t) + 0.004 * np.sin(2 * np.pi * 3.1 * t)
    u = 0.012 * np.sin(2 * np.pi * 0.7 * t + 0.4)
    lib = ActuatorLibrary(dead_zone=1e-3, backlash=2e-4, delay=0.0, dt=1e-3)
    theta = lib.fit(np.column_stack([delta, u])).transform(np.column_stack([delta, u]))
    names = lib.get_feature_names()
    assert len(names) == theta.shape[1] == 6
    dz = dead_zone(u - play_along(delta, 2e-4), 1e-3)
    assert np.allclose(theta[:, names.index("DZ_z(u(t-Td)-K*play_r(delta))")], dz)
    target = 3.0 * dz - 0.5 * delta + 1e-6 * rng.standard_normal(t.size)
    for optimizer in (
        ps.STLSQ(threshold=0.1, normalize_columns=True),
        ps.SR3(reg_weight_lam=1e-3, regularizer="L0", normalize_columns=True),
        ps.EnsembleOptimizer(ps.STLSQ(threshold=0.1, normalize_columns=True), bagging=True,
                             n_models=10),
    ):
        coef = optimizer.fit(np.asarray(theta), target).coef_[0]
        assert coef[names.index("DZ_z(u(t-Td)-K*play_r(delta))")] == pytest.approx(3.0, rel=0.05)
        assert coef[names.index("delta")] == pytest.approx(-0.5, rel=0.05)
        assert abs(coef[names.index("sign(delta')")]) < 1e-3


def test_actuator_library_rejects_a_bad_term_and_a_bad_input():
    with pytest.raises(ValueError, match="unknown library term"):
        ActuatorLibrary(terms=["cubic"]).fit(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="two input columns"):
        ActuatorLibrary().fit(np.zeros((10, 3)))


def test_weak_integrals_integrate_by_parts():
    # int phi x''' = -int phi''' x for x = sin(w t): no boundary terms, no numerical derivative
    t = np.arange(0, 3, 1e-3)
    w = 2 * np.pi * 2.0
    tf = BumpTestFunctions(0.045)
    prep = prepare_signals(t, np.zeros_like(t), np.sin(w * t), tf)
    lhs = -weak_integrals(prep, np.sin(w * t), 3)
    rhs = weak_integrals(prep, -w**3 * np.cos(w * t), 0)
    assert np.allclose(lhs, rhs, rtol=0, atol=1e-3 * np.max(np.abs(rhs)))
    second = weak_integrals(prep, np.sin(w * t), 2)
    assert np.allclose(second, weak_integrals(prep, -w**2 * np.sin(w * t), 0),
                       atol=1e-3 * np.max(np.abs(second)))


@pytest.fixture(scope="module")
def short_recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("sindy_cli")
    tr = simulate(hypothesis("M002"), OpenLoop.square(2e-2, 2.0), 3.0, rate=1000)
    columns, meta = recording_from_trajectory(tr, seed=0)
    columns["delta"] = columns["delta"] + 1e-5 * np.random.default_rng(5).standard_normal(tr.t.size)
    return save_recording(d / "m002_square.csv", columns, meta)


def test_estimator_fit_returns_self_and_learned_attributes(short_recording):
    est = WeakSINDyActuator(forms=["dead_zone_on_error"], noise=1e-5, n_bootstrap=3)
    assert not hasattr(est, "candidates_")
    assert est.fit(short_recording) is est
    assert est.n_rows_ > 8 and est.fit_time_ > 0
    assert est.candidates_[0].form == "dead_zone_on_error"


def test_estimator_errors_name_the_culprit(tmp_path, short_recording):
    with pytest.raises(UnknownFormError, match="unknown structure form 'M9'"):
        WeakSINDyActuator(forms=["M9"]).fit(short_recording)
    with pytest.raises(ValueError, match="noise must be"):
        WeakSINDyActuator(noise=-1.0).fit(short_recording)
    rec = load_recording(short_recording)
    cols = {k: v[:60] for k, v in rec.columns.items()}
    short = save_recording(tmp_path / "tiny.csv", cols, rec.meta)
    with pytest.raises(RecordingTooShortError, match="tiny.csv"):
        WeakSINDyActuator(forms=["dead_zone_on_error"]).fit(short)


def test_cli_sindy_json(short_recording, capsys):
    code = main(["sindy", str(short_recording), "--noise", "1e-5", "--form", "dead_zone_on_error",
                 "--bootstrap", "5", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    cand = out["candidates"][0]
    assert {"form", "terms", "thresholds", "inclusion", "score"} <= set(cand)
    assert cand["form"] == "dead_zone_on_error"
    assert cand["thresholds"]["delay"] == pytest.approx(7e-3, abs=5e-4)
    assert cand["score"] is not None and cand["score"] < 0.05


def test_cli_sindy_unknown_form_is_rejected(short_recording, capsys):
    with pytest.raises(SystemExit):
        main(["sindy", str(short_recording), "--form", "nonsense"])
    assert "invalid choice" in capsys.readouterr().err


def test_actuator_library_inside_pysindy_sindy_model():
    # the library plugs into ps.SINDy (lists of trajectories, feature names from the inputs)
    t = np.arange(0, 2, 1e-3)
    x = np.column_stack([0.01 * np.sin(2 * np.pi * 1.3 * t), 0.012 * np.sin(2 * np.pi * 0.7 * t)])
    lib = ActuatorLibrary(dead_zone=1e-3, backlash=2e-4, dt=1e-3, terms=["delta", "play_r(delta)"])
    model = ps.SINDy(feature_library=lib, optimizer=ps.STLSQ(threshold=1e-6))
    model.fit([x, x[::-1].copy()], t=1e-3, feature_names=["d", "c"])
    assert model.get_feature_names() == ["d", "play_r(d)"]
    assert np.asarray(model.coefficients()).shape == (2, 2)
