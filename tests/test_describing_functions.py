"""Describing functions: analytic formulas against the numeric first harmonic."""
import numpy as np
import pytest

from tvcid.discovery.describing import (
    Chain,
    DeadZone,
    FrictionOffset,
    Gain,
    PlayOperator,
    Relay,
    Saturation,
    backlash_df,
    dead_zone_df,
    dead_zone_friction_df,
    describing_function,
    friction_offset_df,
    inverse_dead_zone_df,
    numeric_df,
    relay_df,
    saturation_df,
)

TOLERANCE = 1e-4
AMPLITUDES = np.array([1.25e-3, 1.6e-3, 2.5e-3, 4.89e-3, 1e-2, 5e-2])


@pytest.mark.parametrize(
    "element, analytic",
    [
        (DeadZone(1.2e-3), lambda a: dead_zone_df(a, 1.2e-3)),
        (Saturation(1.2e-3), lambda a: saturation_df(a, 1.2e-3)),
        (Relay(0.3), lambda a: relay_df(a, 0.3)),
        (FrictionOffset(-0.0054), lambda a: friction_offset_df(a, -0.0054)),
        (PlayOperator(2.182e-4), lambda a: backlash_df(a, 2.182e-4)),
        (PlayOperator.from_full_width(4.364e-4), lambda a: backlash_df(a, full_width=4.364e-4)),
        (PlayOperator(1.1625e-3, initial=0.3), lambda a: backlash_df(a, 1.1625e-3)),
    ],
    ids=["dead_zone", "saturation", "relay", "friction", "play_half", "play_full", "play_memory"],
)
def test_numeric_df_matches_analytic(element, analytic):
    numeric = numeric_df(element, AMPLITUDES)
    exact = np.asarray(analytic(AMPLITUDES), dtype=complex)
    # relative to the size of the DF (the relay's is ~100 at these amplitudes)
    assert np.max(np.abs(numeric - exact) / np.maximum(1.0, np.abs(exact))) < TOLERANCE


def test_chain_of_dead_zone_and_friction_matches_its_formula():
    chain = Chain((DeadZone(8.3e-3), FrictionOffset(-0.0054)))
    a = np.array([0.01, 0.02, 0.05, 0.1])
    numeric = numeric_df(chain, a, samples_per_period=2 ** 16)
    assert np.max(np.abs(numeric - dead_zone_friction_df(a, 8.3e-3, -0.0054))) < TOLERANCE


def test_chain_with_memory_gain_before_play_equals_scaled_play():
    # play_r(K x) = K play_{r/K}(x): the chain's DF is K times the play DF of half width r/K
    k, r = 1.0697, 1.1625e-4
    chain = Chain((Gain(k), PlayOperator(r)))
    a = np.array([2e-4, 5e-4, 4.89e-3])
    assert np.max(np.abs(numeric_df(chain, a) - k * backlash_df(a, r / k))) < TOLERANCE
    # describing_function falls back to the numeric DF for a chain
    assert np.max(np.abs(describing_function(chain, a) - numeric_df(chain, a))) < 1e-12


def test_backlash_width_conventions_and_limits():
    a = 4.89e-3
    assert backlash_df(a, full_width=4.364e-4) == pytest.approx(backlash_df(a, 2.182e-4))
    assert backlash_df(a, 0.0) == pytest.approx(1.0)
    assert backlash_df(1e-4, 2e-4) == 0  # amplitude inside the play: the output stays still
    n = backlash_df(a, 4.364e-4)
    assert 0 < n.real < 1 and n.imag < 0  # a lag
    with pytest.raises(ValueError, match="exactly one of half_width or full_width"):
        backlash_df(a, 1e-4, full_width=2e-4)


def test_dead_zone_df_below_and_inverse():
    assert dead_zone_df(1e-3, 1.2e-3) == 0.0
    assert dead_zone_df(1e3, 1.2e-3) == pytest.approx(1.0, abs=2e-6)
    for gain in (0.05, 0.5, 0.95):
        rho = inverse_dead_zone_df(gain)
        assert dead_zone_df(1.0, rho) == pytest.approx(gain, abs=1e-12)
    with pytest.raises(ValueError, match="required gain 1.2 cannot be met"):
        inverse_dead_zone_df(1.2)


def test_bad_inputs_name_the_culprit():
    with pytest.raises(ValueError, match="amplitude must be finite and > 0"):
        dead_zone_df(-1.0, 1e-3)
    with pytest.raises(ValueError, match="half_width must be a finite number >= 0"):
        dead_zone_df(1.0, -1e-3)
    with pytest.raises(ValueError, match="samples_per_period must be a multiple of 4"):
        numeric_df(DeadZone(1e-3), 1.0, samples_per_period=30)
    with pytest.raises(ValueError, match="is not callable"):
        numeric_df(3.0, 1.0)
