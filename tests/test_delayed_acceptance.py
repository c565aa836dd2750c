"""Delayed acceptance (discovery/calibration/delayed_acceptance.py): the chain samples the true
posterior whatever the surrogate, with DE, stretch and Metropolis-Hastings inner moves; a
surrogate equal to the target changes nothing but the number of simulations; the true log
probability sees only the first stage's survivors; blobs, non-finite surrogates and seeds."""
import warnings

import emcee
import numpy as np
import pytest

from tvcid.discovery.calibration.delayed_acceptance import DelayedAcceptanceMove

MEAN = np.array([1.0, -2.0, 0.5])
SD = np.array([1.0, 2.0, 0.5])
CORR = np.array([[1.0, 0.6, 0.3], [0.6, 1.0, -0.4], [0.3, -0.4, 1.0]])
COV = CORR * np.outer(SD, SD)
NWALKERS = 32


def _gaussian(mean, cov):
    """Vectorised log density (up to a constant) of a Gaussian."""
    whiten = np.linalg.inv(np.linalg.cholesky(cov))
    ndim = len(mean)

    def logp(x):
        d = np.atleast_2d(x) - mean
        # elementwise operations only: a row's value has the same bits in any batch, so that a
        # surrogate equal to the target gives second-stage ratios of exactly one
        z = [sum(whiten[i, j] * d[:, j] for j in range(ndim)) for i in range(ndim)]
        return -0.5 * sum(zi * zi for zi in z)

    return logp


TARGET = _gaussian(MEAN, COV)
# wrong on purpose: the mean half a standard deviation off, the first axis' variance doubled
_STRETCH = np.diag([np.sqrt(2.0), 1.0, 1.0])
WRONG = _gaussian(MEAN + 0.5 * SD, _STRETCH @ COV @ _STRETCH)


def _start(mean, cov, seed, n=NWALKERS):
    return mean + np.random.default_rng(seed).standard_normal((n, len(mean))) @ \
        np.linalg.cholesky(cov).T


def _run(move, logp, p0, nsteps, seed, vectorize=True):
    """A seeded run: emcee 3.1's sampler takes its RandomState from the initial State."""
    sampler = emcee.EnsembleSampler(len(p0), p0.shape[1], logp, moves=[(move, 1.0)],
                                    vectorize=vectorize)
    sampler.run_mcmc(emcee.State(p0, random_state=np.random.RandomState(seed).get_state()),
                     nsteps)
    return sampler


def _z_scores(series, expected):
    """``(mean - expected) / standard error`` of each column of ``series`` (nsteps, nwalkers, k),
    the effective sample size from emcee's integrated autocorrelation time."""
    tau = emcee.autocorr.integrated_time(series, quiet=True)
    flat = series.reshape(-1, series.shape[-1])
    se = flat.std(axis=0) / np.sqrt(len(flat) / tau)
    return (flat.mean(axis=0) - expected) / se


def _inner(name):
    if name == "DEMove":
        return emcee.moves.DEMove()
    if name == "StretchMove":
        return emcee.moves.StretchMove()
    if name == "DESnookerMove":
        return emcee.moves.DESnookerMove()
    # a diagonal covariance: with a full matrix emcee's GaussianMove draws one displacement and
    # adds it to every walker, so the walkers are not independent chains and the ensemble's
    # autocorrelation time understates the mean's error
    return emcee.moves.GaussianMove(0.5 * np.diag(COV))


INNER = ["DEMove", "StretchMove", "GaussianMove"]


@pytest.mark.parametrize("inner", INNER)
def test_gaussian_moments_with_a_wrong_surrogate(inner):
    # measured |z| <= 2.1 and covariance errors <= 0.04 sd_i sd_j for the three inner moves;
    # sampling the surrogate instead would put the mean 0.5 sd, some 20 standard errors, off
    move = DelayedAcceptanceMove(_inner(inner), WRONG)
    sampler = _run(move, TARGET, _start(MEAN, COV, 11), 3000, seed=12)
    chain = sampler.get_chain(discard=500)
    assert np.all(np.abs(_z_scores(chain, MEAN)) < 4.0)
    cov = np.cov(chain.reshape(-1, 3), rowvar=False)
    assert np.all(np.abs(cov - COV) < 0.15 * np.outer(SD, SD))
    assert move.n_proposed == move.n_screened_out + move.n_evaluated
    assert 0 < move.n_accepted < move.n_evaluated < move.n_proposed


def test_banana_moments():
    # x1 ~ N(0, 1), x2 | x1 ~ N(b x1^2, 1): E x2 = b, var x2 = 1 + 2 b^2
    b = 0.5

    def banana(x):
        return -0.5 * x[:, 0] ** 2 - 0.5 * (x[:, 1] - b * x[:, 0] ** 2) ** 2

    mean, var = np.array([0.0, b]), np.array([1.0, 1.0 + 2.0 * b * b])
    # a moment-matched Gaussian, widened 1.5x in variance; sampled alone its variances are
    # 1.5x the banana's
    surrogate = _gaussian(mean, np.diag(1.5 * var))
    move = DelayedAcceptanceMove(emcee.moves.DEMove(), surrogate)
    sampler = _run(move, banana, _start(mean, np.diag(var), 21), 3000, seed=22)
    chain = sampler.get_chain(discard=500)
    # measured z of the means 2.2 and -0.2, of x1's variance 0.9; x2's variance 4.5 % high
    assert np.all(np.abs(_z_scores(chain, mean)) < 4.0)
    assert abs(_z_scores((chain[..., :1] - mean[0]) ** 2, var[:1])[0]) < 4.0
    # x2's squared deviations have heavy tails and their autocorrelation time is underestimated
    # (z of x2's variance spread over -3.2..2.3 on eight seeds): a relative bound instead
    assert abs(chain[..., 1].var() / var[1] - 1.0) < 0.2


