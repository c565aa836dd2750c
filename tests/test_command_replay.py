"""A command known only as samples, its edge timing integrated out (else the replay error itself
becomes a mismatch).

Cases: the coverage benchmark's draw 3 (seed 2003), a square of 0.313 Hz sampled at 1 kHz from
t = 0, every edge 1596 samples after the previous one while the true half period is 1595.81
samples (a hold replay drifts 0.9 ms late by the fifth edge); and 200 Hz sampling, where every
edge is known only to 5 ms, the size of the delay.
"""
import json
from pathlib import Path

import numpy as np
import pytest

from tvcid.discovery.calibration.likelihood import make_term
from tvcid.models import M002, OpenLoop
from tvcid.models.commands import command_from_samples
from tvcid.models.edge_timing import EdgeTiming
from tvcid.models.recording import load_recording
from tvcid.models.simulate import simulate_batch
from tvcid.models.synthetic import synthetic_recording

FREQUENCY = 0.31331990500313334
NOISE = 2.5e-5


def _true_theta(timing, true_edges):
    a = np.stack([np.ones_like(timing.index), timing.index], axis=1)[:, : timing.dim]
    return np.linalg.lstsq(a, true_edges - timing.centre, rcond=None)[0]


@pytest.mark.parametrize("rate", [1000.0, 200.0])
def test_the_true_timing_is_feasible_and_the_hold_is_not_the_truth(rate):
    t = np.arange(0, 9.0, 1.0 / rate)
    u = OpenLoop.square(0.02, FREQUENCY).command(t)
    true_edges = np.arange(1, 6) / (2 * FREQUENCY)
    timing = EdgeTiming(t, u, 5e-4)
    assert timing.dim == 2
    theta = _true_theta(timing, true_edges)
    assert timing.feasible(theta)
    assert np.allclose(timing.centre + theta[0] + timing.index * theta[1], true_edges, atol=1e-9)
    hold = command_from_samples(t, u).t_samples
    assert np.max(np.abs(hold - true_edges)) > 0.8 / rate  # any single replay is off by ~a sample
    # the simulated edges sit on the solver's grid (an off-grid edge costs RK4 its order)
    assert np.allclose(timing.grid / 5e-4, np.round(timing.grid / 5e-4), atol=1e-9)


def test_a_step_has_one_timing_coordinate_and_smooth_commands_none():
    t = np.arange(0, 4.0, 5e-3)
    timing = EdgeTiming(t, np.where(t > 1.0, 0.01, 0.0), 5e-4)
    assert timing.dim == 1
    assert timing.log_area == pytest.approx(np.log(5e-3), abs=1e-6)
    with pytest.raises(ValueError, match="not piecewise constant"):
        EdgeTiming(t, 0.01 * np.sin(2 * np.pi * t), 5e-4)


def test_laplace_volume_matches_the_numeric_integral_over_a_step_timing():
    """The log of the timing's integral (1-D: a step at 200 Hz) against a fine quadrature."""
    rate, dt = 200.0, 5e-4
    t = np.arange(0, 2.0, 1.0 / rate)
    true_edge = 0.5023  # between samples
    u = np.where(t >= true_edge, 0.01, 0.0)
    timing = EdgeTiming(t, u, dt)
    truth = M002()
    run = simulate_batch([truth], [OpenLoop.piecewise(np.array([true_edge]), np.array([0.0, 0.01]))],
                         2.0, dt=1e-5, rate=None)
    data = np.interp(t, run.t, run.signal("delta")[0])
    data = data + NOISE * np.random.default_rng(1).standard_normal(t.size)
    sim = simulate_batch([truth], [timing.experiment], 2.0, dt=dt, rate=None)
    ts, ys = sim.t, sim.signal("delta")[0]
    var = np.full(t.size, NOISE**2)
    res, log_volume, theta = timing.marginal(t, data, ts, ys, var)
    ll_star = -0.5 * np.sum(res**2 / var)
    grid = np.linspace(timing._vertices[0, 0], timing._vertices[1, 0], 4001)
    ll = []
    for g in grid:
        y, _ = timing.shifted(np.array([g]), t, ts, ys)
        r = data - y
        r = r - r.mean()
        ll.append(-0.5 * np.sum(r**2 / var))
    ll = np.array(ll)
    weight = np.exp(ll - ll_star)
    numeric = np.log(np.trapezoid(weight, grid)) - timing.log_area
    mean = np.trapezoid(weight * grid, grid) / np.trapezoid(weight, grid)
    sd = np.sqrt(np.trapezoid(weight * (grid - mean) ** 2, grid) / np.trapezoid(weight, grid))
    assert theta[0] == pytest.approx(grid[np.argmax(ll)], abs=0.1 * sd)  # the needle's top found
    assert abs(timing.centre[0] + theta[0] - true_edge) < 3 * sd  # and the truth under it
    assert log_volume == pytest.approx(numeric, abs=0.15)
    assert log_volume < -1.0  # the response times the edge far better than the samples do


