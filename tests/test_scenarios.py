"""The shared generator of truths and designs (studies/benchmarks/scenarios.py): seeded, in its stated ranges,
over the whole structure space, and its recordings read as measured data."""
import json
import math

import numpy as np
import pytest

from tvcid.models import simulate
from tvcid.models.hypotheses import DeadZonePosition
from tvcid.models.recording import load_recording
from tvcid.models.structures import structure_space
from tvcid.studies.benchmarks.scenarios import (
    RecordingDesign,
    draw_design,
    draw_scenario,
    draw_truth,
    oscillates,
    record_added_test,
    shortened,
    write_recordings,
)


def test_same_seed_same_scenario_other_seed_other():
    a, b, c = draw_scenario(11), draw_scenario(11), draw_scenario(12)
    assert a.to_dict() == b.to_dict()
    assert a.to_dict() != c.to_dict()


@pytest.mark.parametrize("ranges, factor, delay", [("wide", math.sqrt(10.0), (0.8e-3, 8e-3)),
                                                   ("papers", 2.5, (1e-3, 8e-3))])
def test_truths_cover_every_kept_structure_within_the_stated_ranges(ranges, factor, delay):
    """Every kept structure is drawn; each parameter within its range (a decade for the thresholds
    and the delay under ``wide``), and the draws reach both ends of each range."""
    rng = np.random.default_rng(0)
    kept, _ = structure_space()
    seen, spread = set(), {"dead_zone": [], "backlash": [], "delay": []}
    for _ in range(600):
        p = draw_truth(rng, ranges=ranges)
        seen.add(p.dead_zone_position.value + p.delay_position.value
                 + str((p.friction_offset != 0, p.backlash != 0, p.bandpass_gain != 0)))
        assert 0.7 * 305500 <= p.gain <= 1.3 * 305500
        assert 0.7 * 202.1 <= p.damping <= 1.3 * 202.1
        assert 0.7 * 14520 <= p.stiffness <= 1.3 * 14520
        assert 0.85 * 1.0697 <= p.feedback_gain <= 1.15 * 1.0697
        centre = 0.0083 if p.dead_zone_position is DeadZonePosition.VELOCITY else 1.2e-3
        assert centre / factor <= p.dead_zone <= centre * factor
        spread["dead_zone"].append(p.dead_zone / centre)
        assert delay[0] <= p.delay <= delay[1]
        spread["delay"].append(p.delay)
        if p.friction_offset != 0:
            assert -0.9 * p.dead_zone <= p.friction_offset <= -0.3 * p.dead_zone
        if p.backlash != 0:
            assert 1.1625e-4 / factor <= p.backlash <= 1.1625e-4 * factor
            spread["backlash"].append(p.backlash / 1.1625e-4)
        if p.bandpass_gain != 0:
            assert 30 <= p.bandpass_gain <= 100 and 0.008 <= p.bandpass_saturation <= 0.02
    assert len(seen) == len(kept)
    for name, values in spread.items():
        span = max(values) / min(values)
        wanted = delay[1] / delay[0] if name == "delay" else factor**2
        assert 0.8 * wanted <= span <= wanted, name


@pytest.mark.parametrize("ranges, rates, waveforms, closed_s, open_s", [
    ("wide", {200.0, 500.0, 1000.0, 2000.0}, {"square", "sine", "piecewise"}, (20, 40), (8, 12)),
    ("short", {200.0, 500.0, 1000.0, 2000.0}, {"square", "sine", "piecewise"}, (5, 15), (5, 15)),
    ("papers", {200.0, 1000.0}, {"square", "sine"}, (20, 40), (8, 12))])
