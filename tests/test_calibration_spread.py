"""Initial walkers along the posterior's principal axes (``Calibration(spread="hessian")``).

On a Gaussian whose covariance is known, the axes from the finite-difference Hessian reproduce
the covariance; along a direction the prior box cuts short (a ridge) the spread is a quarter of
the box's extent there, not the axis-wise sd that leaves the walkers in a thin ball.
"""
import numpy as np
import pytest

from tvcid.discovery.calibration.optimum import (
    _axis_scales,
    _box_extent,
    _hessian,
    _principal_axes,
)
from tvcid.discovery.calibration.testing import GaussianLogProb


class _Box:
    def __init__(self, low, high):
        self.internal_bounds = (low, high)


class _LP:
    def __init__(self, cov, half_width):
        self.g = GaussianLogProb(np.zeros(len(cov)), cov)
        self.priors = [_Box(-half_width, half_width) for _ in cov]

    def __call__(self, z):  # one point -> a float, a batch -> an array (as LogPosterior)
        zz = np.atleast_2d(z)
        inside = np.all(np.abs(zz) <= self.priors[0].internal_bounds[1], axis=1)
        out = np.where(inside, self.g(zz), -np.inf)
        return float(out[0]) if np.ndim(z) == 1 else out


@pytest.mark.parametrize("rho", [0.0, 0.9, 0.999])
def test_axes_reproduce_a_known_covariance(rho):
    """A A^T equals the covariance within 2 % (entries relative to the largest) when the box is
    far away; the axis-wise sds alone give sd * sqrt(1 - rho^2), 22x too thin at rho = 0.999."""
    sd = np.array([1.0, 3.0, 0.5])
    corr = np.array([[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 1.0]])
    cov = corr * np.outer(sd, sd)
    lp = _LP(cov, half_width=1e3)
    z0 = np.zeros(3)
    scale = _axis_scales(lp, z0)
    np.testing.assert_allclose(scale[:2], sd[:2] * np.sqrt(1 - rho**2), rtol=0.05)
    axes = _principal_axes(lp, z0, scale, _hessian(lp, z0, scale))
    np.testing.assert_allclose(axes @ axes.T, cov, atol=0.02 * np.max(cov))


class _Ridge:
    """Flat along z0 = z1 inside the box [-4, 4]^2, sd 0.01 across it."""

    priors = [_Box(-4.0, 4.0), _Box(-4.0, 4.0)]

    def __call__(self, z):
        zz = np.atleast_2d(z)
        inside = np.all(np.abs(zz) <= 4.0, axis=1)
        out = np.where(inside, -0.5 * ((zz[:, 0] - zz[:, 1]) / 0.01) ** 2, -np.inf)
        return float(out[0]) if np.ndim(z) == 1 else out


def test_a_ridge_is_spread_over_the_prior_box():
    """A flat direction (rank-deficient precision) gets a quarter of the box's extent along it."""
    lp = _Ridge()
    z0 = np.zeros(2)
    scale = _axis_scales(lp, z0)
    axes = _principal_axes(lp, z0, scale, _hessian(lp, z0, scale))
    lengths = np.linalg.norm(axes, axis=0)
    ridge = axes[:, np.argmax(lengths)]
    assert abs(abs(ridge[0]) - abs(ridge[1])) < 1e-6 * np.max(lengths)  # along z0 = z1
    # the diagonal crosses the box [-4, 4]^2 over a length 8 sqrt(2); a quarter of it
    np.testing.assert_allclose(np.max(lengths), 0.25 * 8 * np.sqrt(2), rtol=1e-6)
    np.testing.assert_allclose(np.min(lengths), 0.01 / np.sqrt(2), rtol=0.05)


def test_box_extent_of_a_line():
    lows, highs = np.array([-1.0, -2.0]), np.array([1.0, 2.0])
    assert _box_extent(np.zeros(2), np.array([1.0, 0.0]), lows, highs) == pytest.approx(2.0)
    assert _box_extent(np.array([0.5, 0.0]), np.array([0.0, 1.0]), lows, highs) == pytest.approx(4.0)
    assert _box_extent(np.zeros(2), np.array([1.0, 1.0]), lows, highs) == pytest.approx(2.0)


def test_unknown_spread_is_named():
    from tvcid.discovery.calibration import Calibration

    with pytest.raises(ValueError, match="spread must be 'axes' or 'hessian'"):
        Calibration("M002", params=("dead_zone",), spread="ball").setup(["data/m000_closed_A.csv"])
