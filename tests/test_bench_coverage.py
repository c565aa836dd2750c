"""The coverage benchmark's quick run and its command line (a file of their own, so that a
second test worker runs them beside the quick studies of ``test_studies.py``)."""
import json

import pytest


@pytest.fixture(scope="module")
def quick_dir(tmp_path_factory):
    """One directory for both likelihoods' quick runs, so that draw 0's recordings (the
    reference path, most of the time) are made once."""
    return tmp_path_factory.mktemp("bench_coverage")


def test_bench_coverage_quick_rows_agree_with_their_summary(quick_dir):
    """``python -m studies.bench_coverage --quick`` (one draw here): every sampled parameter's row
    holds ordered quantiles, a rank in [0, 1] and an 'inside' flag that matches them; the summary's
    coverage and rank histogram are those of the rows. (The coverage itself needs the full run:
    README, "Known limits".)"""
    from studies.bench_coverage import RANK_BINS
    from studies.bench_coverage import main as bench_main

    tmp_path = quick_dir
    assert bench_main(["--quick", "--draws", "1", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "bench.json").read_text())
    (row,) = report["rows"]
    assert row["parameters"] and row["simulated_seconds"] > 0 and len(row["inflation"]) == len(row["design"])
    assert row["laplace"] is None or 0.0 <= row["laplace"]["share"] <= 1.0  # how the move ran
    for name, cell in row["parameters"].items():
        assert cell["q05"] <= cell["q50"] <= cell["q95"] and 0.0 <= cell["rank"] <= 1.0
        assert cell["inside"] == (cell["q05"] <= cell["truth"] <= cell["q95"])
        s = report["summary"][name]
        assert s["coverage"] == float(cell["inside"]) and sum(s["rank_histogram"]) == 1
        assert s["rank_histogram"][min(int(cell["rank"] * RANK_BINS), RANK_BINS - 1)] == 1
    infl = report["summary"]["_inflation"]
    assert infl["records"] == len(row["inflation"]) and infl["max"] == max(row["inflation"])
    assert (tmp_path / "ranks.png").stat().st_size > 0


def test_bench_coverage_quick_with_tvcid_fits_default_likelihood(quick_dir):
    """``--likelihood waveform --quick`` (draw 0: no band-pass loop, so it runs): the row says how
    each record entered (closed-loop records by their waveform or, fallen back, their features;
    open-loop ones by their output error), samples the noise sd, and its cells are consistent;
    draws with the band-pass loop are skipped, not run."""
    from studies.bench_coverage import QUICK_WAVEFORM, coverage_scenario, runs_with
    from studies.bench_coverage import main as bench_main

    assert bench_main(["--quick", "--likelihood", "waveform", "--draws", "1",
                       "--out", str(quick_dir)]) == 0
    report = json.loads((quick_dir / "bench.json").read_text())
    assert report["config"]["likelihood"] == "waveform"
    (row,) = report["rows"]
    kinds = [d["kind"] for d in row["design"]]
    assert len(row["likelihoods"]) == len(kinds)
    for how, kind in zip(row["likelihoods"].values(), kinds):
        assert how == "open" if kind == "open" else how in ("waveform", "features")
    for cell in row["parameters"].values():
        assert cell["inside"] == (cell["q05"] <= cell["truth"] <= cell["q95"])
    banded = next(i for i in range(40) if coverage_scenario(i, QUICK_WAVEFORM).structure.bandpass)
    assert not runs_with(banded, QUICK_WAVEFORM) and runs_with(0, QUICK_WAVEFORM)


def test_bench_coverage_indices_select_draws_and_reject_bad_text():
    """``--indices 10,14-29`` selects those draws (ranges inclusive); text that is not N or N-M
    is refused with a message naming it."""
    from studies.bench_coverage import parse_indices

    assert parse_indices("10,14-16") == {10, 14, 15, 16}
    assert parse_indices("3") == {3}
    with pytest.raises(ValueError, match="'a-2' is not N or N-M"):
        parse_indices("a-2")


def test_oracle_gain_of_a_known_quadratic_and_bad_arguments(capsys):
    """``studies.coverage_oracle``'s maximiser returns the drop from the truth (z = 0) to the
    optimum of a known quadratic, and where it is; a negative index is refused."""
    import numpy as np

    from studies.coverage_oracle import _maximise
    from studies.coverage_oracle import main as oracle_main

    centre = np.array([0.02, -0.05, 0.01])
    gain, move = _maximise(lambda z: 0.5 * float(np.sum(((z - centre) / 0.01) ** 2)) + 3.0, 3)
    assert gain == pytest.approx(0.5 * np.sum((centre / 0.01) ** 2), rel=1e-3)
    assert np.allclose(move, centre, atol=2e-4)
    with pytest.raises(SystemExit):
        oracle_main(["-1"])
    assert "non-negative" in capsys.readouterr().err


