"""What a posterior pins (tvcid.discovery.calibration.pinned), on draws of known distributions."""
import math

import numpy as np
import pytest

from tvcid.discovery.calibration.pinned import pinned_combinations
from tvcid.discovery.calibration.priors import LogUniform, Uniform

PRIORS = {"dead_zone": LogUniform(1e-4, 1e-2), "backlash": LogUniform(1e-6, 3e-3),
          "delay": LogUniform(1e-4, 3e-2), "friction_offset": Uniform(0.0, 1.0)}


def _ridge_draws(rng, n=4000):
    """Paper 002's family as a posterior: ln dead_zone + 0.62 ln backlash fixed to 1e-3 of its
    value, the backlash spread over two decades; the delay pinned alone to 1 %; the friction
    offset free over its prior."""
    ln_b = rng.uniform(math.log(1e-5), math.log(1e-3), n)
    ln_z = math.log(3e-3) - 0.62 * (ln_b - math.log(1e-4)) + 1e-3 * rng.standard_normal(n)
    delay = 5e-3 * np.exp(0.01 * rng.standard_normal(n))
    friction = rng.uniform(0.0, 1.0, n)
    return np.column_stack([np.exp(ln_z), np.exp(ln_b), delay, friction])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_ridge_and_a_pinned_parameter_are_found_and_the_rest_is_free(seed):
    names = ("dead_zone", "backlash", "delay", "friction_offset")
    m = pinned_combinations(_ridge_draws(np.random.default_rng(seed)), names, PRIORS)
    assert len(m.pinned) == 2 and m.free == 2
    ridge = next(c for c in m.pinned if len(c.terms) == 2)
    alone = next(c for c in m.pinned if len(c.terms) == 1)
    assert list(ridge.terms) == ["dead_zone", "backlash"] and ridge.product
    assert ridge.terms["dead_zone"] == 1.0
    assert ridge.terms["backlash"] == pytest.approx(0.62, abs=0.01)
    # dead_zone * backlash^0.62 = 3e-3 * (1e-4)^0.62, known to 0.1 %
    value = math.log(3e-3) + 0.62 * math.log(1e-4)
    assert ridge.median == pytest.approx(value, abs=1e-3)
    assert ridge.high - ridge.low == pytest.approx(2 * 1.645 * 1e-3, rel=0.15)
    assert list(alone.terms) == ["delay"] and alone.median == pytest.approx(math.log(5e-3), abs=2e-3)
    assert "dead_zone * backlash^0.62 = " in ridge.text()
    # each parameter's own interval spans most of its prior: one at a time, nothing is pinned
    assert m.shrinkages[-1] > 0.5


def test_uniform_coordinates_give_a_sum_and_a_noise_sd_is_left_out():
    rng = np.random.default_rng(3)
    f = rng.uniform(0.0, 1.0, 3000)
    ln_z = math.log(2e-3) - 0.5 * f + 1e-4 * rng.standard_normal(3000)
    sigma = 1e-4 * np.ones(3000)
    m = pinned_combinations(np.column_stack([np.exp(ln_z), f, sigma]),
                            ("dead_zone", "friction_offset", "sigma"),
                            {k: PRIORS[k] for k in ("dead_zone", "friction_offset")})
    (c,) = m.pinned
    assert not c.product and c.terms["dead_zone"] == 1.0
    assert c.terms["friction_offset"] == pytest.approx(0.5, abs=0.01)
    assert c.text().startswith("ln dead_zone + 0.5 friction_offset = ")
    assert m.free == 1 and "sigma" not in c.terms


def test_too_few_draws_pin_nothing():
    m = pinned_combinations(np.ones((2, 1)), ("delay",), PRIORS)
    assert m.pinned == () and m.free == 1


def test_a_members_pinned_figure_draws_its_joined_pairs_over_the_df_family(tmp_path):
    from pathlib import Path
    from types import SimpleNamespace

    from tvcid.models import hypothesis
    from tvcid.models.recording import load_recording
    from tvcid.figures import write_pinned_figure

    names = ("dead_zone", "backlash", "delay", "friction_offset")
    draws = _ridge_draws(np.random.default_rng(4), n=800)
    pinned = pinned_combinations(draws, names, PRIORS).to_dict()
    post = SimpleNamespace(samples=draws, names=names)
    rec = load_recording(Path(__file__).resolve().parents[1] / "data" / "m000_closed_A.csv")
    path = write_pinned_figure(post, pinned, tmp_path / "pinned-0.png", [rec], hypothesis("M002"))
    assert path == tmp_path / "pinned-0.png" and path.stat().st_size > 10_000
    alone = {"pinned": [c for c in pinned["pinned"] if len(c["terms"]) == 1], "free": 2}
    assert write_pinned_figure(post, alone, tmp_path / "none.png") is None
    assert not (tmp_path / "none.png").exists()


def test_the_pinned_figure_reads_a_ranking_rows_parameters(tmp_path):
    """The set stage passes a ranking row's parameters as a dict."""
    from pathlib import Path
    from types import SimpleNamespace

    from tvcid.figures import write_pinned_figure
    from tvcid.models import M002
    from tvcid.models.recording import load_recording

    names = ("dead_zone", "backlash", "delay", "friction_offset")
    draws = _ridge_draws(np.random.default_rng(5), n=500)
    pinned = pinned_combinations(draws, names, PRIORS).to_dict()
    rec = load_recording(Path(__file__).resolve().parents[1] / "data" / "m000_closed_A.csv")
    path = write_pinned_figure(SimpleNamespace(samples=draws, names=names), pinned,
                               tmp_path / "p.png", [rec], M002().to_dict())
    assert path.exists()
