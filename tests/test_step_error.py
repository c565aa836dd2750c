"""tvcid.discovery.calibration.step_error: the widening rule, the tilt that moves a posterior, and the
step error measured on real calibrations (a quantity pinned tighter than the step resolves is
widened; one far wider than it is left as it is; the measured move agrees with the difference of
the two steps' optima)."""
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from tvcid.discovery.calibration import Calibration
from tvcid.discovery.calibration.likelihood.solver import SOLVER_ERROR_FACTOR
from tvcid.discovery.calibration.runner import ConvergenceWarning
from tvcid.discovery.calibration.step_error import (
    halved_log_posterior,
    log_evidence_ratio,
    measure_step_error,
    tilt_shift,
    StepError,
)
from tvcid.discovery.calibration.widening import widen_draws, widen_interval, widen_quantiles
from tvcid.models import M000, OpenLoop, hypothesis, simulate
from tvcid.models.recording import recording_from_trajectory, save_recording

DATA = Path(__file__).resolve().parents[1] / "data"


# -- (a) the rule, on numbers --------------------------------------------------------------------
def test_an_interval_narrower_than_twice_the_step_error_is_widened_to_the_median_plus_or_minus_it():
    low, high, widened = widen_interval(0.93480, 0.93482, 0.93485, 1e-4)
    assert widened and low == pytest.approx(0.93472) and high == pytest.approx(0.93492)
    # one side already beyond the error keeps its end, the other is widened
    low, high, widened = widen_interval(0.9, 1.0, 1.00001, 0.06)
    assert widened and low == 0.9 and high == pytest.approx(1.06)


def test_an_interval_at_least_twice_the_step_error_wide_is_kept():
    assert widen_interval(1.0, 1.5, 2.0, 0.25) == (1.0, 2.0, False)  # exactly 2 e wide
    assert widen_interval(1.0, 1.1, 2.0, 0.01) == (1.0, 2.0, False)
    assert widen_interval(1.0, 1.1, 1.2, 0.0) == (1.0, 1.2, False)
    # not measured: nothing changes
    assert widen_interval(1.0, 1.1, 1.2, None) == (1.0, 1.2, False)
    assert widen_interval(1.0, 1.1, 1.2, math.nan) == (1.0, 1.2, False)
    with pytest.raises(ValueError, match="size"):
        widen_interval(1.0, 1.1, 1.2, -1.0)


def test_a_table_of_quantities_is_widened_entry_by_entry_and_keeps_the_sampled_ends():
    table = {"dc_gain": {"q05": 0.93480, "q50": 0.93482, "q95": 0.93485, "unit": "rad/rad"},
             "delay": {"q05": 1.6e-3, "q50": 1.7e-3, "q95": 1.8e-3},
             "backlash": {"q05": 1e-4, "q50": 1.1e-4, "q95": 1.2e-4}}
    out = widen_quantiles(table, {"dc_gain": 1e-4, "delay": 1e-6})
    dc = out["dc_gain"]
    assert dc["widened"] and dc["step_error"] == 1e-4 and dc["unit"] == "rad/rad"
    assert (dc["q05_sampled"], dc["q95_sampled"]) == (0.93480, 0.93485)
    assert dc["q05"] == pytest.approx(0.93472) and dc["q95"] == pytest.approx(0.93492)
    assert not out["delay"]["widened"] and out["delay"]["q05"] == 1.6e-3
    assert "widened" not in out["backlash"] and out["backlash"] == table["backlash"]
    assert table["dc_gain"]["q05"] == 0.93480  # the input is left as it is
    # a delay's widened interval stops at its prior's floor
    floored = widen_quantiles(table, {"delay": 5e-3}, {"delay": (6e-4, 0.05)})["delay"]
    assert floored["widened"] and floored["q05"] == 6e-4 and floored["q95"] == pytest.approx(6.7e-3)


