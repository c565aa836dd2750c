"""Results of a calibration: summaries, plots, ArviZ export, predictive bands, WAIC/BIC, ridge."""
import warnings

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from discovery.calibration import Calibration, compare, synthetic_recording  # noqa: E402
from discovery.calibration.ridge import (  # noqa: E402
    PAPER002_FAMILY_A,
    RidgeAnalysis,
    df_family,
    robust_amplitude,
)
from discovery.calibration.runner import ConvergenceWarning  # noqa: E402
from models import CONTROLLER_A, M002  # noqa: E402


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    """Short M002 and M001i fits of one 3 s window of an M002 limit cycle (noise 1e-4, seed 4)."""
    rec = synthetic_recording(M002(), CONTROLLER_A, 12.0, 1e-4, 4,
                              tmp_path_factory.mktemp("res") / "a.csv", keep_last=4.0)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for name in ("M002", "M001i"):
            out[name] = Calibration(name, params=("backlash", "dead_zone", "sigma"), window=3.0,
                                    transient=3.0, n_walkers=8, max_steps=40, seed=1).fit([rec])
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
    assert np.all(lo <= hi) and t.size == 3001
    # the true model's predictive median sits within the noise of the data
    assert comp.predictive["M002"].rms_error("a") < 1.5e-4
    assert comp.predictive["M002"].rms_error("a") < comp.predictive["M001i"].rms_error("a")
    axes = comp.plot()
    assert len(axes) == 2


def test_ridge_analysis_and_df_family(fits):
    rec, cals = fits
    post = cals["M002"].posterior_
    ridge = RidgeAnalysis({"one": post, "same again": post}, amplitude=5e-3,
                          truths={"backlash": M002().backlash, "dead_zone": M002().dead_zone})
    rows = ridge.table()
    assert len(rows) == 2 and -1 <= rows[0]["corr_log_pair"] <= 1
    assert ridge.shrinkage()["same again"]["backlash"] == pytest.approx(1.0)
    assert ridge.plot() is not None
    ax = ridge.plot(zoom=0.05)
    assert ax.get_xlim()[0] == pytest.approx(0.95 * M002().backlash)
    f, zm, source = df_family(2 * PAPER002_FAMILY_A["amplitude"])
    assert f[0] == pytest.approx(2e-4) and zm[0] == pytest.approx(2 * 1.011e-3)
    assert "MODELS.md" in source
    # with the cycle's frequency, the controller and the structure: discovery.describing's family
    f, zm, source = df_family(4.89e-3, 8.57, CONTROLLER_A, M002(), backlash=[2e-4, 4.364e-4])
    assert "paper002_family" in source
    assert zm == pytest.approx([1.111e-3, 1.333e-3], rel=2e-3)  # MODELS.md's corrected family
    assert robust_amplitude(rec.t, rec.delta) == pytest.approx(4.99e-3, rel=0.01)
