"""Model discrepancy: the likelihood's inflation at the MAP and the posterior predictive check.

A right model keeps inflation 1 (its intervals unchanged) and passes the check; a wrong one
(here: M002's linear block 30 % off on an M002 open-loop test) is inflated, gets wider intervals,
and fails the check.
"""
import warnings

import numpy as np
import pytest

from tvcid.discovery.calibration import Calibration
from tvcid.discovery.calibration.checks import predictive_check
from tvcid.discovery.calibration.likelihood import features_inflation, waveform_inflation
from tvcid.discovery.calibration.runner import ConvergenceWarning


def test_white_residuals_are_not_inflated():
    """White noise of the assumed sd: factor 1 in 20 of 20 seeds (each factor triggers beyond
    three standard errors). Standard normal features: factor 1 exactly when their chi-square is
    within its 95 % quantile, else one plus the excess per feature; about 1 seed in 20 exceeds."""
    for seed in range(20):
        r = np.random.default_rng(seed).standard_normal(4000) * 2e-5
        assert waveform_inflation(r, 2e-5) == 1.0
    q = 11.0705  # chi2(5) 95 % quantile
    exceeded = 0
    for seed in range(40):
        z = np.random.default_rng(seed).standard_normal(5)
        chi2 = float(np.sum(z**2))
        expected = 1.0 if chi2 <= q else 1.0 + (chi2 - q) / 5
        assert features_inflation(z) == pytest.approx(expected, rel=1e-4), (seed, chi2)
        exceeded += chi2 > q
    assert 0 < exceeded <= 6


def test_correlated_excess_is_inflated_by_its_variance_and_correlation():
    """AR(1) residuals with rho = 0.9 and twice the noise sd: 4 x the integrated autocorrelation
    time (1 + rho) / (1 - rho) = 76."""
    rng = np.random.default_rng(3)
    e = rng.standard_normal(20000)
    r = np.empty_like(e)
    r[0] = e[0]
    for i in range(1, r.size):
        r[i] = 0.9 * r[i - 1] + np.sqrt(1 - 0.81) * e[i]
    assert waveform_inflation(2.0 * r, 1.0) == pytest.approx(76.0, rel=0.2)
    # features: the chi-square's excess over its 95 % quantile (11.07 for k = 5), per feature
    assert features_inflation(np.full(5, 10.0)) == pytest.approx(1.0 + (500.0 - 11.0705) / 5, rel=1e-4)


def test_features_inflation_starts_from_one_at_the_tests_threshold():
    """No jump at the threshold: a chi-square just past the 95 % quantile inflates by almost
    nothing (the rule before jumped to chi2 / k = 2.2 there); the factor grows with the excess."""
    k, q = 5, 11.0705
    below = np.full(k, np.sqrt((q - 0.01) / k))
    above = np.full(k, np.sqrt((q + 0.01) / k))
    assert features_inflation(below) == 1.0
    assert 1.0 < features_inflation(above) < 1.01
    factors = [features_inflation(np.full(k, np.sqrt(c / k))) for c in (15.0, 30.0, 100.0)]
    assert factors == sorted(factors) and factors[0] == pytest.approx(1.0 + (15.0 - q) / k, rel=1e-4)


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    from tvcid.models import M002, OpenLoop
    from tvcid.models.synthetic import synthetic_recording

    path = tmp_path_factory.mktemp("mismatch") / "square.csv"
    return synthetic_recording(M002(), OpenLoop.square(0.02, 1.0), 4.0, 2e-5, 5, path)


def _fit(rec, gain_factor, discrepancy, max_steps=150):
    from tvcid.models import M002

    base = M002()
    base = base.replace(gain=base.gain * gain_factor)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return Calibration(base, params=("dead_zone", "backlash", "delay"), n_walkers=12,
                           max_steps=max_steps, seed=1, discrepancy=discrepancy).fit([rec])


def test_right_model_unchanged_and_passes_the_check(square):
    cal = _fit(square, 1.0, True)
    assert cal.inflation_ == [1.0]
    check = predictive_check(cal, n_draws=16)
    assert check.passes, check.to_dict()


