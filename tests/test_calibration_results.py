"""Results of a calibration: summaries, plots, ArviZ export, predictive bands, WAIC/BIC, ridge."""
import warnings

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tvcid.discovery.calibration import Calibration, compare  # noqa: E402
from tvcid.discovery.calibration.ridge import (  # noqa: E402
    PAPER002_FAMILY_A,
    RidgeAnalysis,
    df_family,
)
from tvcid.discovery.calibration.runner import ConvergenceWarning  # noqa: E402
from tvcid.models import CONTROLLER_A, M002  # noqa: E402
from tvcid.models.cycle_reading import robust_amplitude  # noqa: E402
from tvcid.models.synthetic import synthetic_recording  # noqa: E402


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    """Short M002 and M001i fits of one 3 s window of an M002 limit cycle (noise 1e-4, seed 4)."""
    rec = synthetic_recording(M002(), CONTROLLER_A, 12.0, 1e-4, 4,
                              tmp_path_factory.mktemp("res") / "a.csv", keep_last=4.0)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for name in ("M002", "M001i"):
            # the models' own likelihoods, uninflated: the comparison and the predictive bands
            # below are about them (the discrepancy term: tests/test_calibration_mismatch.py);
            # one likelihood for both (M001i's cycle attracts slowly enough to fall back to its
            # features, and likelihoods that differ cannot be compared)
            out[name] = Calibration(name, params=("backlash", "dead_zone", "sigma"), window=3.0,
                                    transient=3.0, n_walkers=8, max_steps=40, seed=1,
                                    discrepancy=False, features_fallback=False).fit([rec])
    return rec, out


def test_summary_plots_and_inference_data(fits):
    _, cals = fits
    post = cals["M002"].posterior_
    s = post.summary()
    assert set(s["parameters"]) == {"backlash", "dead_zone", "sigma"}
    assert s["correlation"]["coordinates"] == ["log", "log", "log"]
    assert s["parameters"]["backlash"]["truth"] == pytest.approx(M002().backlash)
    fig = post.plot_corner()
    assert len(fig.axes) == 9
    axes = post.plot_traces()
    assert len(axes) == 3
    idata = post.to_inference_data()
    assert set(idata.posterior.data_vars) == {"backlash", "dead_zone", "sigma"}
    assert idata.posterior.sizes["chain"] == 8
    assert np.all(idata.posterior["dead_zone"].values > 0)


def test_compare_prefers_the_true_hypothesis(fits):
    rec, cals = fits
    comp = compare(cals, n_draws=40)
    rows = {r["model"]: r for r in comp.table}
    assert set(rows) == {"M002", "M001i"}
    for r in rows.values():
        assert np.isfinite(r["waic"]) and np.isfinite(r["bic"]) and r["n"] == 3001
    assert comp.best("waic") == "M002" and comp.best("bic") == "M002"
    t, lo, med, hi = comp.predictive["M002"].band("a")
    assert t.size == 3001
    # the data lie within the true model's 90 % band widened by 2 noise sd (1e-4) at about the
    # Gaussian rate, 95.4 % (measured 95.6 %), and within the wrong model's far less often (48 %)
    for name, lo_frac, hi_frac in (("M002", 0.93, 1.0), ("M001i", 0.0, 0.8)):
        _, lo, _, hi = comp.predictive[name].band("a")
        data = comp.predictive[name].curves["a"][1]
        inside = np.mean((data > lo - 2e-4) & (data < hi + 2e-4))
        assert lo_frac < inside < hi_frac, (name, inside)
    # the true model's predictive median sits within the noise of the data
    assert comp.predictive["M002"].rms_error("a") < 1.5e-4
    assert comp.predictive["M002"].rms_error("a") < comp.predictive["M001i"].rms_error("a")
    axes = comp.plot()
    assert len(axes) == 2
    # a record that entered through its features in one model cannot be compared with the other
    cals["M001i"].likelihoods_ = {"a": "features"}
    try:
        with pytest.raises(ValueError, match="entered through different likelihoods .* "
                                             "features_fallback=False"):
            compare(cals, n_draws=40)
    finally:
        cals["M001i"].likelihoods_ = {"a": "waveform"}


