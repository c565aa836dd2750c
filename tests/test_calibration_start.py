"""The start of a calibration's chain (:class:`tvcid.discovery.calibration.start.StartSearch`): from a
start where the model has no limit cycle, the global search finds the posterior's mass, with or
without the discrepancy term."""
import warnings

import numpy as np
import pytest

from tvcid.discovery.calibration import Calibration
from tvcid.discovery.calibration.runner import ConvergenceWarning
from tvcid.models.structures import Structure
from tvcid.models.synthetic import synthetic_recording
from tvcid.studies.benchmarks.coverage import Config, _start, coverage_scenario, priors_for


def test_a_start_without_a_cycle_reaches_the_cycle_without_the_discrepancy_term(tmp_path):
    """Coverage draw 26 (velocity dead zone, friction offset, backlash, delay; one limit cycle
    at 1 kHz here, made by the kernel with 3e-5 rad of noise) from its benchmark start, 30 % off
    the truth by log-normal scatter: there the model's cycle dies out, so the features likelihood
    is -inf and Nelder-Mead cannot move. Without the discrepancy term the calibration must still
    search globally, reach a finite maximum, and put the dead zone the cycle pins within 2 % of
    the truth (here 0.2 %); a search gated on the term stops with "could not place the walkers"."""
    config = Config()
    scenario = coverage_scenario(26, config)
    truth = scenario.truth
    closed = next(d for d in scenario.recordings if d.kind == "closed")
    rec = synthetic_recording(truth, closed.experiment(), 38.0, 3e-5, 5, tmp_path / "d26.csv",
                              keep_last=28.0)
    names = ("dead_zone", "backlash", "delay", "friction_offset")
    priors = priors_for(Structure.of_params(truth))
    drawn = _start(truth, priors, np.random.default_rng([config.seed + 26, 1]), config.start_scatter)
    start = {n: drawn[n] for n in names}
    cal = Calibration(truth, params=names, priors={n: priors[n] for n in names}, start=start,
                      likelihood="features", window=config.window, transient=config.transient,
                      dt=config.dt, discrepancy=False, n_walkers=8, max_steps=10,
                      stop_when_converged=False, seed=3)
    cal.setup([rec])
    lp = cal.log_posterior_
    assert lp(lp.internal(np.array([[start[n] for n in names]]))[0]) == -np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        cal.fit([rec])
    best = np.array([[cal.map_start_[n] for n in names]])
    assert np.isfinite(lp(lp.internal(best)[0]))
    assert cal.map_start_["dead_zone"] == pytest.approx(truth.dead_zone, rel=0.02)
    assert np.all(np.isfinite(cal.sampler_.get_log_prob()))


def test_nelder_mead_stops_at_a_tenth_of_each_axis_sd():
    """The start's Nelder-Mead (:func:`tvcid.discovery.calibration.optimum._nelder_mead`) on a Gaussian
    log posterior whose axes' sds span five decades (a pinned DC gain beside a free resonance),
    from a point 2 sd off on every axis with a first simplex of one sd per axis: it ends within
    0.1 nats of the maximum (measured: 0.002) after 95 evaluations, where the same search
    stopped by one tolerance in internal coordinates (1e-6) takes 405 to gain those 0.002 nats
    (on a simulated likelihood, whose small-scale roughness a 1e-6 simplex resolves, it runs to
    its cap)."""
    from scipy.optimize import minimize

    from tvcid.discovery.calibration.optimum import _nelder_mead

    sd = np.array([1e-5, 1e-3, 0.1, 1.0, 3.0])
    rng = np.random.default_rng(8)
    q, _ = np.linalg.qr(rng.standard_normal((5, 5)))
    corr = q @ np.diag([0.3, 0.6, 1.0, 1.4, 1.7]) @ q.T
    d = np.sqrt(np.diag(corr))
    cov = (corr / np.outer(d, d)) * np.outer(sd, sd)
    prec = np.linalg.inv(cov)
    mode = np.array([0.5, -2.0, 1.0, 3.0, 0.0])
    calls = {"n": 0}

    def lp(z):
        calls["n"] += 1
        r = np.asarray(z, dtype=float) - mode
        return float(-0.5 * r @ prec @ r)

    start = mode + 2.0 * sd
    simplex = np.vstack([start, start + np.diag(sd)])
    cap = 150 * len(sd)
    end = _nelder_mead(lp, simplex, cap)
    scaled = calls["n"]
    assert lp(end) > -0.1, lp(end)
    absolute = minimize(lambda z: -lp(z), start, method="Nelder-Mead",
                        options={"maxfev": cap, "xatol": 1e-6, "fatol": 0.05,
                                 "initial_simplex": simplex})
    assert scaled < cap / 5 and absolute.nfev > 3 * scaled, (scaled, absolute.nfev)


class _Box:
    """A log posterior on a box for the optimisers: ``value(z)`` vectorised over rows, its
    evaluations counted."""

    def __init__(self, value, ndim, half_width=20.0):
        from types import SimpleNamespace

        self.value = value
        self.priors = [SimpleNamespace(internal_bounds=(-half_width, half_width))] * ndim
        self.evaluations = 0

    def __call__(self, z):
        one = np.ndim(z) == 1
        z = np.atleast_2d(z)
        self.evaluations += len(z)
        v = self.value(z)
        return float(v[0]) if one else v


