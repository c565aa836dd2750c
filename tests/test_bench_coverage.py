"""The coverage benchmark (tvcid.studies.benchmarks.coverage): its quick run on a bundled draw, its summary,
its command line and its stored record.

Draw 0 of the quick config is bundled under ``data/bench/coverage_draw000`` as the benchmark
writes it, so that no default test spends two minutes of the reference path making it; a slow
test rebuilds it byte for byte. The coverage itself is a statistic over many draws: the stored
record's, checked in a slow test.
"""
import hashlib
import json
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ROOT / "data" / "bench" / "coverage_draw000"
RECORD = ROOT / "studies" / "benchmarks" / "records" / "bench_coverage.json"


@pytest.fixture(scope="module")
def quick_dir(tmp_path_factory):
    """One output directory for both likelihoods' quick runs, holding the bundled draw 0 where
    the benchmark looks for its recordings."""
    out = tmp_path_factory.mktemp("bench_coverage")
    shutil.copytree(BUNDLED, out / "data" / "draw000")
    return out


@pytest.fixture
def no_reference_path(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the bundled recordings were made again")

    monkeypatch.setattr("tvcid.studies.benchmarks.scenarios.simulate_reference", refuse)


def test_bundled_quick_draw_is_the_generators_own():
    """The bundled provenance is what the generator draws for the quick config's draw 0 today."""
    from tvcid.studies.benchmarks.coverage import QUICK, QUICK_WAVEFORM, coverage_scenario
    from tvcid.studies.benchmarks.scenarios import provenance

    stored = json.loads((BUNDLED / "truth" / "scenario.json").read_text())
    for config in (QUICK, QUICK_WAVEFORM):
        assert stored == provenance(coverage_scenario(0, config))


@pytest.mark.slow
def test_bundled_quick_draw_is_rebuilt_byte_for_byte(tmp_path):
    """The reference path remakes the bundled recordings exactly (about two minutes)."""
    from tvcid.studies.benchmarks.coverage import QUICK, coverage_scenario
    from tvcid.studies.benchmarks.scenarios import write_recordings

    for p in write_recordings(coverage_scenario(0, QUICK), tmp_path):
        for q in (p, p.with_suffix(".json")):
            assert hashlib.sha256(q.read_bytes()).digest() == \
                hashlib.sha256((BUNDLED / q.name).read_bytes()).digest(), q.name


def _check_row_is_the_draws(row, config, index=0):
    """The row calibrates draw ``index``'s truth: the parameters its structure has, each with the truth's
    value and the widened generator range as prior, the draw's design, a chain of the config's
    length, and a finite 90 % interval inside the prior."""
    from tvcid.models.structures import Structure
    from tvcid.studies.benchmarks.coverage import SAMPLED, coverage_scenario, priors_for

    scenario = coverage_scenario(index, config)
    priors = priors_for(Structure.of_params(scenario.truth))
    assert row["index"] == index and row["seed"] == config.seed + index
    assert row["structure"] == Structure.of_params(scenario.truth).name
    assert set(row["parameters"]) == {n for n in SAMPLED if n in priors}
    assert row["design"] == json.loads(json.dumps([r.__dict__ for r in scenario.recordings]))
    assert 0 < row["iterations"] <= config.max_steps and row["simulated_seconds"] > 0
    assert len(row["inflation"]) == len(scenario.recordings)
    for name, cell in row["parameters"].items():
        assert cell["truth"] == getattr(scenario.truth, name)
        assert cell["prior"] == [priors[name].low, priors[name].high]
        assert priors[name].low <= cell["q05"] < cell["q95"] <= priors[name].high, (name, cell)


def test_quick_run_on_the_bundled_draw_calibrates_the_draws_truth(quick_dir, no_reference_path):
    """``python -m tvcid.studies.benchmarks.coverage --quick --draws 1`` on the bundled recordings: one row
    for draw 0 (see :func:`_check_row_is_the_draws`), its summary and the rank figure."""
    from tvcid.studies.benchmarks.coverage import QUICK
    from tvcid.studies.benchmarks.coverage import main as bench_main

    assert bench_main(["--quick", "--draws", "1", "--out", str(quick_dir)]) == 0
    report = json.loads((quick_dir / "bench.json").read_text())
    (row,) = report["rows"]
    _check_row_is_the_draws(row, QUICK)
    assert report["summary"]["_all"]["draws"] == 1
    assert (quick_dir / "ranks.png").stat().st_size > 0


@pytest.mark.slow
def test_quick_run_with_the_waveform_likelihood_enters_each_record_its_own_way(tmp_path):
    """``--likelihood waveform --quick --indices 3`` (``tvcid fit``'s default likelihood) on the
    quick config's draw 3 (a limit cycle and two open-loop tests, no band-pass loop; its
    recordings made here): the closed-loop record enters by its waveform or, fallen back, its
    features, the open-loop ones by their output error, and the noise sd is sampled; draws with
    the band-pass loop are skipped, not run."""
    from tvcid.studies.benchmarks.coverage import QUICK_WAVEFORM, coverage_scenario, runs_with
    from tvcid.studies.benchmarks.coverage import main as bench_main

    assert bench_main(["--quick", "--likelihood", "waveform", "--draws", "4", "--indices", "3",
                       "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "bench.json").read_text())
    assert report["config"]["likelihood"] == "waveform"
    (row,) = report["rows"]
    _check_row_is_the_draws(row, QUICK_WAVEFORM, index=3)
    kinds = [d["kind"] for d in row["design"]]
    assert kinds.count("open") == 2 and kinds.count("closed") == 1
    assert len(row["likelihoods"]) == len(kinds)
    for how, kind in zip(row["likelihoods"].values(), kinds):
        assert how == "open" if kind == "open" else how in ("waveform", "features")
    banded = next(i for i in range(40) if coverage_scenario(i, QUICK_WAVEFORM).structure.bandpass)
    assert not runs_with(banded, QUICK_WAVEFORM) and runs_with(3, QUICK_WAVEFORM)


def test_summary_counts_coverage_ranks_and_inflation_of_known_rows():
    """Ten rows with one rank in each decile and the truth outside the interval in the first:
    coverage 0.9 and a flat rank histogram; a parameter some rows lack is counted over the rows
    that have it; inflation factors are pooled over records."""
    from tvcid.studies.benchmarks.coverage import RANK_BINS, summarise

    rows = []
    for i in range(10):
        cells = {"dead_zone": {"rank": (i + 0.5) / 10, "inside": i > 0, "relative_width": 0.1 * (i + 1)}}
        if i < 4:
            cells["delay"] = {"rank": 0.97, "inside": True, "relative_width": 0.2}
        rows.append({"parameters": cells, "inflation": [1.0, 4.0] if i == 0 else [1.0],
                     "converged": i != 3, "commit": "abc" if i < 5 else "def", "wall_s": float(i),
                     "simulated_seconds": 10.0 * i})
    s = summarise(rows)
    assert RANK_BINS == 10
    assert s["dead_zone"]["coverage"] == pytest.approx(0.9) and s["dead_zone"]["draws"] == 10
    assert s["dead_zone"]["rank_histogram"] == [1] * 10
    assert s["dead_zone"]["median_relative_width"] == pytest.approx(0.55)
    assert s["delay"] == {"draws": 4, "coverage": 1.0, "rank_histogram": [0] * 9 + [4],
                          "median_relative_width": pytest.approx(0.2)}
    assert s["_inflation"]["records"] == 11 and s["_inflation"]["max"] == 4.0
    assert s["_inflation"]["fraction_at_1"] == pytest.approx(10 / 11)
    assert s["_inflation"]["fraction_within_20_percent"] == pytest.approx(10 / 11)  # sqrt(4) = 2
    assert s["_all"]["converged"] == 9 and s["_all"]["commits"] == ["abc", "def"]


@pytest.mark.slow
def test_stored_record_covers_the_truth_80_to_97_percent_per_parameter():
    """The benchmark's claim on its stored record (``studies/benchmarks/records/bench_coverage.json``, the
    default config over 30 draws): every chain converged, and per parameter the 90 % intervals
    hold the truth in 80-97 % of the draws that sample it; the stored summary is the rows'."""
    from tvcid.studies.benchmarks.coverage import Config, summarise

    record = json.loads(RECORD.read_text())
    assert record["config"] == json.loads(json.dumps(Config().__dict__))
    rows = record["rows"]
    assert sorted(r["index"] for r in rows) == list(range(30))
    assert all(r["converged"] for r in rows)
    summary = summarise(rows)
    assert json.loads(json.dumps(summary)) == record["summary"]
    for name in ("dead_zone", "backlash", "delay", "friction_offset"):
        assert 0.80 <= summary[name]["coverage"] <= 0.97, (name, summary[name])


def test_stored_misses_and_all_but_one_discrepancy_are_in_draws_with_held_controllers():
    """``docs/limits.md``'s reading of the stored record: every truth outside its 90 % interval is
    in a draw whose controller is held at 200 Hz (zero-order hold), and so is every draw with a
    discrepancy factor over 1 but one."""
    rows = json.loads(RECORD.read_text())["rows"]

    def held(row):
        return any(d["kind"] == "closed" and d["controller_rate"] for d in row["design"])

    missed = [r for r in rows if not all(c["inside"] for c in r["parameters"].values())]
    inflated = [r for r in rows if max(r["inflation"]) > 1.0]
    assert missed and all(held(r) for r in missed)
    assert sum(not held(r) for r in inflated) == 1


@pytest.mark.slow
def test_a_stored_draw_rerun_gives_its_stored_interval(tmp_path):
    """The record is what the code gives: its shortest draw (22, about a minute of calibration
    after its recordings are made) calibrated again reproduces the stored quantiles."""
    from tvcid.studies.benchmarks.coverage import Config, run_draw

    stored = next(r for r in json.loads(RECORD.read_text())["rows"] if r["index"] == 22)
    row = run_draw(22, Config(), tmp_path)
    assert set(row["parameters"]) == set(stored["parameters"])
    for name, cell in row["parameters"].items():
        for q in ("q05", "q50", "q95"):
            assert cell[q] == pytest.approx(stored["parameters"][name][q], rel=1e-9), (name, q)


def test_bench_coverage_indices_select_draws_and_reject_bad_text():
    """``--indices 10,14-29`` selects those draws (ranges inclusive); text that is not N or N-M
    is refused with a message naming it."""
    from tvcid.studies.benchmarks.coverage import parse_indices

    assert parse_indices("10,14-16") == {10, 14, 15, 16}
    assert parse_indices("3") == {3}
    with pytest.raises(ValueError, match="'a-2' is not N or N-M"):
        parse_indices("a-2")


def test_oracle_gain_of_a_known_quadratic_and_bad_arguments(capsys):
    """``tvcid.studies.benchmarks.coverage_oracle``'s maximiser returns the drop from the truth (z = 0) to the
    optimum of a known quadratic, and where it is; a negative index is refused."""
    import numpy as np

    from tvcid.studies.benchmarks.coverage_oracle import _maximise
    from tvcid.studies.benchmarks.coverage_oracle import main as oracle_main

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
    from tvcid.models import OpenLoop, hypothesis, simulate
    from tvcid.models.recording import Recording
    from tvcid.studies.benchmarks.coverage_oracle import main as oracle_main
    from tvcid.studies.benchmarks.coverage_oracle import replay_chi_square
    from tvcid.studies.benchmarks.scenarios import RecordingDesign

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
    from tvcid.studies.benchmarks.coverage import widening

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
    from tvcid.studies.benchmarks.coverage import main as bench_main

    assert bench_main(["--quick", "--widening", "--out", str(tmp_path)]) == 1
    assert "no finished draws" in capsys.readouterr().out


def test_a_failing_draw_is_reported_and_the_others_still_run(tmp_path, monkeypatch, capsys):
    """Both the benchmark and ``--widening`` run their draws through ``run_draws``: a draw that
    raises is named in the output and in the exit status, the draws after it still run."""
    from dataclasses import asdict

    import tvcid.studies.benchmarks.coverage as bc

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