def test_ridge_analysis_on_samples_of_known_correlation_and_width(fits):
    """RidgeAnalysis's numbers against samples whose answers are known: (ln f, ln zm, ln sigma)
    drawn with sd 0.3 and corr(ln f, ln zm) = 0.9, then the same draws shrunk 10x about their
    centre. Expected: the 90 % width relative to the median is 2 sinh(1.645 sd), so 1.027 and
    0.0987, a shrinkage of 0.0961; 20 000 draws leave about 1 % sampling error."""
    from dataclasses import replace

    _, cals = fits
    post = cals["M002"].posterior_
    assert post.names == ("backlash", "dead_zone", "sigma")
    rng = np.random.default_rng(0)
    cov = 0.3**2 * np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 1.0]])
    z = rng.multivariate_normal(np.zeros(3), cov, 20_000)
    centre = np.log([M002().backlash, M002().dead_zone, 1e-4])
    wide = replace(post, samples=np.exp(centre + z), internal=centre + z)
    narrow = replace(post, samples=np.exp(centre + z / 10), internal=centre + z / 10)
    truths = {"backlash": 1.2 * M002().backlash, "dead_zone": M002().dead_zone}
    ridge = RidgeAnalysis({"wide": wide, "narrow": narrow}, amplitude=5e-3, truths=truths)
    wide_row, narrow_row = ridge.table()
    assert wide_row["corr_log_pair"] == pytest.approx(0.9, abs=0.01)
    assert narrow_row["corr_log_pair"] == pytest.approx(0.9, abs=0.01)
    for name in post.names:
        assert wide_row["width90_relative"][name] == pytest.approx(2 * np.sinh(1.645 * 0.3), rel=0.03)
        assert ridge.shrinkage()["narrow"][name] == pytest.approx(
            np.sinh(1.645 * 0.03) / np.sinh(1.645 * 0.3), rel=0.03)
    # a truth 20 % off the centre: inside the wide interval (-39 %, +64 %), outside the narrow one
    assert wide_row["truth_inside_90"] == {"backlash": True, "dead_zone": True}
    assert narrow_row["truth_inside_90"] == {"backlash": False, "dead_zone": True}
    # the plot draws each data set's samples and the DF family for the given amplitude
    ax = ridge.plot()
    labels = [line.get_label() for line in ax.lines]
    assert labels[:2] == ["wide (corr ln 0.90)", "narrow (corr ln 0.90)"]
    family = ax.lines[labels.index("DF family (paper 002)")]
    np.testing.assert_allclose(family.get_xdata(), df_family(5e-3)[0])
    np.testing.assert_allclose(family.get_ydata(), df_family(5e-3)[1])
    zoomed = ridge.plot(zoom=0.05)
    assert zoomed.get_xlim() == pytest.approx((0.95 * truths["backlash"], 1.05 * truths["backlash"]))
    import matplotlib.pyplot as plt

    plt.close(ax.figure)
    plt.close(zoomed.figure)


def test_df_family_and_robust_amplitude(fits):
    rec, _ = fits
    f, zm, source = df_family(2 * PAPER002_FAMILY_A["amplitude"])
    assert f[0] == pytest.approx(2e-4) and zm[0] == pytest.approx(2 * 1.011e-3)
    assert "scaled by homogeneity" in source  # the tabulated family of docs/models.md#errata
    # with the cycle's frequency, the controller and the structure: tvcid.discovery.describing's family
    f, zm, source = df_family(4.89e-3, 8.57, CONTROLLER_A, M002(), backlash=[2e-4, 4.364e-4])
    assert "paper002_family" in source
    # docs/models.md#errata's corrected family
    assert zm == pytest.approx([1.111e-3, 1.333e-3], rel=2e-3)
    # docs/models.md#reference-limit-cycles: M002 at controller A, (max - min)/2 = 4.991e-3 rad
    assert robust_amplitude(rec.t, rec.delta) == pytest.approx(4.99e-3, rel=0.01)


def test_a_narrow_posterior_clear_of_a_near_bound_is_not_at_it():
    """``at_prior_bound``: a needle pressed against a bound is stuck; the same needle a few of its
    widths inside a wide prior (M000's delay, 1.70-1.72 ms in a prior from 1.2 to 20 ms) is not;
    a wide posterior reaching a bound is not."""
    from types import SimpleNamespace

    from tvcid.discovery.calibration.posterior import Posterior
    from tvcid.discovery.calibration.priors import Uniform

    rng = np.random.default_rng(0)
    prior = Uniform(1.2e-3, 2e-2)

    def stuck(samples):
        post = Posterior.__new__(Posterior)
        post.names, post.internal = ("delay",), np.asarray(samples)[:, None]
        post.calibration = SimpleNamespace(log_posterior_=SimpleNamespace(priors=[prior]))
        return post.at_prior_bound()

    assert stuck(1.7e-3 + 6e-6 * rng.standard_normal(2000)) == []
    assert stuck(1.2e-3 + np.abs(6e-6 * rng.standard_normal(2000))) == ["delay"]
    assert stuck(2e-2 - np.abs(6e-6 * rng.standard_normal(2000))) == ["delay"]
    assert stuck(rng.uniform(1.2e-3, 1.2e-2, 2000)) == []
