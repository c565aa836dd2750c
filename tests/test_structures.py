"""The grammar of structures (tvcid.models.structures) and the replay of sampled commands
(tvcid.models.commands)."""
import numpy as np
import pytest

from tvcid.models import OpenLoop, hypothesis
from tvcid.models.commands import command_from_samples
from tvcid.models.structures import (
    Structure,
    UnknownStructureError,
    all_structures,
    structure_space,
)


def test_space_is_every_combination_minus_the_stated_prunings():
    assert len(all_structures()) == 48
    kept, pruned = structure_space()
    assert len(kept) == 36 and len(pruned) == 12
    assert all(s.friction and s.dead_zone_position.value == "error" for s in pruned)
    assert all("velocity" in why for why in pruned.values())


@pytest.mark.parametrize("name", ["M002", "M001i", "M001f", "M000"])
def test_every_hypothesis_is_a_kept_structure_and_maps_back_exactly(name):
    p = hypothesis(name)
    s = Structure.of_params(p)
    assert s in structure_space()[0]
    assert s.to_params(p).to_dict() == p.to_dict()
    assert Structure.parse(s.name) == s


def test_absent_components_are_zeroed_and_nesting_works():
    p = hypothesis("M000")
    s = Structure.of_params(p).without("friction").without("bandpass")
    q = s.to_params(p)
    assert q.friction_offset == 0.0 and q.bandpass_gain == 0.0 and q.backlash == p.backlash
    assert s.with_("bandpass").bandpass and not s.friction
    assert "friction_offset" not in s.parameter_names()


def test_fixed_structural_choices_restrict_the_space():
    kept, pruned = structure_space({"delay_position": "output", "backlash": 0.0})
    assert kept and all(s.delay_position.value == "output" and not s.backlash for s in kept)
    assert len(kept) == 6  # error: bandpass on/off; velocity: friction x bandpass


def test_unparseable_structure_name_is_an_error():
    with pytest.raises(UnknownStructureError, match="cannot parse"):
        Structure.parse("dz_sideways+delay_output")
    with pytest.raises(UnknownStructureError, match="unknown component"):
        Structure.parse("dz_error+delay_output+gearbox")


@pytest.mark.parametrize("rate, frequency", [(1000.0, 0.5), (200.0, 0.7), (1000.0, 1.3)])
def test_sampled_square_wave_is_replayed_with_its_edges(rate, frequency):
    exact = OpenLoop.square(0.01, frequency)
    t = np.arange(0, 8.0, 1.0 / rate)
    replay = command_from_samples(t, exact.command(t))
    assert replay.waveform == "piecewise"
    true_edges = np.arange(1, int(2 * 8.0 * frequency) + 1) / (2 * frequency)
    true_edges = true_edges[true_edges < t[-1]]
    err = np.abs(replay.t_samples[: true_edges.size] - true_edges)
    # edges on the sample grid come back exact; edges drifting across the grid (several samples
    # over the record) within half a sample and a quarter
    # on average, where a zero-order hold is half a sample late on average and up to one
    assert err.max() < 0.5 / rate and err.mean() < 0.25 / rate


def test_smooth_command_is_interpolated():
    t = np.arange(0, 4.0, 1 / 200)
    replay = command_from_samples(t, 0.01 * np.sin(2 * np.pi * 3.0 * t))
    assert replay.waveform == "samples"
    fine = np.linspace(0, 3.9, 1001)
    assert np.max(np.abs(replay.command(fine) - 0.01 * np.sin(2 * np.pi * 3.0 * fine))) < 2.5e-4
    assert replay.command(np.array([-1.0, 5.0])).tolist() == [0.0, replay.u_samples[-1]]


@pytest.mark.parametrize("seed", range(6))
def test_sampled_sine_replay_is_far_below_the_smallest_noise(seed):
    """A sine of the benchmarks' designs (5-30 mrad, 0.3-3 Hz, sampled at 200 Hz or 1 kHz, drawn
    here) replayed from its samples stays within 1 % of the smallest noise (1e-5 rad) everywhere;
    read by its chords it would not at 200 Hz (a 3 Hz, 30 mrad sine: 3.3e-5 rad)."""
    rng = np.random.default_rng(seed)
    amplitude, frequency = rng.uniform(0.005, 0.03), rng.uniform(0.3, 3.0)
    rate = (200.0, 1000.0)[seed % 2]
    t = np.arange(0, 6.0, 1 / rate)
    exact = OpenLoop.sine(amplitude, frequency)
    replay = command_from_samples(t, exact.command(t))
    fine = np.linspace(0.0, t[-1], 20001)
    spline_error = np.max(np.abs(replay.command(fine) - exact.command(fine)))
    chord_error = np.max(np.abs(OpenLoop.from_samples(t, exact.command(t)).command(fine)
                                - exact.command(fine)))
    assert spline_error < 1e-7 and spline_error < 0.05 * chord_error, (spline_error, chord_error)


def test_unknown_interpolation_and_too_few_samples_for_a_spline_are_errors():
    with pytest.raises(ValueError, match="unknown interpolation 'quadratic'"):
        OpenLoop.from_samples([0.0, 1.0], [0.0, 1.0], interpolation="quadratic")
    with pytest.raises(ValueError, match="needs >= 4 samples"):
        OpenLoop.from_samples([0.0, 1.0, 2.0], [0.0, 1.0, 0.0], interpolation="cubic")


def test_shared_choices_decide_what_every_indistinguishable_structure_shares():
    """M000's quick discovery set: the dead zone's position, the backlash and the band-pass loop
    are decided; the delay's position and the friction offset (merged into the threshold) are not."""
    from tvcid.models.structures import shared_choices

    decided = shared_choices(["dz_velocity+delay_before_first_integrator+backlash+bandpass",
                              "dz_velocity+delay_before_first_integrator+friction+backlash+bandpass",
                              "dz_velocity+delay_before_integrator+backlash+bandpass"])
    assert decided == {"dead_zone_position": "velocity", "delay_position": None, "friction": None,
                       "backlash": True, "bandpass": True}
    one = Structure.parse("dz_error+delay_output")
    assert shared_choices([one]) == {"dead_zone_position": "error", "delay_position": "output",
                                     "friction": False, "backlash": False, "bandpass": False}
    with pytest.raises(ValueError, match="at least one structure"):
        shared_choices([])
