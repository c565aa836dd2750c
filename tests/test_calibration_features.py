"""A cycle that is not periodic (M000's band-pass loop): the features likelihood's covariance counts
its wander (and not a periodic M002's), and the waveform likelihood warns."""
import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from tvcid.discovery.calibration.likelihood import FeatureTerm
from tvcid.models import CONTROLLER_A, CONTROLLER_B, M002
from tvcid.models.recording import load_recording
from tvcid.models.synthetic import synthetic_recording

DATA = Path(__file__).resolve().parents[1] / "data"


def test_m000_cycle_wanders_beyond_its_sensor_noise():
    term = FeatureTerm(load_recording(DATA / "m000_closed_A.csv"), 10.0, 6.0, 5e-4)
    freq = term.features.index("frequency")
    wander_sd = np.sqrt(term.wander_var[freq])
    # M000's band-pass loop leaves the 10 s frequency wandering: the estimate is 0.43 % at A, far
    # above what the sensor noise alone spreads it (< 0.01 %)
    assert 1e-3 < wander_sd / term.observed[freq] < 1e-2
    noise_var = term.cov_hat[freq, freq] - 2.0 * term.wander_var[freq]
    assert np.sqrt(noise_var) < 0.1 * wander_sd


@pytest.mark.parametrize("name, controller", [("A", CONTROLLER_A), ("B", CONTROLLER_B)])
def test_m000_wander_estimate_against_the_spread_of_many_windows(name, controller):
    """The wander is estimated from four 2.5 s pieces of the record's one 10 s window. Measured
    independently: the features of 40 disjoint 10 s windows (20-420 s) of the same M000 at the same
    controller with another noise seed (7; the bundled records use 1 and 2). The estimate is
    1.1-3.8x the windows' spread at A and 3.9-7.5x at B (per feature; frequency: 0.43 % vs 0.12 %
    at A, 0.36 % vs 0.06 % at B): conservative, so asserted as between 1x and 8x.
    Every window lies within 2 sd of the record's features under the covariance (largest |z| 1.2),
    which it would not without the wander (the frequency's noise-only sd is < 0.01 %)."""
    from tvcid.models import hypothesis, simulate

    term = FeatureTerm(load_recording(DATA / f"m000_closed_{name}.csv"), 10.0, 6.0, 5e-4)
    meta = load_recording(DATA / f"m000_closed_{name}.csv").meta
    params = hypothesis("M000", noise_seed=7, noise_power=meta["parameters"]["noise_power"],
                        noise_band=meta["parameters"]["noise_band"])
    tr = simulate(params, controller, 420.0, rate=1000.0)
    windows = []
    for start in np.arange(20.0, 420.0, 10.0):
        sel = (tr.t >= start) & (tr.t < start + 10.0)
        windows.append(term._data_features_at(tr.t[sel] - start, tr.delta[sel]))
    windows = np.array(windows)
    ratio = np.sqrt(term.wander_var) / np.std(windows, axis=0, ddof=1)
    assert np.all((ratio >= 1.0) & (ratio <= 8.0)), dict(zip(term.features, ratio.round(2)))
    z = (windows - term.observed) / np.sqrt(np.diag(term.cov_hat))
    assert np.max(np.abs(z)) < 2.0, dict(zip(term.features, np.abs(z).max(axis=0).round(2)))


def test_periodic_m002_cycle_has_no_wander(tmp_path):
    rec = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, 3, tmp_path / "m002.csv", keep_last=10.0)
    term = FeatureTerm(rec, 10.0, 6.0, 5e-4)
    assert np.all(term.wander_var == 0.0)



def test_waveform_likelihood_warns_on_a_cycle_that_is_not_periodic(tmp_path):
    from tvcid.discovery.calibration import Calibration, IllPosedLikelihoodWarning

    m000 = load_recording(DATA / "m000_closed_A.csv")
    with pytest.warns(IllPosedLikelihoodWarning, match="m000_closed_A: the simulated cycle .* not periodic"):
        Calibration("M000", params=("dead_zone",), likelihood="waveform").setup([m000])
    rec = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, 3, tmp_path / "m002.csv", keep_last=10.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", IllPosedLikelihoodWarning)
        cal = Calibration("M002", params=("dead_zone",), likelihood="waveform").setup([rec])
    assert cal.terms_[0].period_mismatch < 0.01 * cal.terms_[0].sigma_hat