def test_designs_within_the_stated_ranges(ranges, rates, waveforms, closed_s, open_s):
    rng = np.random.default_rng(1)
    n_open, seen_rates, seen_waveforms = [], set(), set()
    for _ in range(300):
        recs, acq = draw_design(rng, ranges)
        closed = [r for r in recs if r.kind == "closed"]
        assert 1 <= len(closed) <= 3
        n_open.append(len(recs) - len(closed))
        for r in recs:
            seen_rates.add(r.rate)
            if r.kind == "closed":
                assert closed_s[0] <= r.duration <= closed_s[1]
                assert r.controller_rate in (None, 200.0)
                continue
            seen_waveforms.add(r.waveform)
            assert 5e-3 <= r.amplitude <= 30e-3 and 0.3 <= r.frequency <= 3.0
            assert open_s[0] <= r.duration <= open_s[1]
            if r.waveform == "piecewise":
                dwell = np.diff((0.0,) + r.edges)
                assert len(r.levels) == len(r.edges) + 1 and r.edges[-1] < r.duration
                assert np.all(np.abs(r.levels) <= r.amplitude)
                half = 0.5 / r.frequency
                assert np.all((dwell >= 0.5 * half - 1e-12) & (dwell <= 1.5 * half + 1e-12))
                u = r.experiment().command(np.array([0.0, r.edges[0] + 1e-9]))
                assert u[0] == r.levels[0] and u[1] == r.levels[1]
            else:
                assert r.edges == () and r.levels == ()
        assert 1e-5 <= acq.noise_sd <= 1e-4 and abs(acq.offset) <= 3e-4
        assert acq.quantisation == 0 or 5e-6 <= acq.quantisation <= 3e-5
    assert set(n_open) == {0, 1, 2} and seen_rates == rates and seen_waveforms == waveforms


def test_unknown_ranges_get_one_line():
    with pytest.raises(ValueError, match="unknown ranges 'narrow'; choose one of wide, short, papers"):
        draw_scenario(1, ranges="narrow")


def test_drawn_truth_oscillates_at_every_setting_and_recordings_read_as_measured(tmp_path):
    """Draw 2 (a cycle with its controller held at 200 Hz, a square and a staircase, all acquired
    at 2 kHz, sensor offset and quantisation), shortened: the truth oscillates, and the recordings
    read back as measured ones (no truth in the sidecars, commands only as samples)."""
    sc = shortened(draw_scenario(2), closed=6.0, open_=4.0)
    assert sc.acquisition.quantisation > 0 and sc.acquisition.offset != 0
    assert {r.waveform for r in sc.recordings if r.kind == "open"} == {"square", "piecewise"}
    for rd in sc.recordings:
        if rd.kind == "closed":
            assert oscillates(sc.truth, rd.experiment())
    paths = write_recordings(sc, tmp_path, dt=5e-4)  # the format is tested here, not accuracy
    assert len(paths) == len(sc.recordings)
    for path, rd in zip(paths, sc.recordings):
        meta = json.loads(path.with_suffix(".json").read_text())
        assert "hypothesis" not in meta and "parameters" not in meta
        rec = load_recording(path)
        assert rec.kind == rd.kind
        assert rec.sample_rate == pytest.approx(rd.rate, rel=1e-6)
        assert rec.t[-1] == pytest.approx(rd.duration, abs=2.0 / rd.rate)
        if rd.kind == "closed":
            assert (rec.meta["kp"], rec.meta["kd"], rec.meta["mu"]) == (rd.kp, rd.kd, rd.mu)
        else:  # the command is in the samples only, no waveform in the sidecar
            assert "waveform" not in meta
            shown = [v for e, v in zip((0.0,) + rd.edges, rd.levels) if e <= rd.duration]
            span = np.ptp(shown) if rd.waveform == "piecewise" else 2 * rd.amplitude
            assert np.ptp(rec.u) == pytest.approx(span, rel=0.05)
    truth = json.loads((tmp_path / "truth" / "scenario.json").read_text())
    assert truth["structure"] == sc.structure.name
    assert math.isclose(truth["truth"]["dead_zone"], sc.truth.dead_zone)


def test_the_data_step_keeps_the_solver_error_under_the_smallest_noise():
    """The reference path's RK4 error near square edges and switching events must stay below the
    generator's smallest sensor noise (1e-5 rad), or a right model's fit reads it as a misfit
    (coverage draw 8's 1 kHz square: rms 1.36e-5 at 2e-4, discrepancy factor 12.8 at the truth)."""
    from tvcid.models.simulate import simulate_batch
    from tvcid.studies.benchmarks.coverage import Config, coverage_scenario
    from tvcid.studies.benchmarks.scenarios import DATA_DT

    sc = coverage_scenario(8, Config())
    rd = next(r for r in sc.recordings if r.kind == "open" and r.waveform == "square")
    exp, t_end = rd.experiment(), 6.0
    exact = simulate_batch([sc.truth], exp, t_end, dt=5e-6, rate=1000.0).signal("delta")[0]

    def rms_error(dt):
        e = simulate_batch([sc.truth], exp, t_end, dt=dt, rate=1000.0).signal("delta")[0] - exact
        return float(np.sqrt(np.mean(e**2)))

    assert rms_error(2e-4) > 1e-5  # at 2e-4 s the error is the noise's size
    assert rms_error(DATA_DT) < 0.3e-5