def _square_as_samples(path, seed, rate=1000.0):
    """M002 driven by the square, recorded measured-style: the command only as samples."""
    synthetic_recording(M002(), OpenLoop.square(0.01, FREQUENCY), 9.0, NOISE, seed, path, dt=2e-4,
                        rate=rate)
    sidecar = path.with_suffix(".json")
    meta = json.loads(sidecar.read_text())
    for key in ("waveform", "amplitude", "frequency", "start", "offset", "from_rest",
                "hypothesis", "parameters"):
        meta.pop(key, None)
    sidecar.write_text(json.dumps(meta))
    return load_recording(path)


@pytest.mark.parametrize("rate", [1000.0, 200.0])
def test_the_truth_fits_to_the_noise_and_the_likelihood_is_smooth_in_the_delay(tmp_path, rate):
    """At the truth the residuals at the most probable timing are the sensor's noise; the
    likelihood is continuous in the delay across half-step multiples of the solver (the delay
    line read the first sample only from the first stage after Td: jumps of 5-12 nats there)
    and peaks within its own width of the truth."""
    truth = M002()
    rec = _square_as_samples(tmp_path / "square.csv", 3, rate)
    term = make_term(rec, "waveform", 10.0, 6.0, 5e-4)
    term.setup(truth)
    assert term.timing is not None
    res = term.residuals([truth])[0]
    assert float(np.sqrt(np.mean(res**2))) == pytest.approx(NOISE, rel=0.1)
    delays = truth.delay + np.linspace(-100e-6, 100e-6, 41)  # crosses 7.0 ms = 14 half steps
    ll = term.loglike([truth.replace(delay=float(d)) for d in delays], np.full(delays.size, NOISE))
    assert np.all(np.isfinite(ll))
    assert np.max(np.abs(np.diff(ll, 2))) < 2.0  # no jumps: second differences stay small
    peak = delays[int(np.argmax(ll))]
    curvature = -np.polyfit(delays - truth.delay, ll, 2)[0] * 2
    sd = 1.0 / np.sqrt(curvature)
    assert abs(peak - truth.delay) < 3 * sd + 5e-6


@pytest.mark.parametrize("rate, noise, refined", [(1000.0, 1.3e-5, True), (200.0, 1e-4, False)])
def test_open_loop_step_refined_until_its_error_is_under_the_noise(tmp_path, monkeypatch, rate, noise,
                                                                   refined):
    """RK4 converges at first order near a square's edges; under low noise at 1 kHz the 5e-4 s
    step's error, one-signed over thousands of samples, outweighed the noise (coverage draw 10's
    truth, band-pass loop and backlash: dead zone and backlash 5 % and 58 % off). The term halves
    its step (at most 8x) until the step-doubling change adds at most ``SOLVER_LOAD_LIMIT`` to the
    chi-square: the truth's log-likelihood then lies within 15 nats of a term started 8x finer
    (measured 11.9), against 363 at 5e-4 s. A record with 1e-4 rad of noise at 200 Hz keeps the
    5e-4 s step."""
    from tvcid.discovery.calibration.likelihood import solver as likelihood
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    truth = coverage_scenario(10, Config()).truth
    path = tmp_path / "square.csv"
    synthetic_recording(truth, OpenLoop.square(0.026, 0.3766), 9.0, noise, 11, path, dt=2.5e-5,
                        rate=rate)
    meta = json.loads(path.with_suffix(".json").read_text())
    for key in ("waveform", "amplitude", "frequency", "start", "offset", "from_rest",
                "hypothesis", "parameters"):
        meta.pop(key, None)
    path.with_suffix(".json").write_text(json.dumps(meta))
    rec = load_recording(path)
    term = make_term(rec, "waveform", None, 0.0, 5e-4).setup(truth)
    assert (term.sim_dt < 5e-4) == refined, (term.sim_dt, term.solver_load)
    if not refined:
        assert term.solver_load <= likelihood.SOLVER_LOAD_LIMIT
        return
    sig = np.array([term.sigma_hat])
    fine = make_term(rec, "waveform", None, 0.0, 5e-4 / likelihood.MAX_STEP_REFINEMENT).setup(truth)
    monkeypatch.setattr(likelihood, "MAX_STEP_REFINEMENT", 1)
    coarse = make_term(rec, "waveform", None, 0.0, 5e-4).setup(truth)
    ll = {k: float(t.loglike([truth], sig)[0]) for k, t in
          (("refined", term), ("fine", fine), ("coarse", coarse))}
    assert abs(ll["refined"] - ll["fine"]) < 15.0, ll
    assert abs(ll["coarse"] - ll["fine"]) > 10 * abs(ll["refined"] - ll["fine"]), ll


