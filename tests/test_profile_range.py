"""tvcid.discovery.calibration.profile_range: the range a quantity's profile likelihood allows, read
off posterior draws, against the true 95 % profile range of known distributions."""
import numpy as np
import pytest

from tvcid.discovery.calibration.profile_range import AllowedRange, allowed_range

#: The 95 % profile range's half-width in sd for a Gaussian: sqrt(2 * 1.92).
Z95 = np.sqrt(2 * 1.92)


def _gaussian(rng, d, n=4000):
    """``n`` exact draws of a ``d``-dimensional Gaussian with a random covariance, their log
    density, and the first coordinate's sd."""
    a = rng.standard_normal((d, d))
    cov = a @ a.T + 0.1 * d * np.eye(d)
    z = rng.standard_normal((n, d))
    return z @ np.linalg.cholesky(cov).T, -0.5 * np.sum(z ** 2, axis=1), float(np.sqrt(cov[0, 0]))


@pytest.mark.parametrize("d", [2, 9, 13])
def test_the_range_is_the_gaussians_profile_range_in_any_dimension(d):
    """Ten Gaussians of ``d`` dimensions, 4000 draws each: the range is within 10 % of the true
    95 % profile range (mean +- 1.96 sd) every time."""
    rng = np.random.default_rng(100 + d)
    ratios = []
    for _ in range(10):
        x, lp, sd = _gaussian(rng, d)
        r = allowed_range(x[:, 0], lp)
        assert not (r.low_open or r.high_open)
        ratios.append((r.high - r.low) / (2 * Z95 * sd))
    assert np.all(np.abs(np.array(ratios) - 1) <= 0.10), ratios


def _banana_profile_range():
    """The true 95 % profile range of both coordinates of :func:`_banana` (on a fine grid)."""
    t = np.linspace(-12, 12, 4801)
    out = []
    for grid, profile in ((np.linspace(-8, 8, 3201), lambda v: -v ** 2 / 8),
                          (np.linspace(-5, 12, 3401),
                           lambda v: np.max(-t ** 2 / 8 - 0.5 * (v - (t ** 2 / 4 - 1)) ** 2))):
        p = np.array([profile(v) for v in grid])
        inside = grid[p >= p.max() - 1.92]
        out.append((inside[0], inside[-1]))
    return out


def test_the_range_is_a_bananas_profile_range():
    """A banana (``y1 ~ N(0, 2^2)``, ``x2 = y2 + y1^2 / 4 - 1``, ``y2 ~ N(0, 1)``), whose second
    coordinate's profile is skewed with a kink at its top: ten sets of 4000 draws, both
    coordinates' ranges within 10 % of the true profile range's width."""
    rng = np.random.default_rng(7)
    truth = _banana_profile_range()
    for _ in range(10):
        y1, y2 = 2 * rng.standard_normal(4000), rng.standard_normal(4000)
        x2 = y2 + y1 ** 2 / 4 - 1
        lp = -y1 ** 2 / 8 - 0.5 * y2 ** 2
        for values, (lo, hi) in ((y1, truth[0]), (x2, truth[1])):
            r = allowed_range(values, lp)
            assert abs((r.high - r.low) / (hi - lo) - 1) <= 0.10, (r, lo, hi)
            assert abs(r.low - lo) <= 0.1 * (hi - lo) and abs(r.high - hi) <= 0.1 * (hi - lo)


def test_an_end_the_prior_sets_is_open():
    """A likelihood flat below 2e-4 and falling as a Gaussian of sd 2e-5 above, under a
    log-uniform prior from 1e-6: the low end is open (the prior's floor), the high end is the
    bound's 1.92-nat point (2.39e-4) within 5 %; ``to_list`` gives ``[None, high]``."""
    rng = np.random.default_rng(5)
    x = np.exp(rng.uniform(np.log(1e-6), np.log(3e-3), 800_000))
    loglike = np.where(x > 2e-4, -0.5 * ((x - 2e-4) / 2e-5) ** 2, 0.0)
    kept = np.log(rng.uniform(size=x.size)) < loglike
    r = allowed_range(x[kept][:20000], loglike[kept][:20000])
    assert r.low_open and not r.high_open
    assert r.low < 1.5e-6 and r.high == pytest.approx(2.39e-4, rel=0.05)
    assert r.to_list() == [None, r.high]


def test_too_few_draws_give_no_range_and_one_value_a_point():
    assert allowed_range(np.arange(50.0), np.zeros(50)) is None
    assert allowed_range(np.full(500, 3.0), np.zeros(500)) == AllowedRange(3.0, 3.0)
    low, high = allowed_range(np.full(500, 3.0), np.zeros(500))
    assert (low, high) == (3.0, 3.0)
