"""discovery.structure.set_posterior: the linear block's DC gain and bandwidth, the members'
quantities, and their equal-weight mixture with the structure-dependence rule."""
import numpy as np
import pytest
from scipy import signal

from discovery.structure.set_posterior import (
    STRUCTURE_DEPENDENCE,
    MemberPosterior,
    combine,
    linear_block_dc_gain_and_bandwidth,
    member_quantities,
)
from models import M000, M002


@pytest.mark.parametrize("params", [M000(), M002()])
def test_dc_gain_and_bandwidth_are_those_of_the_position_loop(params):
    """``1/K`` and the -3 dB frequency of ``K1/(s^3 + K2 s^2 + K3 s + K K1)``, checked against
    scipy's frequency response on a fine grid (0.1 % apart at most)."""
    k1, k2, k3, k = params.gain, params.damping, params.stiffness, params.feedback_gain
    dc, bw = linear_block_dc_gain_and_bandwidth(k1, k2, k3, k)
    w = np.logspace(0, 4, 200_000)
    _, h = signal.freqs([k1], [1.0, k2, k3, k * k1], worN=w)
    reference = w[np.argmax(np.abs(h) * k < 1 / np.sqrt(2))]
    assert dc[0] == pytest.approx(1 / k)
    assert bw[0] == pytest.approx(reference, rel=1e-3)


def test_member_quantities_take_draws_and_fill_the_rest_from_the_fit():
    """Sampled fields come from the draws, the others from the fit; the velocity form's
    threshold is ``z - off``; a member without friction has offset 0."""
    params = M000().to_dict()
    draws = {"dead_zone": np.array([0.008, 0.009]), "delay": np.array([0.001, 0.002])}
    q = member_quantities(params, draws)
    assert np.allclose(q["dead_zone[velocity]"], [0.008, 0.009])
    assert np.allclose(q["threshold"], np.array([0.008, 0.009]) - params["friction_offset"])
    assert np.allclose(q["backlash"], params["backlash"]) and np.allclose(q["delay"], [0.001, 0.002])
    error = member_quantities(M002().to_dict(), {"delay": np.array([0.007])})
    assert "dead_zone[error]" in error and "threshold" not in error


def _member(name, centre, sd, rng, n=4000):
    values = centre + sd * rng.standard_normal(n)
    return MemberPosterior(name, {"delay": values, "backlash": np.full(n, 1e-4)}, {"converged": True},
                           0.5)


def test_equal_weights_mix_the_members_and_flag_disagreement():
    """Two members whose delays disagree by many of their own widths: the combined interval
    spans both and the delay depends on the structure; two that agree: decided regardless. The
    mixture's median lies between the members'; each member keeps its own quantiles."""
    rng = np.random.default_rng(0)
    apart = combine([_member("a", 2e-3, 1e-5, rng), _member("b", 3e-3, 1e-5, rng)], seed=1)
    d = apart.quantities["delay"]
    assert d["q05"] < 2.01e-3 and d["q95"] > 2.99e-3 and 2e-3 < d["q50"] < 3e-3
    assert d["depends_on_structure"] and d["spread_over_width"] > 10
    together = combine([_member("a", 2e-3, 1e-4, rng), _member("b", 2.01e-3, 1e-4, rng)], seed=1)
    t = together.quantities["delay"]
    assert not t["depends_on_structure"] and t["spread_over_width"] < STRUCTURE_DEPENDENCE
    assert t["q95"] - t["q05"] == pytest.approx(2 * 1.645e-4, rel=0.1)
    out = apart.to_dict()
    assert [m["weight"] for m in out["members"]] == [0.5, 0.5]
    assert out["members"][0]["quantities"]["delay"]["q50"] == pytest.approx(2e-3, rel=1e-3)
    with pytest.raises(ValueError, match="no member"):
        combine([])