def test_closed_loop_waveform_keeps_the_coarse_step_once_the_friction_jump_is_located(tmp_path):
    """The ridge case's truth (``ridge_scenario(0)``: friction offset at the dead zone, limit cycles
    at controllers A and B, 1e-4 rad noise). While RK4 sampled the friction offset's jump at its
    stages, the cycle at B locked to the 5e-4 s grid, added 37 to the chi-square and sat 16 nats
    from a term 8x finer (a phase error the delay absorbed: the posterior beat the truth by 21
    nats). With the jump located inside the step (``tvcid.models.nonlinearities.sign_switch_average``)
    both cycles keep 5e-4 s with a load under 1 (measured 0.002 and 0.0) and the log-likelihood at
    the truth is within 1 nat of the 8x finer term's (measured 0.06)."""
    from tvcid.discovery.calibration.likelihood import solver as likelihood
    from tvcid.studies.benchmarks.scenarios import ridge_scenario

    scenario = ridge_scenario(0)
    truth = scenario.truth
    assert truth.friction_offset != 0
    for name, design in zip("AB", scenario.recordings):
        path = tmp_path / f"{name}.csv"
        synthetic_recording(truth, design.experiment(), 30.0, 1e-4, 3, path, keep_last=12.0, dt=5e-5)
        term = make_term(load_recording(path), "waveform", 10.0, 20.0, 5e-4).setup(truth)
        assert term.sim_dt == 5e-4 and term.solver_load < 1.0, (name, term.solver_load)
        fine = make_term(term.recording, "waveform", 10.0, 20.0,
                         5e-4 / likelihood.MAX_STEP_REFINEMENT).setup(truth)
        sig = np.array([term.sigma_hat])
        gap = float(term.loglike([truth], sig)[0] - fine.loglike([truth], sig)[0])
        assert abs(gap) < 1.0, (name, gap)


def test_step_check_repeated_at_the_map_refines_and_never_coarsens(tmp_path, monkeypatch):
    """The load moves with the parameters: on coverage draw 10's 1 kHz square (1e-4 rad noise,
    the command known as samples) the
    solver's load at 5e-4 s (the larger of the step-doubling change and the edges' placement
    against a fine simulation) is 53.9 at the truth and 56.0 with the backlash 30 % short. With the limit put between the two, the term set up at the truth keeps
    5e-4 s, ``refine_at`` (what Calibration runs at the maximum a posteriori) halves the step at
    the other point, and a later check where the load is small keeps the finer step."""
    from tvcid.discovery.calibration.likelihood import solver as likelihood
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    truth = coverage_scenario(10, Config()).truth
    other = truth.replace(backlash=0.7 * truth.backlash)
    path = tmp_path / "square.csv"
    synthetic_recording(truth, OpenLoop.square(0.026, 0.3766), 9.0, 1e-4, 11, path, dt=2.5e-5,
                        rate=1000.0)
    meta = json.loads(path.with_suffix(".json").read_text())
    for key in ("waveform", "amplitude", "frequency", "start", "offset", "from_rest",
                "hypothesis", "parameters"):
        meta.pop(key, None)  # measured-style: the command known only as samples
    path.with_suffix(".json").write_text(json.dumps(meta))
    rec = load_recording(path)
    monkeypatch.setattr(likelihood, "MAX_STEP_REFINEMENT", 1)
    load = {k: make_term(rec, "waveform", None, 0.0, 5e-4).setup(p).solver_load
            for k, p in (("truth", truth), ("other", other))}
    assert load["other"] > 1.02 * load["truth"], load
    monkeypatch.setattr(likelihood, "MAX_STEP_REFINEMENT", 8)
    monkeypatch.setattr(likelihood, "SOLVER_LOAD_LIMIT", float(np.sqrt(load["truth"] * load["other"])))
    term = make_term(rec, "waveform", None, 0.0, 5e-4).setup(truth)
    assert term.sim_dt == 5e-4
    assert term.refine_at(other).sim_dt == 2.5e-4
    assert term.refine_at(truth).sim_dt == 2.5e-4