def test_wrong_model_is_inflated_widened_and_flagged(square):
    """K1 30 % high: the misfit is smooth and far above the noise; the inflation widens every
    interval at least 3x over the uninflated posterior (a needle whose backlash sits at its
    prior's upper bound, 1 % wide; the differential-evolution moves alone stay in a local needle
    at the dead zone's lower bound, 5.7 million nats below it), and the check fails the
    recording."""
    plain = _fit(square, 1.3, False, max_steps=400)
    # the wide posterior needs the steps to be mapped: after 150 (tau ~17) its walkers had not
    # yet left the backlash's upper end, after 600 its 90 % interval spans most of the prior
    honest = _fit(square, 1.3, True, max_steps=600)
    assert honest.inflation_[0] > 10.0
    # without the term: a needle against the dead zone's lower prior bound; with it: not stuck
    assert plain.posterior_.at_prior_bound() == ["backlash"]
    assert honest.posterior_.at_prior_bound() == []
    for n in ("dead_zone", "backlash", "delay"):
        w_plain = np.subtract(*plain.posterior_.interval(n)[::-1])
        w_honest = np.subtract(*honest.posterior_.interval(n)[::-1])
        assert w_honest > 3.0 * w_plain, (n, w_plain, w_honest)
    check = predictive_check(honest, n_draws=16)
    assert not check.passes
    (row,) = check.recordings
    assert row.statistics["lag1_autocorrelation"] > 0.5 and row.p_value < 1e-6


BUNDLED = ["data/m000_closed_A.csv", "data/m000_closed_B.csv", "data/m000_open_square.csv",
           "data/m000_open_sine.csv"]


@pytest.mark.slow
@pytest.mark.parametrize("hypothesis, params, fixed, passes", [
    ("M002", ("dead_zone", "backlash", "delay"), {}, False),
    ("M000", ("dead_zone", "backlash", "delay", "friction_offset"), {"noise_power": 4e-13}, True),
])
def test_bundled_records_wrong_structure_flagged_right_one_passes(hypothesis, params, fixed,
                                                                   passes):
    """The mismatch check on the bundled M000 records (both limit cycles, both open-loop
    tests): M002's structure has no parameter at a prior bound and fails the check on every
    record; M000's own model (its in-loop noise as data/generate.py made the records) passes on
    every record (150 steps)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        cal = Calibration(hypothesis, params=params, fixed=fixed, likelihood="features",
                          max_steps=150, seed=2).fit(BUNDLED)
    assert cal.posterior_.at_prior_bound() == []
    check = predictive_check(cal)
    assert [r.passes for r in check.recordings] == [passes] * 4, check.to_dict()


def test_a_point_short_of_the_maximum_is_not_read_as_discrepancy(square):
    """The factor is measured where the searches stopped. From a point off the maximum (dead zone
    +15 %, backlash -15 %, delay +5 %; the right model) the factor is over 1; the short ensemble
    run (``Calibration._scout``) finds a better point, where the factor is 1 (coverage draw 23:
    30 at the searches' point, 1.0 at the truth)."""
    from tvcid.models import M002

    truth = M002()
    cal = Calibration(truth, params=("dead_zone", "backlash", "delay"), n_walkers=12,
                      seed=1).setup([square])
    lp = cal.log_posterior_
    off = lp.internal(np.array([[truth.dead_zone * 1.15, truth.backlash * 0.85,
                                 truth.delay * 1.05]]))[0]
    factors = cal._inflations_at(lp, off)
    assert max(factors) > 1.0, factors
    for term, value in zip(cal.terms_, factors):
        term.inflation = value
    z = cal._scout(lp, off, np.random.default_rng(0))
    assert z is not None
    assert cal._inflations_at(lp, z) == [1.0]
    assert [t.inflation for t in cal.terms_] == factors  # restored: the caller sets them


def test_a_sampled_noise_sd_does_not_undo_the_inflation(square):
    """Where the noise sd is sampled (``"sigma"``), the inflation must not be absorbed by it. An
    inflated variance ``sigma^2 f`` would be: its maximum over ``sigma`` moves to
    ``sqrt(RSS / n f)``, and the physical parameters' curvature there is what it is without the
    term (coverage draw 18, an open-loop factor of 1.36: intervals 4-7 % narrower with the term
    than without). The
    tempered likelihood keeps the noise sd's maximum where it is and divides the physical
    parameters' curvature by ``f``."""
    from tvcid.models import M002

    base = M002()
    base = base.replace(gain=base.gain * 1.3)  # a wrong model: a smooth misfit over the noise
    cal = Calibration(base, params=("dead_zone", "sigma"), n_walkers=12, seed=1).setup([square])
    term = cal.terms_[0]
    sigmas = np.geomspace(1e-5, 1e-1, 1201)
    near = [base.replace(dead_zone=base.dead_zone * (1 + e)) for e in (-0.02, 0.0, 0.02)]

    def profile(f):
        term.inflation = f
        ll = term.loglike([base] * sigmas.size, sigmas)
        best = sigmas[int(np.argmax(ll))]
        at = term.loglike(near, np.full(3, best))
        return best, at[0] + at[2] - 2.0 * at[1]

    (s1, c1), (s4, c4) = profile(1.0), profile(4.0)
    term.inflation = 1.0
    assert 2e-5 < s1 < 0.09  # inside the grid: the misfit's rms
    assert s4 == pytest.approx(s1, rel=0.02)  # inflated variance: s4 = s1 / 2
    assert c4 == pytest.approx(c1 / 4.0, rel=0.05)