def test_periodic_and_wandering_cycles_are_not_taken_as_settling(tmp_path):
    rec = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, 3, tmp_path / "m002.csv", keep_last=10.0)
    term = FeatureTerm(rec, 10.0, 6.0, 5e-4)
    assert np.all(term.settling_var == 0.0) and term.record_start is None
    for name in ("A", "B"):  # M000's band-pass wander has no steady direction
        term = FeatureTerm(load_recording(DATA / f"m000_closed_{name}.csv"), 10.0, 6.0, 5e-4)
        assert np.all(term.settling_var == 0.0), name
        # over the whole record: A's wander is not an approach; B's cycle grows from its kick
        # (H1 4.3, 5.8, 6.6, 6.7, 7.0 e-3 rad over its first five 2.9 s pieces), which is one
        assert (term.record_start is None) == (name == "A"), name


def test_a_cycle_still_settling_leaves_its_settled_features_inside_the_covariance(tmp_path):
    """The coverage benchmark's draw 2 (seed 2002): a truth whose cycle grows for ~100 s, recorded
    from 10 s to 36.5 s after rest. The record's last 10 s sit 7 % under the settled H1 (5 sd of
    the noise-and-wander covariance, which made the right model's features inflation 58x); with
    the settling term the settled features lie within 2 sd of the record's, feature by feature."""
    from tvcid.models import simulate
    from tvcid.models.recording import save_recording
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    scenario = coverage_scenario(2, Config())
    design = scenario.recordings[0]
    assert design.kind == "closed"
    exp = design.experiment()
    tr = simulate(scenario.truth, exp, 180.0, dt=2e-4, rate=1000.0)
    keep = (tr.t >= 10.0) & (tr.t <= 10.0 + design.duration)
    rng = np.random.default_rng(5)
    delta = tr.delta[keep] + 2.5e-5 * rng.standard_normal(int(keep.sum()))
    path = tmp_path / "settling.csv"
    save_recording(path, {"t": tr.t[keep] - 10.0, "u": tr.u[keep], "delta": delta},
                   {"kind": "closed", "kp": exp.kp, "kd": exp.kd, "mu": exp.mu})
    term = FeatureTerm(load_recording(path), 10.0, 6.0, 5e-4)
    h1 = term.features.index("H1")
    assert term.settling_var[h1] > 0.0
    late = tr.t >= 160.0
    settled = term._data_features_at(tr.t[late] - 160.0, tr.delta[late])
    z = (settled - term.observed) / np.sqrt(np.diag(term.cov_hat))
    assert abs(z[h1]) > 0.5  # the record is really off its settled cycle ...
    assert np.max(np.abs(z)) < 2.0, dict(zip(term.features, z.round(2)))  # ... and the sd says so


def test_start_imprint_of_a_slowly_settling_cycle_is_counted(tmp_path):
    """Coverage draw 20's truth (drawn by the shared generator: dead zone on the velocity signal,
    friction offset, delay at the output; its cycle at A settles with a ~5 s time constant), its
    settled cycle recorded at A. Runs start on the cycle of a start 30 % off in the delay: after a
    20 s transient the truth's features still carry that start, and its log-likelihood moves by
    tens of nats between transients of 20 and 60 s. The start imprint measured over a few
    points near the truth must cover that move (under 3 nats once it is in the variance; measured
    1.5), and it must be
    negligible for a run started on its own cycle (periodic M002: the warm start is its own, scaled
    by the record's noisy rms; measured up to 0.06 sd, a 0.4 % wider variance)."""
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    truth = coverage_scenario(20, Config()).truth
    rec = synthetic_recording(truth, CONTROLLER_A, 70.0, 7e-5, 5, tmp_path / "d20.csv", keep_last=10.0,
                              dt=2e-4)
    start = truth.replace(delay=1.3 * truth.delay)
    near = [truth.replace(dead_zone=truth.dead_zone * f, friction_offset=truth.friction_offset
                          - truth.dead_zone * (1 - f)) for f in (0.8, 1.0, 1.25)]

    def loglike(transient, imprint):
        term = FeatureTerm(rec, 10.0, transient, 5e-4).setup(start)
        if imprint:
            term.set_transient_variance(term.transient_variance(near))
        return term, float(term.loglike([truth], np.array([term.sigma_hat]))[0])

    _, short = loglike(20.0, False)
    _, long = loglike(60.0, False)
    assert abs(short - long) > 20.0  # measured: 30 nats (27 at 20 s, 57 at 60 s)
    term, short = loglike(20.0, True)
    _, long = loglike(60.0, True)
    assert np.any(term.transient_var > 0)
    assert abs(short - long) < 3.0

    m002 = synthetic_recording(M002(), CONTROLLER_A, 20.0, 1e-4, 3, tmp_path / "m002.csv", keep_last=10.0)
    own = FeatureTerm(m002, 10.0, 6.0, 5e-4).setup(M002())
    sd = np.sqrt(own.transient_variance([M002()]) / np.diag(own.cov_hat))
    assert np.all(sd < 0.1)