#: Noise-free 4 s responses of coverage draws' squares, made by the reference path
#: (:func:`square_response`, about 20-40 s each) and rebuilt byte for byte by a slow test.
SQUARES = Path(__file__).resolve().parents[1] / "data" / "bench" / "reference_squares"


def square_response(index):
    """Coverage draw ``index``'s first square (default config), noise-free, 4 s from rest by the
    reference path at 5e-5 s, sampled at the design's rate: columns and a measured-style sidecar."""
    from tvcid.models.reference import simulate_reference
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    scenario = coverage_scenario(index, Config())
    design = next(r for r in scenario.recordings if r.waveform == "square")
    ref = simulate_reference(scenario.truth, design.experiment(), 4.0, dt=5e-5, rate=design.rate)
    return ({"t": ref.t - ref.t[0], "u": ref.u, "delta": ref.delta},
            {"kind": "open", "sample_rate": design.rate, "source": "simulated",
             "generator": "tests/test_command_replay.py square_response (reference path)"})


@pytest.mark.slow
@pytest.mark.parametrize("index", [5, 7, 18])
def test_bundled_square_responses_are_rebuilt_byte_for_byte(index, tmp_path):
    from tvcid.models.recording import save_recording

    path = save_recording(tmp_path / f"draw{index:02d}.csv", *square_response(index))
    for p in (path, path.with_suffix(".json")):
        assert p.read_bytes() == (SQUARES / p.name).read_bytes(), p.name


@pytest.mark.parametrize("index, hunts", [(5, True), (7, False), (18, True)])
def test_a_response_that_never_settles_is_simulated_at_its_own_edges(index, hunts):
    """Coverage draw 5's square (band-pass loop, backlash, friction offset): the output hunts on
    every plateau, so the grid's response shifted to other edges is not the response to them
    (noise-free, at the truth, 11 s: rms 5.6e-5 rad for noise 8.9e-5). The term simulates the
    edges where they are, at the most probable timing (4 s: 0.9 ms from the centre, rms 2.9e-5
    when simulated at the centre), and fits to under a tenth of the noise (1.7e-6). Draw 7's
    square settles: shifting the grid's response is then as good as simulating the edges where
    they are (both loads under 0.1; since the stage average of a piecewise command is its exact
    integral, the centre's is the smaller, 0.004 against 0.016, and either way may be taken).
    Draw 18's 2.56 Hz square at 200 Hz (band-pass loop) hunts too, but its centre edges fall on
    the grid, where both ways are one simulation (loads 0.76 each): the way is chosen at the
    record's own timing, 2.4 ms from the centre (grid 249, its own edges 5.7)."""
    from tvcid.discovery.calibration.likelihood import OpenLoopTerm
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    scenario = coverage_scenario(index, Config())
    truth, noise = scenario.truth, scenario.acquisition.noise_sd
    rec = load_recording(SQUARES / f"draw{index:02d}.csv")  # square_response(index)
    term = OpenLoopTerm(rec, None, 0.0, 5e-4)
    term.sigma_hat = noise  # the noise-free record stands for one with the draw's noise
    term.setup(truth, warm_start=False)
    loads = term.edge_loads_  # chi-square against the centre edges simulated 8x finer
    assert (loads["grid_at_timing"] > 10 * loads["centre_at_timing"]) is hunts
    if hunts:
        assert not term.edges_on_grid
    else:
        assert max(loads.values()) < 0.1
    res = term.residuals([truth], [noise])[0]
    assert np.sqrt(np.mean(res**2)) < 0.1 * noise


def _numpy_shift_read(timing, theta, tau, t_sim, y_sim):
    """The edge timing's read of a simulated response, written with numpy.searchsorted and
    numpy.interp (the reference the compiled read is checked against)."""
    edges = timing.centre + theta[0] + (timing.index * theta[1] if timing.dim == 2 else 0.0)
    seg = np.searchsorted(edges, tau, side="right")
    before = seg > 0
    j = np.maximum(seg - 1, 0)
    x = tau - np.where(before, edges[j] - timing.grid[j], 0.0)
    h = t_sim[1] - t_sim[0]
    y = np.interp(x, t_sim, y_sim)
    slope = np.interp(x, 0.5 * (t_sim[1:] + t_sim[:-1]), np.diff(y_sim) / h)
    jac = np.zeros((tau.size, timing.dim))
    jac[:, 0] = np.where(before, -slope, 0.0)
    if timing.dim == 2:
        jac[:, 1] = np.where(before, -slope * timing.index[j], 0.0)
    return y, jac


