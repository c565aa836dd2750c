"""Spectral analysis as papers 001 and 000 do it."""
import functools
import json

import numpy as np
import pytest

from tvcid.cli import main
from tvcid.discovery.spectral import (
    SpectralInputError,
    amplitude_spectrum,
    harmonic_table,
    lowpass_reconstruction,
    noise_floor,
)
from tvcid.models import CONTROLLER_A, InsufficientPeriodsError, hypothesis, simulate
from tvcid.models.noise import band_limited_white_noise
from tvcid.models.recording import load_recording, recording_from_trajectory, save_recording
from tvcid.studies.benchmarks.scenarios import draw_scenario

RATE = 1000.0


def _sine(duration=10.0, freqs=((1.5, 5e-3), (25.0, 1e-4))):
    t = np.arange(int(duration * RATE)) / RATE
    x = sum(a * np.sin(2 * np.pi * f * t) for f, a in freqs)
    return t, x


def test_amplitude_spectrum_reads_amplitudes_and_derivative():
    t, x = _sine()
    spec = amplitude_spectrum(t, x)
    for f, a in ((1.5, 5e-3), (25.0, 1e-4)):
        k = int(np.argmin(np.abs(spec.frequency_hz - f)))
        assert spec.amplitude[k] == pytest.approx(a, rel=1e-9)
    deriv = amplitude_spectrum(t, x, derivative=True)
    k = int(np.argmin(np.abs(deriv.frequency_hz - 25.0)))
    assert deriv.amplitude[k] == pytest.approx(2 * np.pi * 25.0 * 1e-4, rel=1e-9)


def test_lowpass_reconstruction_drops_content_above_the_cutoff():
    t, x = _sine()
    rebuilt = lowpass_reconstruction(t, x)  # 10 Hz default
    slow = 5e-3 * np.sin(2 * np.pi * 1.5 * t)
    assert np.max(np.abs(rebuilt.delta - slow)) < 1e-9
    assert np.max(np.abs(rebuilt.derivative - 2 * np.pi * 1.5 * 5e-3 * np.cos(2 * np.pi * 1.5 * t))) < 1e-8
    with pytest.raises(SpectralInputError, match="cutoff_hz 600 must lie between"):
        lowpass_reconstruction(t, x, cutoff_hz=600.0)


@pytest.fixture(scope="module")
def m001f_record():
    tr = simulate(hypothesis("M001f"), CONTROLLER_A, 40.0)
    sl = tr.window(20)
    return tr.t[sl], tr.delta[sl]


def test_harmonic_table_flags_the_seventh_harmonic_of_m001f(m001f_record):
    table = harmonic_table(*m001f_record)
    assert table.raised_harmonics == (7,)
    row = table.rows()[6]
    assert row["frequency_hz"] == pytest.approx(9.57, abs=0.02)
    # docs/models.md#reference-limit-cycles: H7/H1 = 0.45
    assert row["ratio"] == pytest.approx(0.45, abs=0.02)


@functools.lru_cache(maxsize=None)
def _drawn(seed):
    """Draw ``seed`` of the shared generator (:func:`tvcid.studies.benchmarks.scenarios.draw_scenario`: truths
    over every structure) at its first limit-cycle setting (controller, hold and acquisition
    rate): ``(scenario, experiment, rate)``."""
    scenario = draw_scenario(seed, ranges="papers")
    first = next(r for r in scenario.recordings if r.kind == "closed")
    return scenario, first.experiment(), first.rate


#: Draws without a band-pass loop: those among draws 0-9 (1, 3, 6, 8) but draw 1, whose truth the
#: generator redraws the most times before it oscillates (0.4 s, the other three 0.3 s together).
PLAIN_DRAWS = (3, 6, 8)


def test_no_raised_harmonic_without_the_bandpass_loop():
    """Drawn truths without a band-pass loop, 20 s of a 40 s cycle: no harmonic is raised, and
    the seventh stays below the fifth (the odd harmonics decay; over the eleven draws without the
    loop among 0-19, H7/H1 reached 0.22 and H5/H1 0.29, both on draw 19)."""
    for seed in PLAIN_DRAWS:
        scenario, experiment, rate = _drawn(seed)
        assert not scenario.structure.bandpass, seed
        tr = simulate(scenario.truth, experiment, 40.0, rate=rate)
        sl = tr.window(20)
        table = harmonic_table(tr.t[sl], tr.delta[sl])
        assert table.raised_harmonics == (), (seed, scenario.structure.name)
        assert table.ratio[6] < table.ratio[4], (seed, table.ratio[:7])


#: Noise powers (rad^2/Hz) and bands (Hz) injected.
NOISE_CASES = [(1e-11, 500.0), (4e-11, 100.0)]