def test_a_widened_interval_stops_at_the_quantity_s_support_never_inside_its_sampled_ends():
    """A dead zone of 2e-3 with a step error of 1e-2 widens to [0, 1.2e-2], not to a negative
    dead zone; a ceiling stops the upper end; a bound inside the sampled interval (draws a little
    beyond a prior draw's range) leaves the sampled end where it is."""
    assert widen_interval(1e-3, 2e-3, 3e-3, 1e-2, (0.0, None)) == (0.0, pytest.approx(1.2e-2), True)
    low, high, widened = widen_interval(1e-3, 2e-3, 3e-3, 1e-2, (0.0, 5e-3))
    assert widened and (low, high) == (0.0, 5e-3)
    assert widen_interval(1e-3, 2e-3, 3e-3, 1e-2, (1.5e-3, 2.5e-3)) == (1e-3, 3e-3, False)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_widened_draws_have_the_widened_interval_s_ends_and_stay_in_the_support(seed):
    """Skewed draws (lognormal, drawn by a seeded generator) narrower than twice a step error:
    after :func:`widen_draws` their 5 % and 95 % quantiles are :func:`widen_interval`'s ends,
    the median stays (to the interpolation between the two middle draws), and no draw leaves the support; draws wide enough come back as
    they were; draws without spread are spread over the widened interval."""
    rng = np.random.default_rng(seed)
    values = 0.02 * np.exp(0.05 * rng.standard_normal(5000))
    q05, q50, q95 = np.quantile(values, (0.05, 0.5, 0.95))
    error = float(rng.uniform(0.003, 0.03))  # up to beyond the median itself
    out, widened = widen_draws(values, error, (0.0, None))
    low, high, _ = widen_interval(q05, q50, q95, error, (0.0, None))
    assert widened
    assert np.quantile(out, (0.05, 0.95)) == pytest.approx([low, high], rel=1e-6, abs=1e-12)
    assert np.median(out) == pytest.approx(q50, rel=1e-3) and out.min() >= 0.0
    same, again = widen_draws(values, 0.1 * (q95 - q05))
    assert not again and np.array_equal(same, values)
    flat, spread = widen_draws(np.full(1000, 0.5), 0.01)
    assert spread and np.quantile(flat, (0.05, 0.95)) == pytest.approx([0.49, 0.51], abs=2e-4)


def test_the_evidences_ratio_is_the_mean_of_the_likelihoods_ratio_over_the_posterior():
    """Draws of a standard normal posterior and a half-step change ``D = c + a z``: the
    evidences' ratio is ``E[exp(D)] = exp(c + a^2 / 2)``, inside three standard errors over 20
    seeds for a change of a tenth of the width and of the whole width; a constant change is
    returned exactly, with no error; fewer than two finite changes are an error."""
    for a in (0.1, 1.0):
        for seed in range(20):
            z = np.random.default_rng(seed).standard_normal(400)
            ratio, se = log_evidence_ratio(2.0 + a * z)
            assert abs(ratio - (2.0 + a * a / 2)) < 4 * se, (a, seed, ratio, se)
    assert log_evidence_ratio(np.full(10, -1.5)) == (pytest.approx(-1.5), 0.0)
    with pytest.raises(ValueError, match="at least 2 finite"):
        log_evidence_ratio([0.0, np.nan])


def test_a_member_is_not_resolved_only_where_the_residual_exceeds_its_spread_beyond_noise():
    """64 points, 8 parameters (55 residual degrees of freedom, the residual sd known to 10 %):
    a residual 10 % above the posterior's own log-density spread is within that noise and the
    member is resolved; 8 times above (a closed-loop cycle the step resolves at some draws and
    not at others) is not; unmeasured is resolved."""
    params = {f"p{i}": {"shift": 0.0, "se": 0.0, "error": 0.0} for i in range(8)}
    at = lambda r: StepError(params, n_points=64, residual_sd=r, log_prob_sd=2.0)  # noqa: E731
    assert at(2.2).resolved and at(1.0).resolved
    assert not at(2.0 * 1.25).resolved and not at(15.7).resolved
    assert StepError(params).resolved and at(15.7).to_dict()["resolved"] is False


# -- the tilt ------------------------------------------------------------------------------------
def test_a_linear_tilt_moves_a_gaussian_by_covariance_times_slope_even_beyond_its_width():
    """A correlated 3-d Gaussian, its log density changed by ``g . z`` plus 0.3 nats of
    roughness: the move is ``C g``, here 8 sd along the first axis, where importance weights
    keep under 1 % of the points; without roughness it is exact."""
    rng = np.random.default_rng(1)
    a = rng.standard_normal((3, 3))
    cov = a @ a.T + 0.5 * np.eye(3)
    draws = rng.multivariate_normal([1.0, -2.0, 0.5], cov, size=4000)
    g = np.linalg.solve(cov, np.array([8.0 * math.sqrt(cov[0, 0]), 0.0, 0.0]))
    points = draws[:40]
    smooth = points @ g + 3.0
    shift, _, residual_sd = tilt_shift(draws, points, smooth)
    np.testing.assert_allclose(shift, np.cov(draws, rowvar=False) @ g, rtol=1e-9)
    assert residual_sd < 1e-9
    rough = smooth + 0.3 * rng.standard_normal(points.shape[0])
    shift, shift_cov, residual_sd = tilt_shift(draws, points, rough)
    sampled = np.cov(draws, rowvar=False) @ g  # the draws' own covariance
    assert np.all(np.abs(shift - sampled) < 4 * np.sqrt(np.diag(shift_cov)))
    assert np.linalg.norm(shift - cov @ g) < 0.05 * np.linalg.norm(cov @ g)
    assert residual_sd == pytest.approx(0.3, rel=0.35)
    w = np.exp(rough - rough.max())
    assert w.sum() ** 2 / (w @ w) < 0.1 * points.shape[0]
    with pytest.raises(ValueError, match="coefficients"):
        tilt_shift(draws, points[:4], smooth[:4])