@pytest.mark.parametrize("rate", [1000.0, 200.0])
def test_compiled_edge_read_and_normal_equations_equal_numpy(rate):
    """The compiled read of the response (one pass over the samples, index arithmetic on the
    solver's grid) equals numpy.searchsorted + numpy.interp, at timings inside the feasible set
    and at samples before the first edge, on grid nodes and past the simulation's end; the
    Gauss-Newton normal equations built from it equal numpy's, with and without the offset
    profiled out (to rounding: 1e-16 s on the grid times slopes up to 1e4 per s)."""
    rng = np.random.default_rng(5)
    t = np.arange(0, 6.0, 1.0 / rate)
    u = OpenLoop.square(0.01, 0.7).command(t + 0.0003)
    timing = EdgeTiming(t, u, 5e-4)
    t_sim = 5e-4 * np.arange(int(5.9 / 5e-4) + 1)  # ends before the last samples
    y_sim = np.cumsum(rng.standard_normal(t_sim.size)) * 1e-3
    tau = np.concatenate([t, t_sim[::37]])
    tau.sort()
    data = rng.standard_normal(tau.size) * 1e-3
    var = rng.uniform(0.5, 2.0, tau.size) * 1e-6
    var[::5] = np.inf  # samples left out of a fold
    lo, hi = timing._vertices.min(axis=0), timing._vertices.max(axis=0)
    thetas = [np.zeros(timing.dim), timing._vertices.mean(axis=0)]
    thetas += [lo + rng.uniform(size=timing.dim) * (hi - lo) for _ in range(5)]
    for theta in thetas:
        y, jac = timing.shifted(theta, tau, t_sim, y_sim)
        y_ref, jac_ref = _numpy_shift_read(timing, theta, tau, t_sim, y_sim)
        np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(jac, jac_ref, rtol=0, atol=1e-7)
    from tvcid.models.edge_timing import _normal_equations

    w = 1.0 / var
    for demean in (True, False):
        theta = thetas[-1]
        r = np.empty(tau.size)
        hess, grad = np.empty((timing.dim, timing.dim)), np.empty(timing.dim)
        _normal_equations(timing._edges(theta), timing.grid, timing.index, tau, data, w,
                          t_sim[0], t_sim[1] - t_sim[0], y_sim, demean, r,
                          np.empty((3, tau.size)), hess, grad)
        y_ref, jac_ref = _numpy_shift_read(timing, theta, tau, t_sim, y_sim)
        r_ref = data - y_ref
        if demean:
            r_ref, jac_ref = r_ref - r_ref.mean(), jac_ref - jac_ref.mean(axis=0)
        np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(hess, jac_ref.T @ (jac_ref * w[:, None]), rtol=1e-9)
        np.testing.assert_allclose(grad, jac_ref.T @ (w * r_ref), rtol=1e-7,
                                   atol=1e-9 * np.abs(jac_ref.T @ np.abs(w * r_ref)).max())


def test_the_step_is_divided_as_far_as_the_record_needs_and_no_further(monkeypatch):
    """The bundled M000 square (1 kHz, noise 2.1e-5 rad): its solver load falls as the step
    squared (184 at 5e-4 s), so the term runs at a fifth of the step (1e-4 s, load 6.7), the
    coarsest whose load is under the limit: at a quarter (1.25e-4 s) it is 10.4, over 10."""
    from tvcid.discovery.calibration.likelihood import solver as likelihood
    from tvcid.models import M000

    rec = load_recording(Path(__file__).resolve().parents[1] / "data" / "m000_open_square.csv")
    term = make_term(rec, "waveform", None, 0.0, 5e-4).setup(M000())
    assert term.sim_dt == pytest.approx(1e-4) and term.solver_load <= likelihood.SOLVER_LOAD_LIMIT
    monkeypatch.setattr(likelihood, "MAX_STEP_REFINEMENT", 1)
    quarter = make_term(rec, "waveform", None, 0.0, 1.25e-4).setup(M000())
    assert quarter.sim_dt == 1.25e-4 and quarter.solver_load > likelihood.SOLVER_LOAD_LIMIT