def test_a_period_two_cycle_counts_where_the_window_falls(tmp_path):
    """Set-coverage draw 1001's truth (dead zone on the error, band-pass loop, delay before the
    first integrator) at controller A held at 200 Hz: its periods alternate (0.751 and 0.817 s),
    so a 10 s window's frequency depends on the parity of the periods it holds, tens of noise sd
    apart. The start imprint, compared over several later windows, covers that spread: at the
    truth the discrepancy factor stays under 5 for transients of 6 and 20 s (measured 1.0 and
    3.1; against one next window, 89 and 1.5)."""
    from tvcid.models import ClosedLoop
    from tvcid.models.cycle_reading import cycle_crossings
    from tvcid.studies.benchmarks.scenarios import draw_scenario

    truth = draw_scenario(1001, ranges="papers").truth
    held = ClosedLoop(CONTROLLER_A.kp, CONTROLLER_A.kd, CONTROLLER_A.mu, sample_rate=200.0)
    rec = synthetic_recording(truth, held, 42.6, 2.3e-5, 1, tmp_path / "p2.csv", keep_last=32.6,
                              dt=5e-5)
    periods = np.diff(cycle_crossings(rec.t, rec.delta))
    assert np.all(np.abs(np.diff(periods)) > 0.05)  # the cycle is period-2
    near = [truth.replace(delay=truth.delay * f) for f in (0.99, 1.0, 1.01)]
    for transient in (6.0, 20.0):
        term = FeatureTerm(rec, 10.0, transient, 5e-4, rng=np.random.default_rng(0)).setup(truth)
        term.set_transient_variance(term.transient_variance(near))
        assert term.discrepancy(truth, term.sigma_hat) < 5.0, transient


def test_features_at_the_fit_step_lie_within_a_tenth_sd_of_a_fine_step(tmp_path):
    """Coverage draw 16's truth (dead zone on the velocity signal, friction offset, band-pass loop,
    delay before the first integrator) at its second setting, controller held at 200 Hz and
    sampled at 200 Hz, noise 1.9e-5 rad. The delay line delivers each held jump at its own time,
    so the raw features at 5e-4 s lie within 0.1 sd (of the data's covariance) of a 5e-5 s
    simulation's (measured 0.053 at most); with the Richardson correction, still within 0.6 sd.
    A line that spread each held jump over the step before its node would put H1 3.2 sd below.
    The remaining variance is the change itself, not twice it."""
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    scenario = coverage_scenario(16, Config())
    truth = scenario.truth
    exp = scenario.recordings[1].experiment()
    rec = synthetic_recording(truth, exp, 30.0, 1.9e-5, 4, tmp_path / "b.csv", keep_last=12.0,
                              dt=5e-5, rate=200.0)
    term = FeatureTerm(rec, 10.0, 20.0, 5e-4).setup(truth)
    fine = FeatureTerm(rec, 10.0, 20.0, 5e-5).setup(truth)
    sd = np.sqrt(np.diag(term._data_cov))
    exact = fine.model_features([truth])[0] + fine.solver_bias
    raw = term.model_features([truth])[0]
    assert np.all(np.abs(raw - exact) < 0.1 * sd), (raw - exact) / sd
    assert np.all(np.abs(raw + term.solver_bias - exact) < 0.6 * sd), (raw + term.solver_bias - exact) / sd
    assert np.allclose(term.solver_var, (term.solver_bias / 2.0) ** 2)


