"""Calibration core: priors, bad input, the runner on a known Gaussian, resume equality, -inf."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from tvcid.cli import main
from tvcid.discovery.calibration import (
    Calibration,
    LogUniform,
    Uniform,
    parse_prior,
    run_ensemble,
)
from tvcid.discovery.calibration.runner import ConvergenceWarning
from tvcid.discovery.calibration.testing import moment_errors, sample_gaussian
from tvcid.models import CONTROLLER_A, M002, simulate
from tvcid.models.cycle_reading import cycle_features, limit_cycle_features
from tvcid.models.recording import RecordingError
from tvcid.models.synthetic import synthetic_recording


@pytest.fixture(scope="module")
def short_record(tmp_path_factory):
    """M002, controller A, 4 s of limit cycle with 1e-4 rad sensor noise (seed 3)."""
    path = tmp_path_factory.mktemp("cal") / "m002_A_short.csv"
    return synthetic_recording(M002(), CONTROLLER_A, 12.0, 1e-4, 3, path, keep_last=4.0)


def _small(backend=None, max_steps=60, **kw):
    return Calibration("M002", params=("backlash", "dead_zone"), window=3.0, transient=3.0,
                       n_walkers=8, max_steps=max_steps, check_every=20, backend=backend,
                       seed=11, **kw)


# -- priors and bad input ------------------------------------------------------------------------
def test_prior_bounds_reversed_and_log_needs_positive():
    with pytest.raises(ValueError, match="reversed"):
        Uniform(2.0, 1.0)
    with pytest.raises(ValueError, match="reversed"):
        parse_prior("backlash=3e-4:1e-4:log")
    with pytest.raises(ValueError, match="low > 0"):
        LogUniform(0.0, 1.0)
    name, prior = parse_prior("dead_zone=1e-4:1e-2:log")
    assert name == "dead_zone" and prior.log and prior.to_natural(prior.to_internal(3e-3)) == pytest.approx(3e-3)


def test_log_uniform_in_linear_coordinate_keeps_its_density():
    """Sampled in the parameter itself, a log-uniform prior still integrates to 1 with the 1/x
    Jacobian, and its draws are log-uniform (deciles of ln x within 0.02 of the exact ones)."""
    p = LogUniform(1e-3, 1e-1, linear=True)
    assert not p.log and p.internal_bounds == (1e-3, 1e-1)
    z = np.linspace(1e-3, 1e-1, 200001)
    assert np.trapezoid(np.exp(p.log_prob_internal(z)), z) == pytest.approx(1.0, abs=1e-6)
    assert np.all(np.isinf(p.log_prob_internal([5e-4, 0.2])))
    draws = np.log(p.to_natural(p.sample_internal(np.random.default_rng(0), 100000)))
    exact = np.log(1e-3) + np.log(100.0) * np.arange(1, 10) / 10
    assert np.max(np.abs(np.quantile(draws, np.arange(1, 10) / 10) - exact)) < 0.02
    assert p.describe()["coordinate"] == "linear"


def test_ridge_coordinates_straighten_only_the_difference_ridge():
    from tvcid.discovery.calibration.priors import ridge_coordinates
    from tvcid.models import M001f

    priors = {"dead_zone": LogUniform(1e-3, 3e-2), "friction_offset": Uniform(-3e-2, 0.0),
              "backlash": LogUniform(1e-5, 1e-3)}
    out = ridge_coordinates(priors, tuple(priors), M001f())  # dead zone on the velocity signal
    assert not out["dead_zone"].log and out["backlash"].log
    assert out["friction_offset"] == priors["friction_offset"]
    assert ridge_coordinates(priors, tuple(priors), M002())["dead_zone"].log  # on the error
    no_friction = {k: v for k, v in priors.items() if k != "friction_offset"}
    assert ridge_coordinates(no_friction, tuple(no_friction), M001f())["dead_zone"].log


def test_unknown_parameter_name_is_named(short_record):
    with pytest.raises(ValueError, match="unknown parameter 'dead_band'.*dead_zone"):
        Calibration("M002", params=("dead_band",)).fit([short_record])
    with pytest.raises(ValueError, match="cannot be calibrated"):
        Calibration("M002", params=("delay_position",)).fit([short_record])
    with pytest.raises(ValueError, match="unknown hypothesis"):
        Calibration("M003", params=("delay",)).fit([short_record])


def test_prior_outside_start_and_unsampled_prior(short_record):
    with pytest.raises(ValueError, match="outside its prior"):
        _small(priors={"backlash": Uniform(1e-3, 2e-3)}).fit([short_record])
    with pytest.raises(ValueError, match="not sampled"):
        _small(priors={"delay": Uniform(1e-3, 2e-2)}).fit([short_record])


def test_empty_recording_and_no_recording(tmp_path, short_record):
    empty = tmp_path / "empty.csv"
    empty.write_text("t,u,delta\n")
    empty.with_suffix(".json").write_text(json.dumps({"kind": "closed", "kp": 5.84, "kd": 0.062, "mu": 12.3}))
    with pytest.raises(RecordingError, match="empty"):
        _small().fit([empty])
    with pytest.raises(ValueError, match="no recording"):
        _small().fit([])
    flat = tmp_path / "flat.csv"
    flat.write_text("t,u,delta\n" + "".join(f"{k * 1e-3},0,0\n" for k in range(3000)))
    flat.with_suffix(".json").write_text(json.dumps({"kind": "closed", "kp": 5.84, "kd": 0.062, "mu": 12.3}))
    with pytest.raises(ValueError, match="no limit cycle"):
        _small().fit([flat])


def test_cli_bad_input_exit_code(tmp_path, short_record, capsys):
    args = ["fit", str(short_record.path), "--hypothesis", "M002", "--out", str(tmp_path / "o")]
    assert main(args + ["--params", "backlash,foo"]) == 2
    assert "unknown parameter 'foo'" in capsys.readouterr().err
    assert main(args + ["--params", "backlash", "--prior", "backlash=3e-4:1e-4"]) == 2
    assert "reversed" in capsys.readouterr().err


# -- the runner on a known distribution ----------------------------------------------------------
def test_runner_recovers_a_correlated_gaussian():
    mean = [1.0, -2.0, 0.5]
    cov = np.array([[1.0, 0.95, 0.0], [0.95, 1.0, 0.3], [0.0, 0.3, 4.0]])
    samples, report, _ = sample_gaussian(mean, cov, seed=5)
    assert report.converged and report.iterations > 50 * max(report.tau)
    err = moment_errors(samples, mean, cov)
    assert np.all(err["mean_in_sd"] < 0.15)
    assert np.all(err["sd_relative"] < 0.1)
    assert np.all(err["correlation"] < 0.08)


def test_runner_warns_at_the_cap():
    lp = lambda x: -0.5 * np.sum(np.atleast_2d(x) ** 2, axis=1)  # noqa: E731
    with pytest.warns(ConvergenceWarning, match="NOT CONVERGED"):
        _, rep = run_ensemble(lp, lambda rng: rng.standard_normal((8, 2)), 8, 2, 30, seed=1)
    assert not rep.converged and rep.iterations == 30


class _StoredChain:
    """What :func:`convergence_report` reads off a sampler, for a chain given as an array."""

    def __init__(self, chain):
        import emcee

        self.chain = chain
        self.iteration, n_walkers, self.ndim = chain.shape
        self.acceptance_fraction = np.full(n_walkers, 0.3)
        self._tau = emcee.autocorr.integrated_time

    def get_autocorr_time(self, discard=0, tol=0, quiet=True):
        return self._tau(self.chain[discard:], tol=tol, quiet=quiet)


def _ar1_chain(rng, n_steps, n_walkers=16, rho=0.8):
    x = np.zeros((n_steps, n_walkers, 1))
    for k in range(1, n_steps):
        x[k] = rho * x[k - 1] + math.sqrt(1 - rho * rho) * rng.standard_normal((n_walkers, 1))
    return x


def test_convergence_is_judged_after_the_walkers_way_in():
    """A chain that starts 20 sd off and relaxes within ~100 steps, then mixes with tau ~8: the
    whole chain's tau is inflated by the way in and never passes; its second half passes alone
    and the report says so (burn = half the chain, the posterior's samples start there). A
    stationary chain passes on the whole (burn 0); a chain that drifts throughout passes neither
    way."""
    from tvcid.discovery.calibration.runner import convergence_report

    rng = np.random.default_rng(3)
    steps = 1200
    stationary = _ar1_chain(rng, steps)
    rep = convergence_report(_StoredChain(stationary))
    assert rep.converged and rep.burn == 0 and steps > 50 * max(rep.tau)

    way_in = stationary + 20.0 * np.exp(-np.arange(steps) / 25.0)[:, None, None]
    whole = convergence_report(_StoredChain(way_in))
    assert whole.converged and whole.burn == steps // 2
    assert (steps - whole.burn) > 50 * max(whole.tau)
    import emcee

    assert steps < 50 * float(emcee.autocorr.integrated_time(way_in, tol=0, quiet=True)[0])

    drift = stationary + np.linspace(0.0, 60.0, steps)[:, None, None]
    assert not convergence_report(_StoredChain(drift)).converged


def test_independent_draws_pass_only_past_tau_factor_steps():
    """Independent draws (tau 1): emcee's tau estimate on 10 steps falls below one step (0.3-0.6),
    which must not call 10 steps converged at 12 tau; past ``tau_factor`` steps they are."""
    from tvcid.discovery.calibration.runner import convergence_report

    rng = np.random.default_rng(5)
    short = _StoredChain(rng.standard_normal((10, 16, 2)))
    assert 10 > 12.0 * max(short.get_autocorr_time())  # the estimate alone would pass
    assert not convergence_report(short, tau_factor=12.0).converged
    assert convergence_report(_StoredChain(rng.standard_normal((30, 16, 2))), tau_factor=25.0).converged


def test_interval_drift_tells_a_settled_chain_from_a_wandering_one():
    """The 90 % intervals of a kept chain's two halves: a stationary AR(1) chain (tau ~9, 1000
    steps, 16 walkers) gives them within 15 % of the width (measured 0.05); the same chain whose
    walkers drift by three sd over the run (a chain still spreading into a direction the data
    leave free) gives them apart by half the width (measured 0.60). A parameter sampled in log
    is judged in log: the settled chain as ``exp`` of itself drifts as much as in its own
    coordinate (0.05; read in natural units, 0.02)."""
    from tvcid.discovery.calibration.posterior import Posterior

    rng = np.random.default_rng(4)
    settled = _ar1_chain(rng, 1000, rho=0.8)
    wandering = settled + np.linspace(0, 3, 1000)[:, None, None]

    def drift(chain, log=False):
        post = Posterior(names=("x",), samples=chain.reshape(-1, 1), internal=chain.reshape(-1, 1),
                         log_prob=np.zeros(chain.size), chain=chain, log_scale=(log,), truths={},
                         report=None, burn=100, thin=1)
        return post.interval_drift()

    assert drift(settled)["largest"] < 0.15 and drift(settled)["parameter"] == "x"
    assert drift(wandering)["largest"] > 0.4
    assert drift(settled[:110]) is None  # 10 kept steps
    assert drift(np.exp(settled), log=True)["largest"] == pytest.approx(
        drift(settled)["largest"], rel=1e-9)


def test_gaussian_resume_through_hdf_equals_straight_run(tmp_path):
    import emcee

    from tvcid.discovery.calibration.testing import GaussianLogProb

    lp = GaussianLogProb([0.0, 1.0], [[1.0, 0.5], [0.5, 2.0]])
    init = lambda rng: rng.standard_normal((8, 2))  # noqa: E731
    s1, _ = run_ensemble(lp, init, 8, 2, 90, seed=3, check_every=25, warn=False)
    be = emcee.backends.HDFBackend(str(tmp_path / "g.h5"))
    run_ensemble(lp, init, 8, 2, 40, seed=3, backend=be, check_every=25, warn=False)
    be2 = emcee.backends.HDFBackend(str(tmp_path / "g.h5"))
    s2, _ = run_ensemble(lp, init, 8, 2, 90, seed=999, backend=be2, check_every=25, warn=False)
    assert np.array_equal(s1.get_chain(), s2.get_chain())


# -- the simulator-backed log posterior ----------------------------------------------------------
def test_invalid_diverging_and_silent_runs_get_minus_inf(short_record):
    cal = _small().setup([short_record])
    lp = cal.log_posterior_
    term = lp.terms[0]
    base = M002()
    sets = [base, base.replace(delay=0.05), base.replace(dead_zone=0.5), None]
    ll = term.loglike(sets, np.full(4, 1e-4))
    assert np.isfinite(ll[0])
    assert np.all(ll[1:] == -np.inf)
    z_out = np.array([[0.0, 0.0], [np.nan, 0.0]])  # outside the prior, NaN
    assert np.all(lp(z_out) == -np.inf)


def test_vectorised_features_match_models_features():
    tr = simulate(M002(), CONTROLLER_A, 14.0)
    sel = tr.t >= 4.0
    names = ("frequency", "amplitude", "H1", "H3", "H5", "H7")
    mine = cycle_features(tr.t[sel], tr.delta[sel], names)
    ref = limit_cycle_features(tr.t[sel], tr.delta[sel], n_harmonics=7)
    assert mine[0] == pytest.approx(ref.frequency, rel=1e-9)
    assert mine[1] == pytest.approx(ref.amplitude, rel=1e-12)
    for k, v in zip((1, 3, 5, 7), mine[2:]):
        assert v == pytest.approx(ref.harmonics[k - 1], rel=1e-9)


def test_a_ripple_at_the_mean_level_reads_as_the_records_do():
    """A cycle with a fast ripple whose slope exceeds the cycle's at its mean crossings (the
    band-pass loop's ~10 Hz on a drawn truth's 1.3 Hz cycle): the simulated cycle's features
    follow the record's trigger rule (``limit_cycle_features``), so the ripple's extra crossings
    do not raise the frequency (every crossing counted: 10.6 rad/s for 7.98)."""
    t = np.arange(0.0, 10.0, 1e-3)
    w = 2 * np.pi * 1.27
    x = np.sin(w * t) + 0.08 * np.sin(19.7 * w * t)
    mine = cycle_features(t, x, ("frequency", "H1"))
    ref = limit_cycle_features(t, x)
    assert mine[0] == pytest.approx(ref.frequency, rel=1e-12)
    assert mine[0] == pytest.approx(w, rel=2e-3)
    assert mine[1] == pytest.approx(ref.harmonics[0], rel=1e-9)


def test_waveform_likelihood_peaks_at_truth(short_record):
    cal = _small().setup([short_record])
    term = cal.log_posterior_.terms[0]
    base = M002()
    sets = [base] + [base.replace(backlash=base.backlash * f) for f in (0.97, 1.03)] + \
        [base.replace(delay=base.delay + d) for d in (-2e-4, 2e-4)]
    ll = term.loglike(sets, np.full(len(sets), 1e-4))
    assert np.all(ll[1:] < ll[0] - 20)


def test_interrupted_run_resumes_to_the_same_chain(tmp_path, short_record, monkeypatch):
    """A fit killed mid-chunk (an exception inside the log posterior) and resumed from its HDF
    file gives, step for step, the chain of an uninterrupted run with the same seed."""
    import warnings

    from tvcid.discovery.calibration.log_posterior import LogPosterior

    warnings.simplefilter("ignore", ConvergenceWarning)
    straight = _small(backend=tmp_path / "a.h5", stop_when_converged=False).fit([short_record])
    original = LogPosterior.__call__
    import emcee

    def steps_taken():
        try:
            return emcee.backends.HDFBackend(str(tmp_path / "b.h5"), read_only=True).iteration
        except (OSError, KeyError):  # the start is still searching: no chain yet
            return 0

    def dying(self, z):
        if steps_taken() >= 30:  # inside the second 20-step chunk, whatever the start cost
            raise KeyboardInterrupt
        return original(self, z)

    monkeypatch.setattr(LogPosterior, "__call__", dying)
    with pytest.raises(KeyboardInterrupt):
        _small(backend=tmp_path / "b.h5", stop_when_converged=False).fit([short_record])
    monkeypatch.setattr(LogPosterior, "__call__", original)
    partial = emcee.backends.HDFBackend(str(tmp_path / "b.h5"), read_only=True).iteration
    assert 0 < partial < 60
    resumed = _small(backend=tmp_path / "b.h5", stop_when_converged=False).fit([short_record])
    assert resumed.report_.new_steps == 60 - partial
    assert np.array_equal(straight.sampler_.get_chain(), resumed.sampler_.get_chain())
    assert np.array_equal(straight.sampler_.get_log_prob(), resumed.sampler_.get_log_prob())


def test_backend_with_another_setup_is_refused(tmp_path, short_record):
    import warnings

    warnings.simplefilter("ignore", ConvergenceWarning)
    _small(backend=tmp_path / "c.h5", max_steps=20).fit([short_record])
    with pytest.raises(ValueError, match="different set-up"):
        Calibration("M002", params=("backlash", "delay"), window=3.0, transient=3.0, n_walkers=8,
                    max_steps=20, backend=tmp_path / "c.h5").fit([short_record])


def test_pool_with_map_is_accepted(short_record):
    """Any object with ``.map`` serves as the pool; the chain is the same as without it."""
    import warnings

    class SerialPool:
        def __init__(self):
            self.calls = 0

        def map(self, fn, items):
            self.calls += 1
            return [fn(i) for i in items]

    warnings.simplefilter("ignore", ConvergenceWarning)
    pool = SerialPool()
    a = _small(max_steps=10, pool=pool).fit([short_record])
    b = _small(max_steps=10).fit([short_record])
    assert pool.calls >= 10
    assert np.array_equal(a.sampler_.get_chain(), b.sampler_.get_chain())
    # the cost in steps: one record, every point simulated at the record's (possibly refined) step
    lp, sim = b.log_posterior_, b.log_posterior_.terms[0].simulator
    assert lp.simulated_steps == pytest.approx(lp.simulated_seconds / sim.dt)
    assert sim.dt <= b.dt_


def test_open_loop_command_rebuilt_from_sidecar(tmp_path):
    """A square-wave test replayed from its 1 kHz samples by linear interpolation has each edge
    0.5 ms early; the sidecar's waveform gives the exact command, and so does the replay of the
    samples as a piecewise-constant command (tvcid.models.commands): the delay is unbiased in both."""
    import json as _json

    from tvcid.models import OpenLoop
    from tvcid.models.recording import load_recording

    rec = synthetic_recording(M002(), OpenLoop.square(5e-3, 1.0), 3.0, 1e-4, 2, tmp_path / "sq.csv")
    exact = Calibration("M002", params=("delay",)).setup([rec])
    assert exact.terms_[0].describe()["command"] == "sidecar square"
    meta = _json.loads((tmp_path / "sq.json").read_text())
    for key in ("waveform", "amplitude", "frequency", "start", "offset"):
        meta.pop(key)
    (tmp_path / "sq.json").write_text(_json.dumps(meta))
    sampled = Calibration("M002", params=("delay",)).setup([load_recording(tmp_path / "sq.csv")])
    assert sampled.terms_[0].describe()["command"].startswith("recorded samples, piecewise")
    base = M002()
    sets = [base.replace(delay=base.delay + d) for d in (0.0, 5e-4)]
    ll_exact = exact.terms_[0].loglike(sets, np.full(2, 1e-4))
    ll_sampled = sampled.terms_[0].loglike(sets, np.full(2, 1e-4))
    assert ll_exact[0] > ll_exact[1]  # the truth wins with the exact command
    assert ll_sampled[0] > ll_sampled[1]  # and with the edges rebuilt from the samples


def test_default_delay_prior_refuses_a_start_below_one_step():
    from tvcid.discovery.calibration import default_prior

    assert default_prior("delay", 7e-3, dt=5e-4).low == pytest.approx(3.5e-3)
    assert default_prior("delay", 1.5e-3, dt=5e-4).low == pytest.approx(7.5e-4)
    # a start under two steps keeps a prior from one step, the kernel's shortest delay
    assert (default_prior("delay", 8e-4, dt=5e-4).low, default_prior("delay", 8e-4).low) == \
        pytest.approx((5e-4, 4e-4))
    for start in (2.4e-4, 4.9e-4):
        with pytest.raises(ValueError, match=f"delay starts at {start:.3g} s, below one step.*declare"):
            default_prior("delay", start, dt=5e-4)


def test_the_step_follows_the_floor_of_the_delay_prior():
    """The default step is halved until one step fits under the delay prior's floor, declared or
    default (half the start): 0.8 ms starts a prior at 0.4 ms on 2.5e-4 s steps, a declared
    floor of 0.1 ms runs at 6.25e-5 s; a floor at or above 5e-4 s, a delay not sampled or a given
    step keeps the step; a floor finer than four halvings is a one-line error."""
    from tvcid.discovery.calibration.priors import MAX_DELAY_HALVINGS, step_under_delay
    from tvcid.models.recording import load_recording

    assert [step_under_delay(f, 5e-4) for f in (7e-3, 5e-4, 4.9e-4, 2.5e-4, 1e-4, 3.125e-5)] == \
        [5e-4, 5e-4, 2.5e-4, 2.5e-4, 6.25e-5, 3.125e-5]
    assert MAX_DELAY_HALVINGS == 4
    for floor in (3e-5, 0.0, -1e-3):
        with pytest.raises(ValueError, match="delay prior's floor .* below the finest default step"):
            step_under_delay(floor, 5e-4)

    recs = [load_recording(Path(__file__).resolve().parents[1] / "data" / "m000_closed_A.csv")]
    short = M002().replace(delay=8e-4)
    cal = Calibration(short, params=("delay",), likelihood="features").setup(recs)
    assert cal.dt_ == 2.5e-4
    assert (cal.priors_["delay"].low, cal.priors_["delay"].high) == pytest.approx((4e-4, 1.6e-3))
    assert Calibration(short.replace(delay=1e-3), params=("delay",),
                       likelihood="features").setup(recs).dt_ == 5e-4
    declared = Calibration(short, params=("delay",), likelihood="features",
                           priors={"delay": Uniform(1e-4, 2e-3)}).setup(recs)
    assert declared.dt_ == 6.25e-5
    assert Calibration(short, params=("delay",), likelihood="features",
                       priors={"delay": Uniform(5e-4, 2e-3)}).setup(recs).dt_ == 5e-4
    with pytest.raises(ValueError, match=r"delay prior's floor \(1e-06 s\)"):
        Calibration(short, params=("delay",), likelihood="features",
                    priors={"delay": Uniform(1e-6, 2e-3)}).setup(recs)
    assert Calibration(short, params=("delay",), likelihood="features", dt=1e-4).setup(recs).dt_ == 1e-4
    assert Calibration(short, params=("dead_zone",), likelihood="features").setup(recs).dt_ == 5e-4
    assert Calibration(M002(), params=("delay",), likelihood="features").setup(recs).dt_ == 5e-4


def _correlated_gaussian():
    """``(mean, sd, cov)`` of a 4-d Gaussian with one correlation 0.99 and sds over two decades."""
    mean = np.array([1.0, -2.0, 0.5, 3.0])
    sd = np.array([1.0, 0.01, 2.0, 0.3])
    corr = np.full((4, 4), 0.5)
    corr[0, 1] = corr[1, 0] = 0.99
    np.fill_diagonal(corr, 1.0)
    return mean, sd, corr * np.outer(sd, sd)


def test_laplace_independence_move_samples_a_known_gaussian():
    """emcee's test pattern: a 4-d Gaussian (one correlation 0.99, sds over two decades) sampled
    with nine steps in ten from the independence move around a slightly wrong centre: moments
    within 0.1 sd / 10 %, and a much shorter tau than the DE moves alone (measured 2.6 vs 11).
    Its acceptance estimate from proposals alone tells a right proposal from a wrong one."""
    import emcee

    from tvcid.discovery.calibration.moves import LaplaceIndependenceMove

    mean, sd, cov = _correlated_gaussian()
    move = LaplaceIndependenceMove(mean + 0.3 * sd, cov)
    moves = [(emcee.moves.DEMove(), 0.08), (emcee.moves.DESnookerMove(), 0.02), (move, 0.9)]
    samples, report, _ = sample_gaussian(mean, cov, moves=moves, seed=3, check_every=50)
    errors = moment_errors(samples, mean, cov)
    assert report.converged and max(report.tau) < 5
    assert np.all(errors["mean_in_sd"] < 0.1) and np.all(errors["sd_relative"] < 0.1)
    _, de_only, _ = sample_gaussian(mean, cov, seed=3, check_every=50)
    assert max(de_only.tau) > 2 * max(report.tau)
    from tvcid.discovery.calibration.testing import GaussianLogProb

    lp = GaussianLogProb(mean, cov)
    rng = np.random.default_rng(0)
    right = move.draw(rng, 48)  # the calibration's trial: 2 n_walkers proposals
    assert move.expected_acceptance(right, lp(right)) > 0.5  # measured 0.62-0.66
    wrong = LaplaceIndependenceMove(mean, np.diag(sd**2))  # the correlation missed
    trial = wrong.draw(rng, 48)
    assert wrong.expected_acceptance(trial, lp(trial)) < 0.15  # measured 0.05-0.08


class _Funnel:
    """A density on the box ``[0, 1]^2 x [-5, 5]`` shaped as a limit cycle's posterior of the
    linear block: ``y`` pinned (sd 0.01) while ``x`` is small, free once ``x`` is large (a
    resonance far above the cycle leaves its damping ratio unseen); ``w`` standard normal."""

    low, high = np.array([0.0, 0.0, -5.0]), np.array([1.0, 1.0, 5.0])

    @staticmethod
    def sd_y(x):
        return 0.01 + 2.0 * np.maximum(x - 0.3, 0.0) ** 2

    def __call__(self, z):
        z = np.atleast_2d(z)
        inside = np.all((z >= self.low) & (z <= self.high), axis=1)
        s = self.sd_y(z[:, 0])
        value = -0.5 * ((z[:, 1] - 0.5) / s) ** 2 - np.log(s) - 0.5 * z[:, 2] ** 2
        return np.where(inside, value, -np.inf)

    def moments(self):
        """Mean of ``x`` and sd of ``y`` by quadrature on a grid."""
        x, y = np.meshgrid(np.linspace(0, 1, 1001), np.linspace(0, 1, 2001), indexing="ij")
        p = np.exp(-0.5 * ((y - 0.5) / self.sd_y(x)) ** 2) / self.sd_y(x)
        p /= p.sum()
        return float((p * x).sum()), float(np.sqrt((p * (y - 0.5) ** 2).sum()))


@pytest.mark.parametrize("seed", [1, 2])
def test_chord_moves_reach_the_wide_end_of_a_funnel(seed):
    """Started where the funnel is narrow (a limit cycle's fit), the default moves' chain, chord
    moves across the prior included, matches the funnel's moments by quadrature: mean of ``x``
    0.447 within 0.06, sd of ``y`` 0.152 within 15 % (measured 0.415-0.424 and 0.137-0.144 over
    4000 steps). The differential-evolution moves alone stay near the neck (0.36-0.38 and
    0.106-0.123): the wide end's volume is reached through proposals the ensemble's spread does
    not make."""
    import emcee

    from tvcid.discovery.calibration.moves import PriorChordMove, _move_weights
    from tvcid.discovery.calibration.runner import run_ensemble

    target = _Funnel()
    w = _move_weights(0.0)[[0, 1, 3]]
    moves = list(zip((emcee.moves.DEMove(), emcee.moves.DESnookerMove(),
                      PriorChordMove(target.low, target.high)), w / w.sum()))

    def initial(rng):
        return np.array([0.1, 0.5, 0.0]) + 1e-3 * rng.standard_normal((16, 3))

    sampler, _ = run_ensemble(target, initial, 16, 3, 4000, seed=seed, moves=moves,
                              stop_when_converged=False, warn=False)
    z = sampler.get_chain(discard=1000, flat=True)
    mean_x, sd_y = target.moments()
    assert abs(z[:, 0].mean() - mean_x) < 0.06, z[:, 0].mean()
    assert abs(z[:, 1].std() / sd_y - 1) < 0.15, z[:, 1].std()


def test_a_chord_move_alone_samples_a_known_gaussian():
    """emcee's test pattern: the chord move as the only move (axes and the complement's principal
    axes, uniform on the prior box's chord) keeps the 4-d correlated Gaussian, boxed at 6 sd, as
    its stationary law: moments within 0.1 sd / 10 %."""
    from tvcid.discovery.calibration.moves import PriorChordMove, resonance_direction

    mean, sd, cov = _correlated_gaussian()
    move = PriorChordMove(mean - 6 * sd, mean + 6 * sd)
    samples, _, _ = sample_gaussian(mean, cov, moves=[(move, 1.0)], seed=2, max_steps=6000,
                                    tau_factor=1e9, n_walkers=24)
    errors = moment_errors(samples, mean, cov)
    assert np.all(errors["mean_in_sd"] < 0.1) and np.all(errors["sd_relative"] < 0.1), errors
    # the linear block's resonance direction: only when gain, damping and stiffness are logs
    from tvcid.discovery.calibration.priors import LogUniform, Uniform

    priors = {"gain": LogUniform(1e4, 1e7), "damping": LogUniform(10, 1e3),
              "stiffness": LogUniform(1e3, 1e5), "delay": Uniform(1e-3, 1e-2)}
    np.testing.assert_allclose(resonance_direction(("delay", "gain", "damping", "stiffness"),
                                                   priors), [0, 2, 1, 2])
    priors["damping"] = Uniform(10, 1e3)
    assert resonance_direction(("delay", "gain", "damping", "stiffness"), priors) is None


@pytest.mark.parametrize("correlated, kept", [(True, True), (False, False)])
def test_laplace_move_kept_only_if_its_steps_are_accepted(correlated, kept):
    """The check every 50 steps reads the walkers' moves off the chain: on the known Gaussian the
    right proposal keeps its share; one that misses the 0.99 correlation (the walkers moved in
    under 15 % of its steps), its refits spent, is switched off in the sampler and ``laplace_``."""
    import emcee

    from tvcid.discovery.calibration import Calibration
    from tvcid.discovery.calibration.moves import (
        LAPLACE_CHECK_STEPS,
        LAPLACE_MAX_REFITS,
        LaplaceIndependenceMove,
        PriorChordMove,
        _move_weights,
    )

    mean, sd, cov = _correlated_gaussian()
    move = LaplaceIndependenceMove(mean, cov if correlated else np.diag(sd**2))
    weights = _move_weights(0.9)
    moves = list(zip((emcee.moves.DEMove(), emcee.moves.DESnookerMove(), move,
                      PriorChordMove(mean - 10 * sd, mean + 10 * sd)), weights))
    _, _, sampler = sample_gaussian(mean, cov, moves=moves, seed=4, max_steps=LAPLACE_CHECK_STEPS + 1,
                                    tau_factor=1e9)
    cal = Calibration("M002")
    cal.laplace_ = {"adapted_at": 1, "share": 0.9, "refits": LAPLACE_MAX_REFITS}
    cal._laplace_move = move
    cal._adapt_laplace(sampler)
    assert cal.laplace_["checked_at"] == LAPLACE_CHECK_STEPS + 1
    assert (cal.laplace_["share"] > 0) == kept, cal.laplace_
    np.testing.assert_allclose(sampler._weights, weights if kept else _move_weights(0.0))


def test_switched_off_laplace_move_is_tried_again_once_the_chain_has_doubled():
    """A proposal switched off early (refitted while the walkers still spread: the ridge case's
    expected acceptance 0.15 at step 200) is refitted again to the chain when it has doubled; on
    the known Gaussian, sampled meanwhile by the DE moves, the refit matches it and the move comes
    back on, and a retry is spent only once per doubling. A retry that fails leaves the burn-in
    where it was: draw 1000 of the wide set-coverage benchmark, its last retry failing at step
    1600, kept only the last 400 of its 2000 steps otherwise."""
    import emcee

    from tvcid.discovery.calibration import Calibration
    from tvcid.discovery.calibration.moves import (
        LAPLACE_MAX_RETRIES,
        LaplaceIndependenceMove,
        PriorChordMove,
        _move_weights,
    )
    from tvcid.discovery.calibration.testing import GaussianLogProb

    mean, sd, cov = _correlated_gaussian()
    move = LaplaceIndependenceMove(mean, np.diag(sd**2))  # the one that was switched off
    moves = list(zip((emcee.moves.DEMove(), emcee.moves.DESnookerMove(), move,
                      PriorChordMove(mean - 10 * sd, mean + 10 * sd)), _move_weights(0.0)))
    _, _, sampler = sample_gaussian(mean, cov, moves=moves, seed=5, max_steps=400, tau_factor=1e9)
    cal = Calibration("M002", n_walkers=16, seed=5)
    cal.log_posterior_ = GaussianLogProb(mean, cov)
    cal._laplace_move = move
    cal.laplace_ = {"adapted_at": 250, "checked_at": 250, "share": 0.0}
    cal._adapt_laplace(sampler)  # 400 < 2 x 250: not yet
    assert cal.laplace_["share"] == 0.0 and "retries" not in cal.laplace_
    cal.laplace_ = {"adapted_at": 200, "checked_at": 200, "share": 0.0}
    cal._adapt_laplace(sampler)
    assert cal.laplace_["retries"] == 1 <= LAPLACE_MAX_RETRIES
    assert cal.laplace_["adapted_at"] == 400 and cal.laplace_["expected_acceptance"] > 0.5
    np.testing.assert_allclose(sampler._weights, _move_weights(0.9))
    # a retry that fails leaves the moves, so the burn-in (adapted_at) stays where it was; the
    # next retry waits for the chain to double from the failed one
    from unittest import mock

    from tvcid.discovery.calibration import moves as moves_module

    cal.laplace_ = {"adapted_at": 200, "checked_at": 200, "share": 0.0}
    with mock.patch.object(moves_module, "LAPLACE_MIN_ACCEPTANCE", 1.01):
        cal._adapt_laplace(sampler)
    assert cal.laplace_["share"] == 0.0 and cal.laplace_["retries"] == 1
    assert cal.laplace_["adapted_at"] == 200 and cal.laplace_["retried_at"] == 400
    sampler._weights = _move_weights(0.0)
    cal._adapt_laplace(sampler)  # 400 < 2 x 400: not yet
    assert cal.laplace_["retries"] == 1


class _BoxedGaussian:
    """N(mean, cov) cut to a box (a posterior whose ridge the prior cuts), with the ``priors``
    interface (``internal_bounds``) the Laplace checks read."""

    def __init__(self, mean, cov, lows, highs):
        from types import SimpleNamespace

        from tvcid.discovery.calibration.testing import GaussianLogProb

        self.gaussian = GaussianLogProb(mean, cov)
        self.lows, self.highs = np.asarray(lows, float), np.asarray(highs, float)
        self.priors = [SimpleNamespace(internal_bounds=(lo, hi)) for lo, hi in zip(lows, highs)]

    def __call__(self, x):
        x = np.atleast_2d(x)
        inside = np.all((x >= self.lows) & (x <= self.highs), axis=1)
        return np.where(inside, self.gaussian(x), -np.inf)


def test_laplace_move_waits_idle_on_a_ridge_the_prior_cuts():
    """A maximum on a prior bound (coverage draw 20: friction offset 0) leaves no Hessian: the
    move starts idle instead of being dropped, is switched on once fitted to the chain, and the
    chain converges in fewer steps than without it, by the differential-evolution and chord moves
    (measured 280 against 1070, tau 2-3 against 16-21), to the cut Gaussian's moments (mean and
    sd of each coordinate within 0.15 sd / 15 % of a rejection sample's)."""
    from tvcid.discovery.calibration import Calibration
    from tvcid.discovery.calibration.optimum import _hessian
    from tvcid.discovery.calibration.priors import Uniform
    from tvcid.discovery.calibration.runner import run_ensemble

    mean, sd, cov = _correlated_gaussian()
    lows, highs = mean - 6 * sd, mean + 6 * sd
    lows[0] = mean[0] - 0.5 * sd[0]  # the prior cuts the 0.99 ridge near its middle
    lp = _BoxedGaussian(mean, cov, lows, highs)
    z0 = mean.copy()
    z0[0] = lows[0]  # the maximum found on the bound
    z0[1] = mean[1] + 0.99 * (z0[0] - mean[0]) * sd[1] / sd[0]
    assert _hessian(lp, z0, 0.5 * sd) is None  # a probe leaves the prior
    ref = np.random.default_rng(0).multivariate_normal(mean, cov, 400_000)
    ref = ref[np.all((ref >= lows) & (ref <= highs), axis=1)]

    def run(laplace_move):
        cal = Calibration("M002", n_walkers=16, seed=7, laplace_move=laplace_move)
        cal.log_posterior_ = lp
        cal.names_ = [f"p{i}" for i in range(len(z0))]
        cal.priors_ = {n: Uniform(lo, hi) for n, lo, hi in zip(cal.names_, lows, highs)}
        cal.laplace_ = None
        if laplace_move:
            cal._start_laplace(lp, z0, None, np.diag(0.5 * sd))
            assert cal.laplace_["share"] == 0.0 and "adapted_at" not in cal.laplace_
        initial = z0 + np.abs(0.1 * sd * np.random.default_rng(1).standard_normal((16, len(z0))))
        sampler, report = run_ensemble(lp, initial, 16, len(z0), 3000, seed=7, moves=cal._moves(),
                                       check_every=10, warn=False, after_chunk=cal._adapt_laplace)
        return cal, sampler, report

    cal, sampler, report = run(True)
    _, _, de_only = run(False)
    assert cal.laplace_["share"] > 0, cal.laplace_
    assert report.converged and report.iterations < 0.7 * de_only.iterations, (
        report.iterations, de_only.iterations)
    burn = max(report.burn, int(cal.laplace_["adapted_at"]))
    samples = sampler.get_chain(discard=burn, flat=True)
    m, s = ref.mean(axis=0), ref.std(axis=0)
    assert np.all(np.abs(samples.mean(axis=0) - m) < 0.15 * s)
    assert np.all(np.abs(samples.std(axis=0) / s - 1) < 0.15)


def test_importance_stage_gives_the_chains_posterior_and_resumes(tmp_path, short_record):
    """With the importance stage on, M002's two thresholds on a short cycle are sampled by
    adaptive importance sampling from the start's Laplace approximation: its diagnostic says
    reliable, each 90 % interval's ends lie within 0.2 of its width of a converged chain's,
    reopening the checkpoint simulates nothing new, and draws read back from the checkpoint
    hold the run's intervals. Measured: 400 points (two rounds, Pareto k
    under 0), against a chain of 80 steps of 8 walkers; the ends within 0.07-0.10 of the
    width."""
    import warnings

    warnings.simplefilter("ignore", ConvergenceWarning)
    chain = _small(max_steps=3000).fit([short_record])
    assert chain.report_.converged and chain.importance_ is None
    drawn = _small(backend=tmp_path / "is.h5", max_steps=3000, importance=200).fit([short_record])
    rep = drawn.report_
    assert rep.method == "importance" and rep.converged and rep.pareto_k < 0.7
    assert drawn.sampler_ is None and drawn.posterior_.importance is drawn.importance_
    assert drawn.posterior_.summary()["sampler"] == "importance"
    for name in drawn.names_:
        lo, hi = chain.posterior_.interval(name)
        a, b = drawn.posterior_.interval(name)
        assert abs(a - lo) + abs(b - hi) < 0.2 * (hi - lo), (name, (a, b), (lo, hi))
    again = _small(backend=tmp_path / "is.h5", max_steps=3000, importance=200).fit([short_record])
    assert again.report_.new_steps == 0
    np.testing.assert_array_equal(again.posterior_.samples, drawn.posterior_.samples)
    # what reads a member's file (tvcid predict, the set's closure) draws from the adopted run
    from tvcid.discovery.prediction.draws import load_chain_draws

    read = load_chain_draws(tmp_path / "is.h5", n_draws=400, seed=5)
    assert read.names == tuple(drawn.names_) and read.samples.shape == (400, len(read.names))
    for j, name in enumerate(read.names):
        lo, hi = drawn.posterior_.interval(name)
        a, b = np.quantile(read.samples[:, j], (0.05, 0.95))
        assert abs(a - lo) + abs(b - hi) < 0.2 * (hi - lo), (name, (a, b), (lo, hi))


def test_interrupted_importance_stage_resumes_to_the_same_run(tmp_path, short_record,
                                                              monkeypatch):
    """Ctrl-C inside the importance stage's second round loses only that round: run again on
    the same checkpoint, the stage simulates the rounds from the second on and ends at the points
    and posterior of a run straight through."""
    import warnings

    from tvcid.discovery.calibration.importance_stage import ImportanceStage

    warnings.simplefilter("ignore", ConvergenceWarning)
    straight = _small(backend=tmp_path / "a.h5", max_steps=3000, importance=200).fit(
        [short_record])
    assert straight.report_.rounds >= 2
    original = ImportanceStage.record_log_likelihoods
    calls = {"n": 0}

    def dying(self, z):
        calls["n"] += 1
        if calls["n"] > 200 // 48 + 1:  # the first round's batches (48 points each) pass
            raise KeyboardInterrupt
        return original(self, z)

    monkeypatch.setattr(ImportanceStage, "record_log_likelihoods", dying)
    with pytest.raises(KeyboardInterrupt):
        _small(backend=tmp_path / "b.h5", max_steps=3000, importance=200).fit([short_record])
    monkeypatch.setattr(ImportanceStage, "record_log_likelihoods", original)
    resumed = _small(backend=tmp_path / "b.h5", max_steps=3000, importance=200).fit(
        [short_record])
    assert resumed.report_.new_steps == straight.report_.iterations - 200
    np.testing.assert_array_equal(resumed.importance_.points, straight.importance_.points)
    np.testing.assert_array_equal(resumed.posterior_.samples, straight.posterior_.samples)