def _noise_floor_errors(seeds, power, band):
    """Relative errors of the matched power and of its root over drawn truths, each at its first
    controller setting and acquisition rate, the noise injected with seed = draw, the last 30 s
    of 40 s."""
    errors, std_errors = [], []
    for seed in seeds:
        scenario, experiment, rate = _drawn(seed)
        params = scenario.truth.replace(noise_power=power, noise_band=band, noise_seed=seed)
        tr = simulate(params, experiment, 40.0, rate=rate)
        sl = tr.window(30)
        floor = noise_floor(tr.t[sl], tr.delta[sl], noise_band=band)
        errors.append(floor.power / power - 1)
        std_errors.append(floor.std / np.sqrt(power * 2 * band) - 1)
    return np.array(errors), np.array(std_errors)


@pytest.mark.parametrize("power, band", NOISE_CASES)
def test_noise_floor_recovers_the_injected_power(power, band):
    """Measured over draws 0-19: every matched power within 12.5 % of the injected one (draw 4,
    whose band-pass loop answers the noise coherently, as M000's does:
    tvcid.discovery.spectral.noise_floor), its root within 6.1 %. Asserted on :data:`PLAIN_DRAWS`:
    each within 20 % (1.6x the largest) and the root within 10 %."""
    errors, std_errors = _noise_floor_errors(PLAIN_DRAWS, power, band)
    assert np.max(np.abs(errors)) < 0.20, errors.round(3)
    assert np.max(np.abs(std_errors)) < 0.10, std_errors.round(3)


@pytest.mark.slow
@pytest.mark.parametrize("power, band", NOISE_CASES)
def test_noise_floor_is_unbiased_over_ten_drawn_truths(power, band):
    """Draws 0-9, band-pass loops included: each matched power within 20 % of the injected one,
    their mean within 5 % (measured +3.1 % and +0.9 %; one estimate scatters by about 5 %, 4-6 %
    over noise seeds on M002: 3 standard errors of a mean of ten) and the root within 10 %."""
    errors, std_errors = _noise_floor_errors(range(10), power, band)
    assert np.max(np.abs(errors)) < 0.20, errors.round(3)
    assert abs(np.mean(errors)) < 0.05, errors.round(3)
    assert np.max(np.abs(std_errors)) < 0.10, std_errors.round(3)


def test_noise_floor_of_held_noise_on_a_sine():
    rng = np.random.default_rng(20261121)
    t, x = _sine(duration=20.0, freqs=((1.4, 5e-3),))
    power, band = 2e-11, 50.0  # held over 10 samples: the floor rolls off inside 20-100 Hz
    noise = band_limited_white_noise(power, band, t[-1], rng)
    x = x + noise[np.floor(t * 2 * band + 1e-9).astype(int)]
    assert noise_floor(t, x, noise_band=band).power == pytest.approx(power, rel=0.2)


def test_recording_input_and_cli(tmp_path, capsys):
    tr = simulate(hypothesis("M001f", noise_power=1e-12, noise_seed=5), CONTROLLER_A, 30.0)
    path = save_recording(tmp_path / "m001f.csv", *recording_from_trajectory(tr))
    recording = load_recording(path)
    assert harmonic_table(recording).raised_harmonics == (7,)
    assert main(["spectrum", str(path), "--window", "15", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["raised"] == [7]
    assert out["harmonics"][6]["raised"] is True
    assert out["noise_floor"]["power"] == pytest.approx(1e-12, rel=0.2)


def test_short_and_bad_records_are_refused():
    t, x = _sine(duration=1.0, freqs=((1.5, 5e-3),))
    with pytest.raises(InsufficientPeriodsError, match="at least two"):
        harmonic_table(t, x)
    t2 = t.copy()
    t2[10] += 3e-4
    with pytest.raises(SpectralInputError, match="uniformly sampled"):
        amplitude_spectrum(t2, x)
    with pytest.raises(SpectralInputError, match="NaN"):
        noise_floor(t, np.where(t > 0.5, np.nan, x))
    with pytest.raises(SpectralInputError, match="band 20-100 Hz holds"):
        noise_floor(t[:50], x[:50])
    with pytest.raises(SpectralInputError, match="not both"):
        amplitude_spectrum(load_recording_stub(), x)


def load_recording_stub():
    from tvcid.models.recording import Recording

    return Recording(columns={"t": np.arange(10.0), "u": np.zeros(10), "delta": np.zeros(10)}, meta={"kind": "open"})


def test_plots_draw_on_given_axes():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, x = _sine(duration=10.0, freqs=((1.5, 5e-3), (10.5, 1e-3)))
    fig, axes = plt.subplots(2, 2)
    open_figures = plt.get_fignums()  # other tests may have left figures open
    for ax, result in zip(axes.flat, (amplitude_spectrum(t, x), lowpass_reconstruction(t, x),
                                      harmonic_table(t, x), noise_floor(t, x))):
        assert result.plot(ax=ax) is ax
        assert ax.lines or ax.patches
    assert plt.get_fignums() == open_figures
    plt.close(fig)