def test_heldout_cases_are_the_papers_placements_and_oscillate():
    """``tvcid.studies.benchmarks.heldout_cases``: the three held-out recordings sets, each truth a
    paper's placement that oscillates at every closed-loop setting of its design (else the
    script would fail after minutes of the reference path), and the comparison of a fit with
    the truth reads 0 on the truth itself."""
    from tvcid.studies.benchmarks.heldout_cases import cases, compared

    expected = {
        "m001f_no_bandpass": "dz_velocity+delay_before_integrator+friction+backlash",
        "m000_hwil": "dz_velocity+delay_before_first_integrator+friction+backlash+bandpass",
        "m002_cycles": "dz_error+delay_output+backlash",
    }
    found = cases()
    assert {k: v.structure.name for k, v in found.items()} == expected
    assert all(r.controller_rate == 200.0 and r.rate == 200.0
               for r in found["m000_hwil"].recordings)
    assert found["m000_hwil"].acquisition.offset == 1.5e-4
    assert [r.waveform for r in found["m001f_no_bandpass"].recordings if r.kind == "open"] == [
        "square", "sine"]
    for name, scenario in found.items():
        assert all(oscillates(scenario.truth, r.experiment())
                   for r in scenario.recordings if r.kind == "closed"), name
        errors = compared(scenario.truth.to_dict(), scenario.truth)
        assert errors and all(v == 0.0 for v in errors.values()), name


def test_an_added_test_is_recorded_once_and_again_when_its_scenario_changes(tmp_path, monkeypatch):
    """The loop's and the next-test benchmark's added test: recorded from the truth beside the
    draw, kept on a rerun of the same scenario, made again for another one. The bookkeeping is
    tested here: the numba kernel makes the data in place of the reference path (10 s per
    simulated second at its step)."""
    monkeypatch.setattr("tvcid.studies.benchmarks.scenarios.simulate_reference", simulate)
    sc = shortened(draw_scenario(24), closed=6.0, open_=4.0)
    square = RecordingDesign("open", 1.0, 1000.0, waveform="square", amplitude=0.01, frequency=2.0)
    extended, path = record_added_test(sc, square, tmp_path)
    assert extended.recordings == sc.recordings + (square,)
    assert path.name == f"rec{len(sc.recordings):02d}_open.csv"
    rec = load_recording(path)
    assert rec.kind == "open" and len(rec.t) == 1001
    made = path.stat().st_mtime_ns
    record_added_test(sc, square, tmp_path)
    assert path.stat().st_mtime_ns == made
    other = RecordingDesign("open", 1.0, 1000.0, waveform="square", amplitude=0.02, frequency=2.0)
    _, again = record_added_test(sc, other, tmp_path)
    assert again == path and not np.allclose(load_recording(again).delta, rec.delta)


def test_an_unfinished_draw_keeps_the_recordings_it_finished(tmp_path, monkeypatch):
    """A benchmark stopped while it made a draw's recordings: on the rerun each recording whose
    ``truth/recNN.json`` holds the scenario is kept, the others are made; another scenario's
    recordings are all made again. The bookkeeping is tested here: the numba kernel makes the
    data in place of the reference path."""
    monkeypatch.setattr("tvcid.studies.benchmarks.scenarios.simulate_reference", simulate)
    sc = shortened(draw_scenario(2), closed=2.0, open_=1.0)
    paths = write_recordings(sc, tmp_path, dt=5e-4)
    assert len(paths) >= 2
    (tmp_path / "truth" / "scenario.json").unlink()
    (tmp_path / "truth" / "rec01.json").unlink()  # stopped while it made recording 1
    stamps = [p.stat().st_mtime_ns for p in paths]
    again = write_recordings(sc, tmp_path, dt=5e-4, reuse=True)
    assert again == paths and (tmp_path / "truth" / "scenario.json").exists()
    after = [p.stat().st_mtime_ns for p in paths]
    assert after[0] == stamps[0] and after[1] != stamps[1]
    assert all(a == s for a, s in zip(after[2:], stamps[2:]))
    other = shortened(draw_scenario(3), closed=2.0, open_=1.0)
    write_recordings(other, tmp_path, dt=5e-4, reuse=True)
    assert tmp_path.joinpath(paths[0].name).stat().st_mtime_ns != stamps[0]