@pytest.mark.parametrize("inner", INNER + ["DESnookerMove"])
def test_exact_surrogate_passes_every_survivor(inner):
    # the first stage is then the inner move's own test and the second accepts with probability
    # one (the stretch and snooker moves' proposal ratios in the second stage instead would
    # reject some survivors)
    move = DelayedAcceptanceMove(_inner(inner), TARGET)
    p0 = _start(MEAN, COV, 31)
    da = _run(move, TARGET, p0, 300, seed=32)
    plain = _run(_inner(inner), TARGET, p0, 300, seed=32)
    assert move.n_accepted == move.n_evaluated > 0
    assert abs(da.acceptance_fraction.mean() - plain.acceptance_fraction.mean()) < 0.02
    # the second stage makes no draw at a ratio of one, so the random stream, and the chain, are
    # the plain move's to the bit
    assert np.array_equal(da.get_chain(), plain.get_chain())


def test_good_surrogate_saves_evaluations():
    move = DelayedAcceptanceMove(emcee.moves.DEMove(), _gaussian(MEAN, 1.2 * COV))
    sampler = _run(move, TARGET, _start(MEAN, COV, 41), 1000, seed=42)
    # measured 0.35 (plain DEMove's acceptance is 0.32: the surrogate screens out nearly every
    # proposal the target would reject)
    assert move.evaluated_fraction < 0.45
    # and the acceptance is the plain move's (measured 0.32 both)
    assert sampler.acceptance_fraction.mean() > 0.28


def test_true_log_prob_sees_only_survivors():
    class Counted:
        rows = 0

        def __call__(self, x):
            self.rows += len(x)
            return TARGET(x)

    target = Counted()
    move = DelayedAcceptanceMove(emcee.moves.StretchMove(), WRONG)
    _run(move, target, _start(MEAN, COV, 51), 300, seed=52)
    # the initial state's NWALKERS evaluations, then the survivors alone
    assert target.rows == move.n_evaluated + NWALKERS
    assert move.n_evaluated < move.n_proposed == 300 * NWALKERS


def test_blobs_follow_accepted_points():
    # not vectorised: emcee maps over the rows and reads the blobs after the log probability
    def logp(x):
        return TARGET(x)[0], x.sum(), 2.0 * x[0]

    move = DelayedAcceptanceMove(emcee.moves.DEMove(), WRONG)
    sampler = _run(move, logp, _start(MEAN, COV, 61), 200, seed=62, vectorize=False)
    chain, blobs = sampler.get_chain(), sampler.get_blobs()
    assert blobs.shape == (200, NWALKERS, 2)
    assert np.allclose(blobs[..., 0], chain.sum(axis=-1))
    assert np.allclose(blobs[..., 1], 2.0 * chain[..., 0])
    assert np.allclose(sampler.get_log_prob(), TARGET(chain.reshape(-1, 3)).reshape(200, -1))
    assert 0 < move.n_accepted < move.n_proposed


def test_non_finite_surrogate():
    def target(x):
        return -0.5 * np.sum(x * x, axis=1)

    nan_rows = []

    def surrogate(x):
        s = target(x)
        s[x[:, 0] > 2.0] = -np.inf
        s[x[:, 0] < -2.5] = np.nan
        nan_rows.append(int(np.sum(x[:, 0] < -2.5)))
        return s

    n = 16
    p0 = np.random.default_rng(71).uniform(-1.0, 1.0, size=(n, 2))
    p0[: n // 2, 0] += 3.0  # where the surrogate is -inf
    move = DelayedAcceptanceMove(emcee.moves.DEMove(), surrogate)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        sampler = _run(move, target, p0, 300, seed=72)
    x0 = np.concatenate([p0[None, :, 0], sampler.get_chain()[..., 0]])
    # the walkers that start outside leave it by a step on the target and never come back; no
    # walker enters where the surrogate is NaN
    inside = x0 <= 2.0
    assert inside[-1].all()
    assert np.array_equal(np.maximum.accumulate(inside, axis=0), inside)
    assert np.all(x0 >= -2.5)
    # measured: 422 proposals where the surrogate is NaN; the walkers outside leave in 1-9 steps
    assert sum(nan_rows) > 0
    assert np.all(np.isfinite(sampler.get_log_prob()))


def test_seeded_runs_repeat():
    def run(seed):
        move = DelayedAcceptanceMove(emcee.moves.DEMove(), WRONG)
        sampler = _run(move, TARGET, _start(MEAN, COV, 81), 100, seed=seed)
        return sampler.get_chain(), move.n_evaluated

    (a, na), (b, nb), (c, _) = run(82), run(82), run(83)
    assert np.array_equal(a, b) and na == nb
    assert not np.array_equal(a, c)


def test_rejects_other_moves():
    with pytest.raises(TypeError):
        DelayedAcceptanceMove(emcee.moves.Move(), TARGET)