# -- (b) real calibrations -----------------------------------------------------------------------
def _calibrate(recordings, params, base=None, likelihood="waveform", steps=40, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return Calibration(base or M000(), params=params, likelihood=likelihood, n_walkers=8,
                           max_steps=steps, stop_when_converged=False, seed=1,
                           global_search=False, **kwargs).fit(recordings)


def _optimum(lp, z0, scale):
    """The maximum of ``lp`` near ``z0`` (internal coordinates): Nelder-Mead restarted twice."""
    from scipy.optimize import minimize

    for _ in range(3):
        res = minimize(lambda z: -float(np.ravel(lp(z[None, :]))[0]), z0, method="Nelder-Mead",
                       options={"initial_simplex": np.vstack([z0, z0 + np.diag(scale)]),
                                "xatol": 1e-4 * scale.min(), "fatol": 1e-5, "maxfev": 600})
        z0 = res.x
    return z0


def _optima_shift(cal):
    """The move of the maximum a posteriori from the calibration's step to half of it
    (natural units)."""
    post = cal.posterior_
    lp, half = cal.log_posterior_, halved_log_posterior(cal)
    scale = post.internal.std(axis=0)
    full = _optimum(lp, post.internal[np.argmax(post.log_prob)], scale)
    return lp.natural(_optimum(half, full, scale))[0] - lp.natural(full)[0]


def test_the_half_step_likelihood_is_the_calibrations_own_built_at_half_the_step():
    """On M000's bundled open-loop sine (5e-4 s, not refined): the half-step log posterior is
    the one a calibration given half the step builds (same priors, its step checked at the same
    maximum), value for value, while it differs from the full step's by about a nat across the
    posterior."""
    rec = DATA / "m000_open_sine.csv"
    cal = _calibrate([rec], ("feedback_gain", "delay"))
    post = cal.posterior_
    half = halved_log_posterior(cal)
    own = Calibration(M000(), params=post.names, likelihood="waveform", dt=cal.dt_ / 2,
                      n_walkers=8, priors=dict(cal.priors_), start=cal.map_start_).setup([rec])
    own._refine_steps_at(cal.map_start_, save=False)
    assert [t.simulator.dt for t in half.terms] == [t.simulator.dt for t in own.terms_] == [2.5e-4]
    z = post.internal[np.random.default_rng(0).choice(len(post.internal), 16, replace=False)]
    lh = half(z)
    np.testing.assert_allclose(lh, own.log_posterior_(z), rtol=0, atol=1e-9)
    assert np.std(lh - cal.log_posterior_(z)) > 0.1


@pytest.fixture(scope="module")
def quiet_square(tmp_path_factory):
    """M000's open-loop square (+-20 mrad at 1 Hz, 4 s) recorded with 2e-7 rad of noise, a
    hundredth of the bundled records': its step stays at the refinement's cap (1/8 of 5e-4 s)
    and the feedback gain is pinned to about 1e-6."""
    truth = hypothesis("M000", noise_seed=4, noise_power=4e-17, noise_band=500.0)
    run = simulate(truth, OpenLoop.square(2e-2, 1.0), 4.0, rate=1000.0)
    path = save_recording(tmp_path_factory.mktemp("quiet") / "square.csv",
                          *recording_from_trajectory(run))
    return path, truth.replace(noise_power=0.0)


def test_a_gain_pinned_tighter_than_the_step_resolves_is_widened_to_its_step_error(quiet_square):
    """Feedback gain and delay on the quiet square (no discrepancy factor, so the interval is the
    data's alone): the feedback gain's and the DC gain's 90 % intervals are about 1e-6 wide, a
    tenth of what halving the step moves them by, and are widened; the DC gain's error is the
    feedback gain's through ``1/K``. The move lies within a factor 2 of the difference of the two
    steps' maxima (here the tilt extrapolates beyond the posterior's width: the importance
    weights keep a few per cent of the points). The calibration itself is left as it was, and
    the cost is the points' evaluations at half the step plus the set-up's few runs."""
    path, base = quiet_square
    cal = _calibrate([path], ("feedback_gain", "delay"), base=base, discrepancy=False)
    post = cal.posterior_
    lp, point = cal.log_posterior_, post.internal[:1]
    before, steps = lp(point), [t.simulator.dt for t in cal.terms_]
    error = measure_step_error(post, seed=0)
    assert lp(point) == pytest.approx(before, abs=1e-9)
    assert [t.simulator.dt for t in cal.terms_] == steps
    assert error.steps == {"square": [steps[0], steps[0] / 2]}
    assert error.n_points == 32 and error.n_failed == 0
    # the half step moves this posterior; it does not reorder its draws
    assert error.resolved and error.residual_sd < error.log_prob_sd

    k = post.names.index("feedback_gain")
    fb = error.parameters["feedback_gain"]
    assert math.isfinite(fb["error"]) and fb["error"] > 0
    assert fb["error"] == SOLVER_ERROR_FACTOR * (abs(fb["shift"]) + fb["se"])
    assert fb["se"] < 0.2 * abs(fb["shift"])
    q05, q50, q95 = np.quantile(post.samples[:, k], (0.05, 0.5, 0.95))
    assert q95 - q05 < 0.5 * fb["error"]
    low, high, widened = widen_interval(q05, q50, q95, fb["error"])
    assert widened and high - low == pytest.approx(2 * fb["error"])
    dc = error.quantities["dc_gain"]
    assert dc["error"] == pytest.approx(fb["error"] / q50**2, rel=0.05)
    assert math.isfinite(error.error("bandwidth")) and error.error("bandwidth") > 0
    gains = 1 / post.samples[:, k]
    assert widen_interval(*np.quantile(gains, (0.05, 0.5, 0.95)), error.error("dc_gain"))[2]

    optima = _optima_shift(cal)
    assert 0.5 < fb["shift"] / optima[k] < 2.0, (fb["shift"], optima[k])

    assert math.isfinite(error.log_evidence_shift) and error.log_evidence_shift_se >= 0
    assert error.to_dict()["log_evidence_shift"] == error.log_evidence_shift

    per_point = sum(t.simulator.t_end for t in cal.terms_)
    assert 32 * per_point <= error.simulated_seconds <= (32 + 12) * per_point
    assert error.simulated_steps >= 2 * 32 * sum(t.simulator.t_end / t.simulator.dt
                                                 for t in cal.terms_)


@pytest.mark.slow
def test_the_step_error_matches_the_move_of_the_maximum_on_the_bundled_square():
    """M000's bundled open-loop square at its own step (1e-4 s, noise 2e-5 rad): the feedback
    gain's and the delay's moves when the step is halved agree with the moves of the maximum a
    posteriori within 25 %, two seeds' subsamples with each other within 10 %; the intervals are
    2-6 times twice the step error and are kept. (Slow: the quiet square's test above checks the
    move against the maxima' in the default suite, within a factor 2.)"""
    cal = _calibrate([DATA / "m000_open_square.csv"], ("feedback_gain", "delay"))
    post = cal.posterior_
    a, b = measure_step_error(post, seed=0), measure_step_error(post, seed=1, quantities=False)
    optima = _optima_shift(cal)
    for j, name in enumerate(post.names):
        shift = a.parameters[name]["shift"]
        assert shift == pytest.approx(optima[j], rel=0.25), name
        assert shift == pytest.approx(b.parameters[name]["shift"], rel=0.1), name
        q05, q50, q95 = np.quantile(post.samples[:, j], (0.05, 0.5, 0.95))
        assert q95 - q05 > 2 * a.parameters[name]["error"]
        assert widen_interval(q05, q50, q95, a.parameters[name]["error"]) == (q05, q95, False)


def test_an_interval_far_wider_than_the_step_error_is_left_as_it_is():
    """Delay and dead zone on one bundled limit cycle (features, its first-order solver error
    corrected): the intervals are over fifty times what halving the step moves them by (measured
    92 times for the dead zone, 290 for the delay), and the table keeps every end. The combined quantities follow the sampled ones (the
    threshold moves with the dead zone) and those of fixed fields do not move."""
    cal = _calibrate([DATA / "m000_closed_A.csv"], ("delay", "dead_zone"), likelihood="features")
    post = cal.posterior_
    error = measure_step_error(post, seed=0)
    summary = post.summary()["parameters"]
    out = widen_quantiles(summary, error.errors)
    for name in post.names:
        e = error.parameters[name]["error"]
        assert math.isfinite(e) and e > 0
        width = summary[name]["q95"] - summary[name]["q05"]
        assert width > 50 * e, (name, width, e)
        assert not out[name]["widened"]
        assert (out[name]["q05"], out[name]["q95"]) == (summary[name]["q05"], summary[name]["q95"])
    combined = error.quantities
    assert {"dead_zone[velocity]", "threshold", "delay", "dc_gain", "bandwidth"} <= set(combined)
    assert combined["threshold"]["shift"] == pytest.approx(error.parameters["dead_zone"]["shift"])
    assert combined["dc_gain"]["error"] == combined["bandwidth"]["error"] == 0.0