@pytest.mark.parametrize("roughness", [0.0, 0.1])
def test_quasi_newton_reaches_the_maximum_in_a_fraction_of_nelder_meads_evaluations(roughness):
    """The members' start (:func:`tvcid.discovery.calibration.optimum._quasi_newton`) on 8-d
    correlated Gaussians (condition numbers of tens to hundreds), from 3 sd off on every axis,
    over 6 seeds: it ends within 0.1 nats of the maximum after 218 evaluations (one Hessian, 129,
    and five gradients with their trial points), Nelder-Mead after 444-771. With a roughness of
    0.1 nats at a twentieth of an sd added (a cycle's features are rough at fine scales) it ends
    within 2.5 nats of the smooth maximum after at most 362 (its 12 iterations), where
    Nelder-Mead stops further below on every seed (measured: 1.3 to 18 nats below it)."""
    from tvcid.discovery.calibration.optimum import (
        _axis_scales,
        _nelder_mead,
        _quasi_newton,
        _simplex,
    )

    d = 8
    for seed in range(6):
        rng = np.random.default_rng(seed)
        a = rng.standard_normal((d, d))
        cov = a @ a.T / d + 0.02 * np.eye(d)
        prec, mode = np.linalg.inv(cov), rng.standard_normal(d)
        sd = np.sqrt(np.diag(cov))

        def value(z):
            r = z - mode
            rough = roughness * np.sum(np.sin(20.0 * z / sd), axis=1)
            return -0.5 * np.einsum("ij,jk,ik->i", r, prec, r) + rough

        start = mode + 3.0 * sd * rng.choice([-1.0, 1.0], d)
        lp = _Box(value, d)
        scale = _axis_scales(lp, start)
        lp.evaluations = 0
        end = _quasi_newton(lp, start, scale)
        smooth = float(-0.5 * (end - mode) @ prec @ (end - mode))
        nm = _Box(value, d)
        end_nm = _nelder_mead(nm, _simplex(start, nm), 150 * d)
        nm_smooth = float(-0.5 * (end_nm - mode) @ prec @ (end_nm - mode))
        assert smooth > (-2.5 if roughness else -0.1), (seed, smooth)
        assert lp.evaluations <= (362 if roughness else 220), (seed, lp.evaluations)
        assert nm.evaluations > 2 * lp.evaluations or roughness, (seed, nm.evaluations)
        if roughness:
            assert smooth > nm_smooth, (seed, smooth, nm_smooth)


def test_an_unknown_start_optimizer_is_refused():
    from tvcid.models.recording import load_recording

    with pytest.raises(ValueError, match="start_optimizer must be one of"):
        Calibration("M000", params=("dead_zone",), start_optimizer="newton").fit(
            [load_recording("data/m000_closed_A.csv")])


@pytest.mark.parametrize("restarts", [0, 1, 3])
def test_the_polish_restarts_at_most_as_often_as_it_is_allowed(restarts, monkeypatch):
    """A misfit that never goes (a wrong model's factor stays over 1) on a curved valley where
    every restart along the principal axes still gains: the polish restarts exactly
    ``polish_restarts`` times, each from the last one's better point, and 0 keeps the start."""
    from types import SimpleNamespace

    import tvcid.discovery.calibration.start as start_module
    from tvcid.discovery.calibration.start import StartSearch

    hessians = []
    real = start_module._hessian
    monkeypatch.setattr(start_module, "_hessian",
                        lambda *a, **k: hessians.append(1) or real(*a, **k))
    monkeypatch.setattr(start_module, "_profile_sigma", lambda lp, z, names: z)

    def value(z):  # a banana: an axis-aligned simplex creeps along it
        return -0.5 * (z[:, 0] ** 2 / 1e3 + 25.0 * (z[:, 1] - 0.05 * z[:, 0] ** 2) ** 2)

    lp = _Box(value, 2, half_width=500.0)
    search = StartSearch()
    search.polish_restarts, search.start_optimizer, search.names_ = restarts, "nelder-mead", ()
    search._inflations_at = lambda lp, z: [2.0]
    search.terms_ = [SimpleNamespace()]
    z0 = np.array([-60.0, 180.0])
    end, factors = search._polish(lp, z0)
    assert len(hessians) == restarts and factors == [2.0]
    assert (lp(end) > lp(z0) + 0.1) if restarts else np.array_equal(end, z0)


@pytest.mark.parametrize("option, value, message", [
    ("polish_restarts", -1, r"^polish_restarts must be an integer >= 0 \(got -1\)$"),
    ("polish_restarts", 1.5, r"^polish_restarts must be an integer >= 0 \(got 1\.5\)$"),
    ("importance_rounds", 0, r"^importance_rounds must be an integer >= 1 \(got 0\)$"),
    ("importance_rounds", "2", r"^importance_rounds must be an integer >= 1 \(got '2'\)$"),
])
def test_a_bad_limit_of_the_start_or_the_importance_rounds_is_refused(option, value, message):
    from tvcid.models.recording import load_recording

    with pytest.raises(ValueError, match=message):
        Calibration("M000", params=("dead_zone",), **{option: value}).fit(
            [load_recording("data/m000_closed_A.csv")])