def _settling_record(path, index, record=0, lead=10.0, noise=1e-5, seed=5):
    """A coverage draw's closed-loop record made by the kernel as the benchmark makes it: from the
    generator's start, ``lead`` seconds dropped, white noise."""
    from tvcid.models import simulate
    from tvcid.models.recording import save_recording
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    scenario = coverage_scenario(index, Config())
    design = scenario.recordings[record]
    exp = design.experiment()
    tr = simulate(scenario.truth, exp, lead + design.duration, dt=1e-4, rate=1000.0)
    keep = tr.t >= lead - 1e-9
    rng = np.random.default_rng(seed)
    delta = tr.delta[keep] + noise * rng.standard_normal(int(keep.sum()))
    save_recording(path, {"t": tr.t[keep] - tr.t[keep][0], "u": tr.u[keep], "delta": delta},
                   {"kind": "closed", "kp": exp.kp, "kd": exp.kd, "mu": exp.mu,
                    "controller_rate": design.controller_rate})
    return scenario.truth, load_recording(path)


def test_a_record_still_settling_is_simulated_from_where_it_starts(tmp_path, monkeypatch):
    """Coverage draw 15's first cycle (dead zone on the velocity signal, friction offset, 1 kHz,
    controller held at 200 Hz): it settles with a ~4.5 s time constant and its last 10 s sit
    under the settled cycle. The whole record's pieces show the approach, so runs start at its
    first piece's size: at the truth the features then agree with the record (chi-square under
    11.1, the 95 % point on 5; measured 1.8). Runs started at the window's size agree too
    (measured 1.8), because the window's own pieces, read over exact whole periods, show the
    trend, and its settled features' uncertainty joins the variance (for H1, about 70 times the
    rest of its variance). The same truth recorded after 60 s, settled, needs no record start: its runs start
    at the window's size."""
    truth, rec = _settling_record(tmp_path / "d15.csv", 15)
    term = FeatureTerm(rec, 10.0, 20.0, 5e-4)
    assert term.record_start is not None
    rms, seconds, piece = term.record_start
    assert seconds == pytest.approx(float(rec.t[-1] - rec.t[0]) - float(term.tau[-1]))
    term.setup(truth)
    chi2 = float(np.sum(term.whitened_residuals([truth], np.array([term.sigma_hat]))[0] ** 2))
    assert chi2 < 11.07
    # every parameter set starts its approach at the record's first size, not only the start's
    # (a shared start puts draw 15's dead zone and friction offset outside, rank 0.01): with
    # the dead zone 10 % off, the first piece 1.5 % off the record's rms shared, 0.36 % matched
    other = truth.replace(dead_zone=1.1 * truth.dead_zone)
    shared, _ = super(FeatureTerm, term).simulate([other])
    matched, ok = term.simulate([other])
    first = term.simulator.t <= piece
    off_shared = abs(np.std(shared[0, first]) / rms - 1)
    off_matched = abs(np.std(matched[0, first]) / rms - 1)
    assert ok[0] and off_shared > 0.01 and off_matched < min(0.005, off_shared / 3), (off_shared,
                                                                                   off_matched)
    # sized on its first piece alone, the run is the one sized on a whole run's first piece
    ws = term.simulator.warm_start
    resized = dataclasses.replace(ws, rms_target=ws.rms_target * rms / np.std(shared[0, first]))
    np.testing.assert_array_equal(matched, term.simulator.run([other], starts=[resized])[0])

    monkeypatch.setattr(FeatureTerm, "_record_start", lambda self, n_segments: None)
    window_sized = FeatureTerm(rec, 10.0, 20.0, 5e-4).setup(truth)
    z = window_sized.whitened_residuals([truth], np.array([window_sized.sigma_hat]))[0]
    assert float(np.sum(z**2)) < 11.07
    h1 = window_sized.features.index("H1")
    assert window_sized.settling_var[h1] > 30 * (window_sized.cov_hat[h1, h1]
                                                   - window_sized.settling_var[h1])
    monkeypatch.undo()

    _, settled = _settling_record(tmp_path / "d15_settled.csv", 15, lead=60.0)
    assert FeatureTerm(settled, 10.0, 20.0, 5e-4).record_start is None