def test_oracle_replay_chi_square_sees_a_sines_chords(capsys):
    """A 2.6 Hz, 23 mrad sine sampled at 200 Hz (coverage draw 17's design) on M002, noise 4e-5
    rad: read by its chords the replay adds a chi-square of several noise units at the truth over
    4 s, as replayed (a spline) none; several draws need ``--replay-only``."""
    from models import OpenLoop, hypothesis, simulate
    from models.recording import Recording
    from studies.coverage_oracle import main as oracle_main
    from studies.coverage_oracle import replay_chi_square
    from studies.scenarios import RecordingDesign

    design = RecordingDesign(kind="open", duration=4.0, rate=200.0, waveform="sine",
                             amplitude=0.0227, frequency=2.58)
    truth = hypothesis("M002")
    tr = simulate(truth, design.experiment(), 4.0, dt=5e-4, rate=200.0)
    u = OpenLoop.sine(0.0227, 2.58).command(tr.t)
    rec = Recording({"t": tr.t, "u": u, "delta": tr.delta}, {"kind": "open"})
    loads = replay_chi_square(truth, design, rec, 4e-5)
    assert loads["chords"] > 5.0 and loads["replayed"] < 1e-3, loads
    with pytest.raises(SystemExit):
        oracle_main(["3", "4"])
    assert "--replay-only" in capsys.readouterr().err


def test_widening_compares_interval_widths_with_and_without_the_discrepancy_term():
    """``widening`` divides each parameter's 90 % width with the term by its width without it,
    pairs draws by index (a draw run one way only is left out) and counts ratios within 1.2."""
    from studies.bench_coverage import widening

    def row(index, widths, inflation=(1.0,)):
        return {"index": index, "inflation": list(inflation), "converged": True,
                "parameters": {n: {"q05": 1.0, "q95": 1.0 + w, "inside": True}
                               for n, w in widths.items()}}

    on = [row(13, {"dead_zone": 0.3, "delay": 0.1}, (2.7, 1.0)), row(15, {"dead_zone": 0.2})]
    off = [row(13, {"dead_zone": 0.2, "delay": 0.1}), row(25, {"dead_zone": 0.1})]
    result = widening(on, off)
    (draw,) = result["draws"]
    assert draw["index"] == 13 and draw["inflation"] == [2.7, 1.0]
    assert draw["parameters"]["dead_zone"]["ratio"] == pytest.approx(1.5)
    assert draw["parameters"]["delay"]["ratio"] == pytest.approx(1.0)
    assert result["intervals"] == 2 and result["within_20_percent"] == 1
    assert result["max_ratio"] == pytest.approx(1.5)


def test_widening_without_finished_draws_says_so(tmp_path, capsys):
    """``--widening`` before the benchmark has rows in DIR: exit 1 and a message naming the file."""
    from studies.bench_coverage import main as bench_main

    assert bench_main(["--quick", "--widening", "--out", str(tmp_path)]) == 1
    assert "no finished draws" in capsys.readouterr().out


def test_a_failing_draw_is_reported_and_the_others_still_run(tmp_path, monkeypatch, capsys):
    """Both the benchmark and ``--widening`` run their draws through ``run_draws``: a draw that
    raises is named in the output and in the exit status, the draws after it still run."""
    from dataclasses import asdict

    import studies.bench_coverage as bc

    def fake_run_draw(index, config, workdir, discrepancy=True):
        if index == 0:
            raise RuntimeError("simulated failure")
        width = 0.2 if discrepancy else 0.1
        return {"index": index, "structure": "s", "inflation": [2.0], "converged": True,
                "iterations": 1, "wall_s": 1.0, "simulated_seconds": 1.0,
                "parameters": {"dead_zone": {"q05": 1.0, "q95": 1.0 + width, "inside": True,
                                             "rank": 0.5, "relative_width": width}}}

    monkeypatch.setattr(bc, "run_draw", fake_run_draw)
    seen = []
    assert bc.run_draws([0, 1], bc.QUICK, tmp_path, 1, seen.append) == [0]
    assert [r["index"] for r in seen] == [1]
    assert "draw 0 FAILED: RuntimeError('simulated failure')" in capsys.readouterr().out

    rows = [fake_run_draw(i, bc.QUICK, tmp_path) for i in (0, 1) if i]  # draw 1 finished
    rows.append({**rows[0], "index": 0})  # and draw 0, whose plain rerun will fail
    (tmp_path / "bench.json").write_text(json.dumps({"config": asdict(bc.QUICK), "rows": rows}))
    assert bc.main(["--quick", "--widening", "--out", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "draw 0 FAILED" in out and "FAILED draws (not in the table): 0" in out
    plain = json.loads((tmp_path / "widening.json").read_text())
    assert [r["index"] for r in plain["plain_rows"]] == [1]
    assert plain["widening"]["draws"][0]["parameters"]["dead_zone"]["ratio"] == pytest.approx(2.0)
