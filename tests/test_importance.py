"""Adaptive importance sampling (:mod:`tvcid.discovery.calibration.importance`) on known
distributions: the moments of a correlated Gaussian from a misplaced start, and the diagnostic that
refuses a banana and a ring."""
import math

import numpy as np
import pytest

from tvcid.discovery.calibration.importance import (
    GOOD_K,
    ImportanceReport,
    StudentT,
    adaptive_importance,
    weighted_quantiles,
)
from tvcid.discovery.calibration.importance_stage import IMPORTANCE_ROUNDS, IMPORTANCE_TARGET_ESS

D = 9


def _gaussian(seed):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((D, D))
    cov = a @ a.T / D + 0.1 * np.eye(D)
    mean = rng.uniform(-1, 1, D)
    prec = np.linalg.inv(cov)

    def log_lik(z):
        d = z - mean
        return (-0.5 * np.einsum("ij,jk,ik->i", d, prec, d))[:, None]

    return mean, cov, log_lik


def _flat_prior(z):
    return np.where(np.all(np.abs(z) < 50, axis=1), 0.0, -np.inf)


def _run(log_lik, start, seed, rounds=IMPORTANCE_ROUNDS, n=400, target=IMPORTANCE_TARGET_ESS,
         **kw):
    return adaptive_importance(_flat_prior, log_lik, [1.0], start,
                               lambda j: np.random.default_rng([seed, j]), n, rounds, target, **kw)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_gaussian_moments_from_a_misplaced_start(seed):
    """Started half an sd off in every coordinate with a covariance twice too narrow, the rounds
    find the posterior: its mean within 0.2 sd and its sds within 15 % (about 3.5 standard errors
    at 300 effective points), each end of its 90 %
    intervals within 0.15 of the interval's width (at 300 effective points a 5 % quantile's
    standard error is 0.11 sd, 0.033 of the width; 108 ends are checked), and the diagnostic
    says reliable."""
    mean, cov, log_lik = _gaussian(seed)
    sd = np.sqrt(np.diag(cov))
    start = StudentT(mean + 0.5 * sd, 0.5 * cov)
    run, new = _run(log_lik, start, seed)
    assert run.reliable(IMPORTANCE_TARGET_ESS), (run.pareto_k, run.ess)
    assert new == run.n
    w = run.weights
    m = w @ run.points
    s = np.sqrt(w @ (run.points - m) ** 2)
    assert np.all(np.abs(m - mean) < 0.2 * sd)
    assert np.all(np.abs(s / sd - 1) < 0.15)
    for j in range(D):
        q = weighted_quantiles(run.points[:, j], w, (0.05, 0.95))
        exact = mean[j] + np.array([-1, 1]) * 1.6449 * sd[j]
        assert np.all(np.abs(q - exact) < 0.15 * (exact[1] - exact[0]))
    report = ImportanceReport.of(run, IMPORTANCE_TARGET_ESS)
    assert report.converged and report.n_over_tau == pytest.approx(run.ess)


def test_resumed_rounds_give_the_same_run():
    """Rounds read back from a checkpoint are not simulated again, and the run goes on to the
    same points as one run straight through."""
    mean, cov, log_lik = _gaussian(1)
    sd = np.sqrt(np.diag(cov))
    start = StudentT(mean + 0.5 * sd, 0.5 * cov)
    saved = []
    run, _ = _run(log_lik, start, 1, save=lambda j, *r: saved.append(r))
    assert len(saved) >= 2
    again, new = _run(log_lik, start, 1, stored=saved[:1])
    assert new == run.n - 400
    np.testing.assert_array_equal(again.points, run.points)
    np.testing.assert_allclose(again.log_weights, run.log_weights)


def test_a_run_capped_at_two_rounds_then_continued_is_the_run_straight_through():
    """The set's screening stops a member's importance run after two rounds; a member the
    weights keep continues from the stored rounds to the same points and weights as a run that
    was never stopped (a start a third too narrow and 1.5 sd off needs more than two rounds)."""
    mean, cov, log_lik = _gaussian(2)
    sd = np.sqrt(np.diag(cov))
    start = StudentT(mean + 1.5 * sd, 0.1 * cov)
    straight, _ = _run(log_lik, start, 2)
    saved = []
    capped, new = _run(log_lik, start, 2, rounds=2, save=lambda j, *r: saved.append(r))
    assert len(capped.counts) == 2 < len(straight.counts) and new == capped.n
    assert not capped.reliable(IMPORTANCE_TARGET_ESS)
    continued, new = _run(log_lik, start, 2, stored=saved)
    assert new == straight.n - capped.n
    np.testing.assert_array_equal(continued.points, straight.points)
    np.testing.assert_allclose(continued.log_weights, straight.log_weights)


def _banana(z):
    # Rosenbrock-like curved ridge in the first two coordinates, Gaussian elsewhere
    x, y = z[:, 0], z[:, 1]
    return (-0.5 * (x / 2.0) ** 2 - 0.5 * ((y - x**2 + 4.0) / 0.1) ** 2
            - 0.5 * np.sum(z[:, 2:] ** 2, axis=1))[:, None]


def _ring(z):
    r = np.sqrt(np.sum(z**2, axis=1))
    return (-0.5 * ((r - 5.0) / 0.1) ** 2)[:, None]


@pytest.mark.parametrize("target", [_banana, _ring])
def test_curved_targets_are_refused(target):
    """A banana and a ring in 9 dimensions cannot be covered by a t: the diagnostic says so
    (Pareto k over 0.7 or too few effective points), where a chain must take over."""
    start = StudentT(np.zeros(D), np.eye(D))
    run, _ = _run(target, start, 5)
    assert not run.reliable(IMPORTANCE_TARGET_ESS)
    assert run.pareto_k >= GOOD_K or run.ess < IMPORTANCE_TARGET_ESS
    assert math.isfinite(run.ess)


def test_bounded_laplace_covariance_holds_flat_directions_to_the_ball():
    """The importance stage's first proposal where the chain's Laplace move refuses one: the
    inverse curvature where it is within 30 ball widths, the ball's own width along a flat
    direction curving the wrong way, 30 widths along a barely curved one."""
    from tvcid.discovery.calibration.optimum import bounded_laplace_covariance

    rng = np.random.default_rng(4)
    v = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    ball = np.diag([1e-2, 1e-3, 1e-4]) ** 2
    b = np.sqrt(ball)
    sd_w = np.array([0.5, 3.0, 100.0])  # in ball units: tighter, wider, far wider than 30
    inner = (v / sd_w**2) @ v.T
    hess = -np.linalg.inv(b) @ inner @ np.linalg.inv(b)
    cov = bounded_laplace_covariance(hess, ball)
    w = np.linalg.inv(b) @ cov @ np.linalg.inv(b)
    got = np.sqrt(np.sort(np.linalg.eigvalsh(w)))
    np.testing.assert_allclose(got, [0.5, 3.0, 30.0], rtol=1e-6)
    inner_flat = (v * np.array([4.0, 1 / 9, -1.0])) @ v.T  # one direction curving the wrong way
    flat = -np.linalg.inv(b) @ inner_flat @ np.linalg.inv(b)
    w = np.linalg.inv(b) @ bounded_laplace_covariance(flat, ball) @ np.linalg.inv(b)
    np.testing.assert_allclose(np.sqrt(np.sort(np.linalg.eigvalsh(w))), [0.5, 1.0, 3.0],
                               rtol=1e-6)
    assert bounded_laplace_covariance(np.full((3, 3), np.nan), ball) is None