def _held_record(tmp_path):
    """Coverage draw 16's truth at its second setting (controller held at 200 Hz), 12 s sampled
    at 200 Hz, noise 1.9e-5 rad: the record whose step error the features correct."""
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario

    scenario = coverage_scenario(16, Config())
    exp = scenario.recordings[1].experiment()
    rec = synthetic_recording(scenario.truth, exp, 30.0, 1.9e-5, 4, tmp_path / "b.csv",
                              keep_last=12.0, dt=5e-5, rate=200.0)
    return scenario.truth, rec


def test_the_solver_correction_is_the_median_change_over_points_where_one_point_jumps(tmp_path):
    """Near the held controller's switching events the step-doubling change is not smooth in the
    parameters: at 16 points within 1 % of the truth (dead zone, delay, backlash and feedback gain
    scattered; seeded) H1 moves by 0.004 to 2.3 data sd, its median 0.08. The correction over
    those points is twice the median change, its variance the mean squared change: the one-point
    rule's on average, without its jump at a special point."""
    truth, rec = _held_record(tmp_path)
    term = FeatureTerm(rec, 10.0, 20.0, 5e-4).setup(truth)
    sd = np.sqrt(np.diag(term._data_cov))
    rng = np.random.default_rng(0)
    names = ("dead_zone", "delay", "backlash", "feedback_gain")
    sets = [truth] + [truth.replace(**{n: getattr(truth, n) * (1 + 0.01 * rng.standard_normal())
                                       for n in names}) for _ in range(15)]
    warm = term.warm_start is not None
    changes = []
    for s in sets:
        term.solver_variance(s, warm)
        changes.append(term.solver_bias / 2.0)
    changes = np.array(changes)
    h1 = np.abs(changes[:, term.features.index("H1")]) / sd[term.features.index("H1")]
    assert h1.max() > 1.0 and h1.min() < 0.05 and h1.max() > 20 * np.median(h1)
    var = term.solver_correction(sets, warm)
    assert np.allclose(term.solver_bias, 2.0 * np.median(changes, axis=0), rtol=1e-9, atol=0)
    assert np.allclose(var, np.mean(changes**2, axis=0), rtol=1e-9, atol=0)
    one = term.solver_variance(sets[0], warm)  # one point: the change and its square
    assert np.allclose(one, changes[0] ** 2, rtol=1e-9, atol=0)


def test_the_start_measures_the_correction_at_its_walkers_and_a_resumed_run_keeps_it(tmp_path):
    """A features calibration measures each record's solver correction over its maximum a
    posteriori and eight of the walkers' starting points, keeps both in its checkpoint, and a
    resumed run takes them from there rather than from the maximum alone; the half-step log
    posterior of the step error measures its own correction over the same points."""
    from tvcid.discovery.calibration import Calibration
    from tvcid.discovery.calibration.runner import ConvergenceWarning
    from tvcid.discovery.calibration.step_error import halved_log_posterior

    truth, rec = _held_record(tmp_path)

    def cal(steps):
        return Calibration(truth, params=("dead_zone", "delay"), likelihood="features",
                           window=10.0, transient=20.0, dt=5e-4, n_walkers=10, max_steps=steps,
                           check_every=5, stop_when_converged=False, backend=tmp_path / "c.h5",
                           seed=2)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        first = cal(5).fit([rec])
        points = first.solver_check_points_
        assert len(points) == 9 and points[0] == pytest.approx(first.map_start_)
        term = first.log_posterior_.terms[0]
        lp = first.log_posterior_
        sets = [lp.params_for(np.array([p[n] for n in first.names_])) for p in points]
        bias, var = term.solver_bias.copy(), term.solver_var.copy()
        again = FeatureTerm(rec, 10.0, 20.0, 5e-4).setup(truth)
        assert np.array_equal(again.solver_correction(sets), var)
        assert np.array_equal(again.solver_bias, bias)
        at_map_alone = again.solver_variance(sets[0])
        assert not np.array_equal(at_map_alone, var)
        resumed = cal(10).fit([rec])
    assert resumed.report_.new_steps == 5
    assert resumed.solver_check_points_ == points
    assert np.array_equal(resumed.log_posterior_.terms[0].solver_bias, bias)
    assert np.array_equal(resumed.log_posterior_.terms[0].solver_var, var)
    over_points = halved_log_posterior(resumed).simulated_seconds
    at_one = halved_log_posterior(resumed, at=points[0]).simulated_seconds
    assert over_points > at_one
