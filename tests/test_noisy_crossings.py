"""Every reader of a measured cycle's period shares the noise-aware crossing trigger.

Coverage draw 5's held band-pass cycle (3.5e-4 rad at 1.9 Hz under 8.9e-5 rad of noise, 200 Hz):
with a hysteresis of 10 % of the amplitude, noise fired the trigger and the waveform term's
period, discovery's stationary tail and the harmonic table read 21, 30 and 21 rad/s for 11.94.
"""
import numpy as np
import pytest

from tvcid.discovery.calibration.likelihood import WaveformTerm
from tvcid.discovery.spectral.harmonics import whole_periods
from tvcid.discovery.spectral.samples import as_uniform_samples
from tvcid.models import CONTROLLER_A
from tvcid.models.cycle_reading import (
    CROSSING_HYSTERESIS,
    crossing_hysteresis,
    cycle_of,
)
from tvcid.models.cycle_settling import stationary_tail
from tvcid.models.recording import Recording

W = 2 * np.pi * 1.9


def _small_noisy_cycle(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, 0.005)
    clean = 3.5e-4 * np.sin(W * t) + 6e-5 * np.sin(3 * W * t + 0.4)
    return t, clean, clean + rng.normal(0.0, 8.9e-5, t.size)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_measured_cycle_readers_keep_the_period_under_noise(seed):
    t, _, x = _small_noisy_cycle(seed)
    rec = Recording(columns={"t": t, "delta": x},
                    meta={"kind": "closed", "kp": CONTROLLER_A.kp, "kd": CONTROLLER_A.kd,
                          "mu": CONTROLLER_A.mu, "sample_rate": 200.0})
    term = WaveformTerm(rec, None, 2.0, 5e-4)
    assert 2 * np.pi / term.period == pytest.approx(W, rel=0.01)
    _, _, ups = stationary_tail(t, x)
    assert 2 * np.pi * (ups.size - 1) / (ups[-1] - ups[0]) == pytest.approx(W, rel=0.01)
    _, _, f0 = whole_periods(as_uniform_samples(t, x))
    assert 2 * np.pi * f0 == pytest.approx(W, rel=0.01)


def test_noise_free_simulation_keeps_the_amplitude_hysteresis():
    """A simulated cycle is compared with the record's: without noise the trigger is unchanged."""
    t, clean, _ = _small_noisy_cycle(0)
    amp = 0.5 * float(np.ptp(clean))
    assert crossing_hysteresis(clean, amp) == pytest.approx(CROSSING_HYSTERESIS * amp)
    omega, _, _ = cycle_of(t, clean)
    assert omega == pytest.approx(W, rel=1e-3)


def test_simulated_cycle_is_measured_at_the_records_multiple():
    """A cycle whose lobes alternate is read at the record's crossings per period, not decided
    afresh per simulated run: across the subharmonic threshold the free decision halves the
    frequency (a jump of the features for a small change of a parameter), the record's does not."""
    from tvcid.models.cycle_reading import (
        SUBHARMONIC_FRACTION,
        crossing_multiple,
        fundamental_crossings,
        peak_to_peak_sizes,
    )

    w = 2 * np.pi * 3.0
    t = np.arange(0.0, 3.0, 2e-3)
    omegas = {}
    for a in (0.7 * SUBHARMONIC_FRACTION, 1.5 * SUBHARMONIC_FRACTION):
        x = np.sin(w * t) + a * np.sin(0.5 * w * t + 0.3)
        omegas[a] = (cycle_of(t, x)[0], cycle_of(t, x, multiple=1)[0])
    (free_lo, fixed_lo), (free_hi, fixed_hi) = omegas.values()
    assert free_lo == pytest.approx(w, rel=0.02) and free_hi == pytest.approx(0.5 * w, rel=0.02)
    assert fixed_lo == pytest.approx(w, rel=0.02) and fixed_hi == pytest.approx(w, rel=0.02)
    x = np.sin(w * t) + 1.5 * SUBHARMONIC_FRACTION * np.sin(0.5 * w * t + 0.3)
    from tvcid.models.cycle_reading import crossing_hysteresis, upward_mean_crossings

    every = upward_mean_crossings(t, x, float(np.mean(x)), crossing_hysteresis(x, 0.5 * np.ptp(x)))
    ups = fundamental_crossings(every, peak_to_peak_sizes(t, x, every), signal=(t, x))
    assert crossing_multiple(t, x, ups) == 2
    assert crossing_multiple(t, x, every) == 1
