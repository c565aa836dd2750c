"""tvcid discover / tvcid.discovery.structure: bad input, resuming, and recovery on drawn scenarios."""
import json
import math

import numpy as np
import pytest

from tvcid.discovery.members.member_calibration import member_walkers
from tvcid.discovery.structure import StructureDiscovery
from tvcid.discovery.structure.indistinguishable import TOL_ABS
from tvcid.discovery.structure.search import Objective
from tvcid.models.recording import save_recording
from tvcid.models.structures import Structure, shared_choices
from tvcid.studies.benchmarks.discovery import coordinate_errors
from tvcid.studies.benchmarks.scenarios import draw_scenario, shortened, write_recordings
from tvcid.cli import main

DATA = "data/m000_closed_A.csv"


def _write(path, delta, kind="closed", **meta):
    t = np.arange(delta.size) / 1000.0
    side = {"kind": kind, **({"kp": 5.84, "kd": 0.062, "mu": 12.3} if kind == "closed" else {}), **meta}
    save_recording(path, {"t": t, "u": np.zeros_like(t), "delta": delta}, side)
    return str(path)


@pytest.mark.parametrize("case, expected", [
    ("none", "no recording given"),
    ("no_cycle", "no limit cycle"),
    ("unknown_fix", "unknown parameter(s) dead_band"),
])
def test_bad_input_is_one_line_error(tmp_path, capsys, case, expected):
    """Discovery's own refusals (the recording-level catalogue is tests/test_bad_input_cli.py)."""
    t = np.arange(8000) / 1000.0
    args = ["discover", "--no-mcmc", "--no-progress", "--quick", "--out", str(tmp_path / "out")]
    if case == "no_cycle":
        args.insert(1, _write(tmp_path / "flat.csv", 1e-3 * np.exp(-t)))
    elif case == "unknown_fix":
        args[1:1] = [DATA, "--fix", "dead_band=1e-3"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err
    assert "Traceback" not in err and len(err.splitlines()) == 1


def test_unknown_search_size_names_the_choices():
    """An unknown search size is refused before any work, naming the sizes there are; the sizes
    are ordered (``thorough`` searches more than ``standard`` at every stage)."""
    from dataclasses import astuple

    from tvcid.discovery.structure.estimator import StructureDiscovery
    from tvcid.discovery.structure.structure_search import SEARCHES

    with pytest.raises(ValueError, match="unknown search size 'huge'.*standard, thorough"):
        StructureDiscovery(search="huge").fit([DATA])
    assert all(a < b for a, b in zip(astuple(SEARCHES["standard"]), astuple(SEARCHES["thorough"]))
               if a != b)
    assert SEARCHES["thorough"].gens > SEARCHES["standard"].gens


def test_a_thorough_run_never_reuses_a_standard_ranking():
    """The ranking's reuse key holds the search size (and not ``--quick``, which only shortens
    the chain): ``--thorough`` on a directory of a default run searches again."""
    from tvcid.models.recording import load_recording
    from tvcid.pipeline import inputs_hash

    recs = [load_recording(DATA)]
    assert inputs_hash(recs, {}, 0, "standard") != inputs_hash(recs, {}, 0, "thorough")
    assert inputs_hash(recs, {}, 0, "standard") == inputs_hash(recs, {}, 0, "standard")


def test_sidecar_hypothesis_and_parameters_are_ignored(tmp_path):
    """A sidecar's truth keys must not leak into discovery: the same data with and without them
    give the same targets."""
    from tvcid.discovery.structure.targets import make_target
    from tvcid.models.recording import load_recording

    rec = load_recording(DATA)
    assert "parameters" in rec.meta
    stripped = tmp_path / "a.csv"
    meta = {k: rec.meta[k] for k in ("kind", "kp", "kd", "mu")}
    save_recording(stripped, {k: rec.columns[k] for k in ("t", "u", "delta")}, meta)
    a, b = make_target(rec, 5e-4), make_target(load_recording(stripped), 5e-4)
    assert a.omega == b.omega and np.allclose(a.harmonics, b.harmonics)


#: Paper 002's placement with its backlash: the structure the known-positions draws are made of.
KNOWN_POSITIONS = Structure("error", "output", friction=False, backlash=True, bandpass=False)
#: Largest error allowed on log K where the design pins it (local spread at the truth under 2 %):
#: 2 %, over twice the largest seen over seeds 0-9 (0.84 % on draw 5; the same with the kernel's
#: data and the reference path's, which agree to the scores' third decimal).
PINNED_ERROR = 0.02


def _recover_known_positions(seed, directory, reference_path):
    """Discovery with the positions and the absence of the loop fixed on draw ``seed`` of
    :data:`KNOWN_POSITIONS` (records shortened to 12 s closed, 6 s open): the two structures left
    (backlash on/off) ranked; the generating one must be in the reported set, fitted at least as
    well as the truth, with log K within :data:`PINNED_ERROR`. Returns the errors of the
    coordinates the local spread at the truth calls pinned."""
    from unittest import mock

    from tvcid.models import simulate
    from tvcid.studies.benchmarks import scenarios

    s = KNOWN_POSITIONS
    scenario = shortened(draw_scenario(seed, structure=s), closed=12.0, open_=6.0)
    if reference_path:
        paths = write_recordings(scenario, directory)
    else:  # the numba kernel at the data's step in place of the plain-Python reference path
        with mock.patch.object(scenarios, "simulate_reference", simulate):
            paths = write_recordings(scenario, directory)
    for p in paths:
        side = json.loads(p.with_suffix(".json").read_text())
        assert "parameters" not in side and "hypothesis" not in side and "waveform" not in side
    fixed = {"dead_zone_position": "error", "delay_position": "output", "bandpass_gain": 0.0}
    disc = StructureDiscovery(fixed=fixed, seed=0, use_sindy=False).fit(paths)
    assert {f.structure for f in disc.ranking_} == {s, s.without("backlash")}
    fit = next(f for f in disc.ranking_ if f.structure == s)
    scores = [(f.structure.name, f.score) for f in disc.ranking_]
    assert fit.indistinguishable_from_best, (seed, scores)
    # the search's part: a fit at least as good as the truth (within what the ranking resolves)
    truth_cost = float(Objective(disc.targets_).costs([scenario.truth]).sum())
    assert fit.cost <= truth_cost + TOL_ABS * len(disc.targets_), (seed, fit.cost, truth_cost)
    # the local spread at the truth is a linear measure: along a curved valley a coordinate it
    # calls pinned can sit well off at the truth's cost (draw 3: log wn 3-4.5 % off at costs
    # 2.10-2.12 against the truth's 2.08), so only log K, which these designs pin (0.01-0.04 %
    # off on draw 3), is held to PINNED_ERROR
    errors = coordinate_errors(disc, scenario.truth, s)
    pinned = {k: v["error"] for k, v in errors.items() if v["identifiable"]}
    assert pinned.get("log_K", 0.0) <= PINNED_ERROR, (seed, errors)
    return pinned


@pytest.mark.parametrize("seed", [1, pytest.param(0, marks=pytest.mark.slow),
                                  pytest.param(3, marks=pytest.mark.slow)])
def test_recovers_a_drawn_truth_with_known_positions(tmp_path, seed):
    """Truths and designs drawn by the benchmark's generator (paper 002's placement: dead zone on
    the error, delay at the output, backlash; the linear block, thresholds, delay, controller
    settings, open-loop tests, acquisition and sensor drawn), records written with measured-style
    sidecars, made by the numba kernel (the reference path costs 1-3 s per simulated second; the
    slow test below uses it). These three designs pin log K; draws 0 and 3 run with the slow
    tests."""
    assert _recover_known_positions(seed, tmp_path, reference_path=False)


@pytest.mark.slow
def test_recovers_drawn_truths_with_known_positions_from_reference_data(tmp_path):
    """As above over seeds 0-6, the records made by the plain-Python reference path (a second
    implementation of the model) at the generator's 5e-5 s step: every generating structure in
    its set fitted at least as well as the truth, log K within :data:`PINNED_ERROR`, and at least 6
    of the 7 designs
    pinning one (measured: all 7; over seeds 0-9 draw 7, two limit cycles and no open-loop test,
    pins none) (~15 CPU-min, most of it the data)."""
    failures, pinned = {}, {}
    for seed in range(7):
        try:
            pinned[seed] = _recover_known_positions(seed, tmp_path / f"draw{seed}",
                                                    reference_path=True)
        except AssertionError as exc:
            failures[seed] = str(exc)[:300]
    assert not failures, failures
    assert sum(bool(v) for v in pinned.values()) >= 6, pinned


#: One structure (M000's placement with its band-pass loop fixed) on one record: a discovery of
#: seconds, so that the test is about resuming, not searching.
ONE_STRUCTURE = ["--fix", "dead_zone_position=velocity", "--fix", "delay_position=before_first_integrator",
                 "--fix", "friction_offset=0", "--fix", "backlash=1.1625e-4", "--fix", "bandpass_gain=72",
                 "--fix", "bandpass_saturation=0.01"]


def test_never_oscillating_structure_is_one_line_error(tmp_path, capsys):
    """A fixed linear block that cannot move the actuator: no candidate oscillates."""
    args = ["discover", DATA, *ONE_STRUCTURE, "--fix", "gain=1", "--fix", "damping=200",
            "--fix", "stiffness=14520", "--quick", "--no-mcmc", "--no-progress",
            "--out", str(tmp_path / "unused")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "no structure reproduces the recordings" in err and len(err.splitlines()) == 1


#: ``tvcid discover`` on one structure with a short chain, interrupted or not.
ONE_STRUCTURE_RUN = [DATA, *ONE_STRUCTURE, "--quick", "--seed", "2", "--max-steps", "60",
                     "--no-progress"]


def _blas_threads():
    from threadpoolctl import threadpool_info

    return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})


@pytest.fixture(scope="module")
def straight_discover(tmp_path_factory):
    """The uninterrupted run every interrupted one is compared with (made once). BLAS's threads
    outside it (two) and as its next test sees them are written beside it
    (``blas_threads.json``)."""
    from threadpoolctl import threadpool_limits

    import tvcid.pipeline as pipeline

    out = tmp_path_factory.mktemp("discover") / "straight"
    seen, original = {}, pipeline.next_test

    def next_test(*args, **kwargs):  # a stage outside the structure search's own limit
        seen["next_test"] = _blas_threads()
        return original(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp, threadpool_limits(limits=2, user_api="blas"):
        mp.setattr(pipeline, "next_test", next_test)
        seen["outside"] = _blas_threads()
        assert main(["discover", *ONE_STRUCTURE_RUN, "--out", str(out)]) == 0
    (out.parent / "blas_threads.json").write_text(json.dumps(seen))
    return out


def test_discover_of_one_structure_samples_it_and_decides_every_choice(straight_discover):
    """One structure given: the set is that structure, every choice is decided, and the chain
    samples the physical parameters (the noise sd stays at the records' estimate)."""
    straight = json.loads((straight_discover / "discovery.json").read_text())
    assert not straight["resumed_ranking"]
    assert "sigma" not in straight["posterior"]["parameters"]
    move = straight["posterior"]["laplace_move"]  # fitted to the chain at step 50 of 60
    assert move["adapted_at"] == 50 and 0.0 <= move["share"] <= 1.0
    assert {"dead_zone", "delay"} <= set(straight["posterior"]["parameters"])
    # the map of what the draws pin: every sampled parameter in a pinned direction or a free one
    pm = straight["posterior"]["pinned"]
    assert len(pm["shrinkages"]) == len(straight["posterior"]["parameters"])
    assert pm["free"] + len(pm["pinned"]) == len(pm["shrinkages"])
    assert all(c["text"] and c["low"] <= c["median"] <= c["high"] for c in pm["pinned"])
    only = Structure.parse(straight["structures"][0]["structure"])
    assert straight["decided"] == shared_choices([only])
    assert only.bandpass and None not in straight["decided"].values()
    report = (straight_discover / "report.md").read_text()
    assert "## What the recordings decide" in report and "- band-pass loop: decided, on" in report
    # where the time goes, in simulated seconds: each parameter set the search simulated runs
    # the one recording over its settling and window (one run, a few seconds to the record's
    # length), each point of the chain over the features' 10 s window at least
    simulated = straight["simulated_seconds"]
    assert set(simulated) == {"global", "nested", "ranking", "discovery", "mcmc", "mcmc_start",
                              "mcmc_evidence", "next_test"}
    search = ("global", "nested", "ranking")
    for ledger in (simulated, straight["simulated_steps"]):  # the search's whole, one entry
        assert ledger["discovery"] == pytest.approx(sum(ledger[k] for k in search), rel=1e-12)
    length = straight["targets"][0]["samples"] / straight["targets"][0]["sample_rate"]
    per_set = (simulated["global"] + simulated["nested"] + simulated["ranking"]) / straight["simulations"]
    assert 3.0 < per_set < length + 10.0
    chain = straight["posterior"]
    n_walkers = member_walkers(len(chain["parameters"]))
    # the chain's steps beside its start (the set-up and the search for the maximum)
    assert simulated["mcmc"] - simulated["mcmc_start"] >= chain["iterations"] * n_walkers * 10.0
    assert simulated["mcmc_start"] > 0
    assert "Simulated seconds (every run of every recording): global" in report


def test_discovery_json_counts_the_work_of_every_stage_and_member(straight_discover):
    """``discovery.json`` holds, per stage, the kernel steps beside the simulated seconds, the
    CPU and the wall seconds, and the same of the set's member in its row; the whole run has BLAS
    on one thread (two outside it)."""
    summary = json.loads((straight_discover / "discovery.json").read_text())
    steps, seconds = summary["simulated_steps"], summary["simulated_seconds"]
    assert set(steps) == set(seconds)
    # the chain's start (its optimisation and curvature) counted in steps as in seconds
    assert 0 < steps["mcmc_start"] < steps["mcmc"]
    assert steps["mcmc_start"] >= seconds["mcmc_start"] / 5e-4 * (1 - 1e-9)
    # one limit cycle, every search and ranking run at the search's 5e-4 s step (one structure:
    # no nested one to refine)
    assert steps["global"] > 0 and steps["ranking"] > 0 and steps["nested"] == 0.0
    for stage in ("global", "nested", "ranking"):
        assert steps[stage] == pytest.approx(seconds[stage] / 5e-4)
    # the chain's step is 5e-4 s or a fraction of it (halved under the delay prior's floor)
    assert steps["mcmc"] >= seconds["mcmc"] / 5e-4 * (1 - 1e-9)
    # a set of one: no weights to weigh, no next test to simulate
    assert steps["mcmc_evidence"] == seconds["mcmc_evidence"] == 0.0
    assert steps["next_test"] == seconds["next_test"] == 0.0
    cpu, wall = summary["cpu_seconds"], summary["timings"]
    for stage in ("sindy", "global", "nested", "ranking", "total", "discovery", "mcmc",
                  "next_test"):
        assert cpu[stage] >= 0.0 and wall[stage] >= 0.0, stage
    assert cpu["global"] > 0 and cpu["mcmc"] > 0 and cpu["total"] >= cpu["global"]
    (member,) = summary["set_posterior"]["members"]
    assert member["simulated_steps"] == pytest.approx(steps["mcmc"])
    assert member["simulated_seconds"] == pytest.approx(seconds["mcmc"])
    assert 0 < member["cpu_seconds"] and 0 < member["wall_seconds"] <= wall["mcmc"]
    blas = json.loads((straight_discover.parent / "blas_threads.json").read_text())
    assert blas == {"outside": [2], "next_test": [1]}


def test_the_speed_benchmark_records_each_stage_and_member_and_flags_a_busy_run(
        straight_discover):
    """The speed benchmark's row of a run: its stages' steps, CPU and wall seconds as
    ``discovery.json`` has them, each member's, and the idle check on the load average at the
    start and the kernel references before and after (here 30 % apart: flagged)."""
    from tvcid.studies.benchmarks.discover_speed import record

    summary = json.loads((straight_discover / "discovery.json").read_text())
    row = record(summary, 12.0, (0.1, 0.2, 0.3), 1.0e-7, 1.3e-7)
    for key in ("simulated_steps", "simulated_seconds", "cpu_seconds"):
        assert row[key] == summary[key]
    assert row["stages"] == summary["timings"] and row["wall_seconds"] == 12.0
    (member,) = summary["set_posterior"]["members"]
    assert row["members"] == [{k: member[k] for k in ("structure", "simulated_steps",
                                                      "simulated_seconds", "cpu_seconds",
                                                      "wall_seconds")}]
    assert row["kernel_cpu_seconds_per_step"] == {"before": 1.0e-7, "after": 1.3e-7}
    assert not row["idle_check"]["passed"] and "differ by 30% > 10%" in row["idle_check"]["reason"]


def test_discovery_result_reads_saves_reports_and_plots(straight_discover, tmp_path):
    """``tvcid.DiscoveryResult`` of a finished run: loads its ``discovery.json``, which is strict
    JSON (no NaN/Infinity tokens); saves the same summary elsewhere; its report starts with the
    one-screen summary (the structure, every physical quantity with its unit and 90 % interval
    over the set, the next test) with 4 significant digits; plots the ranking."""
    import matplotlib

    matplotlib.use("Agg")
    import tvcid

    text = (straight_discover / "discovery.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    result = tvcid.DiscoveryResult.load(straight_discover)
    assert result.best["structure"] == result.summary["structures"][0]["structure"]
    assert json.loads(json.dumps(result.to_dict(), allow_nan=False)) == json.loads(text)
    copy = tvcid.DiscoveryResult.load(result.save(tmp_path / "copy"))
    assert copy.to_dict() == result.to_dict()
    report = (tmp_path / "copy" / "report.md").read_text()
    assert report == (straight_discover / "report.md").read_text()
    head = report.split("## Recordings")[0]
    assert head.startswith("# tvcid discover\n\n## Summary\n")
    assert f"The recordings name one structure: `{result.best['structure']}`." in head
    combined = result.summary["set_posterior"]["quantities"]
    q = combined["dead_zone[velocity]"]
    assert f"| dead_zone[velocity] | {q['q50']:.4g} | [{q['q05']:.4g}, {q['q95']:.4g}] | rad/s |" in head
    for name, unit in (("delay", "s"), ("threshold", "rad/s"), ("dc_gain", "rad/rad"),
                       ("bandwidth", "rad/s")):
        q = combined[name]
        assert f"| {name} | {q['q50']:.4g} | [{q['q05']:.4g}, {q['q95']:.4g}] | {unit} | " in head
    assert "| backlash | 0.0001163 | [0.0001163, 0.0001163] | rad | fixed |" in head
    assert "Next test: none needed (one structure left)." in head
    # a chain stopped at its cap says so, with what continues it
    assert (f"**Not converged**: `{result.best['structure']}` (60 steps, " in head
            and "a larger `--max-steps` continues the chains" in head)
    ax = result.plot()
    assert len(ax.patches) == len(result.summary["structures"])
    with pytest.raises(ValueError, match="not a discovery.json"):
        tvcid.DiscoveryResult.load(tmp_path / "missing.json")


@pytest.fixture(scope="module")
def killed_discover(tmp_path_factory):
    """``tvcid discover`` killed by SIGKILL during its MCMC, once its chain holds 10 steps: its
    directory as the kill left it (made once; each test continues a copy)."""
    from sigkill import kill_once_checkpointed

    root = tmp_path_factory.mktemp("killed")
    killed = root / "killed"
    kill_once_checkpointed(["discover", *ONE_STRUCTURE_RUN, "--out", str(killed)], "chain-*.h5",
                           killed, min_steps=10, max_steps=60, stderr_path=root / "stderr.txt",
                           timeout=600)
    return killed


def _finished_like_straight(directory, straight_discover):
    """``discover`` rerun on ``directory`` reuses the ranking and finishes the chain, which equals
    the uninterrupted run's, step for step."""
    import emcee

    assert main(["discover", *ONE_STRUCTURE_RUN, "--out", str(directory)]) == 0
    resumed = json.loads((directory / "discovery.json").read_text())
    straight = json.loads((straight_discover / "discovery.json").read_text())
    assert resumed["resumed_ranking"] and not straight["resumed_ranking"]
    assert resumed["structures"][0]["params"] == straight["structures"][0]["params"]
    assert resumed["decided"] == straight["decided"]
    (chain,) = directory.glob("chain-*.h5")
    a = emcee.backends.HDFBackend(str(chain), read_only=True)
    b = emcee.backends.HDFBackend(str(straight_discover / chain.name), read_only=True)
    assert a.iteration == b.iteration == 60
    assert np.array_equal(a.get_chain(), b.get_chain())


def test_killed_then_interrupted_discover_resumes_ranking_and_chain(tmp_path, straight_discover,
                                                                    killed_discover):
    """``tvcid discover`` killed by SIGKILL during its MCMC has written its ranking; the rerun
    reuses the ranking (same inputs hash, no new search) and continues the chain. Stopped by
    Ctrl-C (SIGINT) while it does: status 130 and one line. The next rerun finishes the chain,
    which equals the uninterrupted run's, step for step."""
    import shutil
    import signal

    import emcee
    from sigkill import kill_once_checkpointed

    stopped = tmp_path / "stopped"
    shutil.copytree(killed_discover, stopped)
    ranking = json.loads((stopped / "discovery.json").read_text())
    assert "posterior" not in ranking and ranking["structures"]
    (chain,) = stopped.glob("chain-*.h5")
    before = emcee.backends.HDFBackend(str(chain), read_only=True).iteration
    saved = kill_once_checkpointed(["discover", *ONE_STRUCTURE_RUN, "--out", str(stopped)],
                                   "chain-*.h5", stopped, min_steps=before + 10, max_steps=60,
                                   stderr_path=tmp_path / "stderr.txt", timeout=600,
                                   sig=signal.SIGINT)
    assert before < saved < 60
    _finished_like_straight(stopped, straight_discover)


def test_a_copied_run_resumes_under_its_new_names(tmp_path, straight_discover):
    """A finished run and its recordings copied elsewhere (the loop benchmark's round 0 taken
    from the set-coverage benchmark): ``discover`` on the copies reuses the ranking and the
    finished chain, adds no step, and names the recordings it was given."""
    import shutil
    from pathlib import Path

    import emcee

    moved = tmp_path / "recordings"
    moved.mkdir()
    for f in (Path(DATA), Path(DATA).with_suffix(".json")):
        shutil.copy(f, moved / f.name)
    copied = tmp_path / "copied"
    shutil.copytree(straight_discover, copied)
    given = str(moved / Path(DATA).name)
    assert main(["discover", given, *ONE_STRUCTURE_RUN[1:], "--out", str(copied)]) == 0
    resumed = json.loads((copied / "discovery.json").read_text())
    assert resumed["resumed_ranking"]
    assert resumed["recordings"] == [given]
    (chain,) = copied.glob("chain-*.h5")
    a = emcee.backends.HDFBackend(str(chain), read_only=True)
    b = emcee.backends.HDFBackend(str(straight_discover / chain.name), read_only=True)
    assert a.iteration == b.iteration == 60 and np.array_equal(a.get_chain(), b.get_chain())


def test_period_two_cycle_is_measured_at_its_fundamental():
    """A cycle with two upward mean crossings per period (alternating lobes, as a controller held
    at 200 Hz can give) is measured at its true period; a cycle that only wanders is not mistaken
    for one."""
    from tvcid.models.cycle_reading import fundamental_crossings
    from tvcid.models.cycle_settling import stationary_tail

    rng = np.random.default_rng(3)
    t = np.arange(0, 30, 1e-3)
    w = 2 * np.pi / 0.63
    x = 1e-4 * np.sin(w * t) + 2e-4 * np.sin(2 * w * t + 0.4) + 1e-6 * rng.standard_normal(t.size)
    _, _, ups = stationary_tail(t, x)
    assert np.median(np.diff(ups)) == pytest.approx(0.63, rel=1e-3)
    jitter = np.cumsum(0.15 + 0.002 * rng.standard_normal(200))  # 1.3 % wander, one crossing each
    assert fundamental_crossings(jitter).size == jitter.size
    # period 1 whose peaks alternate by +-15 % (a narrow bump, as a beat with a held controller
    # gives): its sizes repeat at lag 2, but its harmonic at half the frequency is small, so it is
    # measured at its own period, and the alternation does not cut the stationary tail
    period = 0.4
    k = np.floor((t - 0.1) / period + 0.5)
    bump = 0.3 * np.where(k % 2 == 0, 1.0, -1.0) * np.exp(-(((t - 0.1 - k * period) / 0.01) ** 2))
    y = np.sin(2 * np.pi / period * t) + bump + 1e-4 * rng.standard_normal(t.size)
    t_tail, _, ups = stationary_tail(t, y)
    assert t_tail[-1] - t_tail[0] > 20.0
    assert np.median(np.diff(ups)) == pytest.approx(0.4, rel=1e-2)


def test_delay_moved_into_the_block_keeps_the_cycle():
    """Moving M000's delay from inside the second-order block's loop to after it (and back) with
    the matched linear block: the round trip returns within 0.5 % (each way matches over a band
    scaled by its own block's natural frequency; measured 0.26 %) and the moved model's cycles
    at controllers A and B agree within 0.3 % in amplitude and 0.05 % in frequency (measured
    0.12 % and 0.011 %; moving the delay alone changes the amplitude 3.6 % at A); this is why the
    ranking may leave the two positions undecided."""
    from tvcid.discovery.structure.transfer import delay_moved
    from tvcid.models import ClosedLoop, hypothesis, simulate
    from tvcid.models.hypotheses import DelayPosition

    p = hypothesis("M000")
    q = delay_moved(p, DelayPosition.BEFORE_INTEGRATOR)
    back = delay_moved(q, DelayPosition.BEFORE_FIRST_INTEGRATOR)
    for name in ("gain", "damping", "stiffness", "delay"):
        assert getattr(back, name) == pytest.approx(getattr(p, name), rel=5e-3)
    naive = p.replace(delay_position=DelayPosition.BEFORE_INTEGRATOR)
    for kp, kd, mu in ((5.84, 0.062, 12.3), (9.8, 0.06, 4.5)):
        f = [simulate(x, ClosedLoop(kp, kd, mu), 30.0).features(window=10.0) for x in (p, q, naive)]
        assert f[1].amplitude == pytest.approx(f[0].amplitude, rel=3e-3)
        assert f[1].frequency == pytest.approx(f[0].frequency, rel=5e-4)
        if kp == 5.84:
            assert abs(f[2].amplitude / f[0].amplitude - 1) > 0.03


def test_delay_moved_matches_the_frequency_response_of_drawn_blocks():
    """Drawn truths (the benchmark's generator, seed 11, 40 draws) with their delay moved across
    the block (inside <-> after): the moved block's frequency response over ``MATCHED_BAND`` is
    never further from the given one than the first-order match's, and where ``K2 Td <= 0.5`` it
    is within 1 % in gain and 0.01 rad in phase (measured <= 0.75 %), where the first-order match
    alone misses by over 5 % in some (it did on benchmark draw 1019: 29 %, and its refit stopped
    at cost 133 against the truth's 0.72)."""
    from tvcid.discovery.structure.transfer import (
        MATCHED_BAND,
        delay_moved,
        first_order_moved,
    )
    from tvcid.models.hypotheses import DelayPosition
    from tvcid.models.linear import second_order_response
    from tvcid.studies.benchmarks.scenarios import draw_truth

    rng = np.random.default_rng(11)
    inner = DelayPosition.BEFORE_FIRST_INTEGRATOR
    first_order_misses, small = 0, 0
    for _ in range(40):
        p = draw_truth(rng)
        inside = p.delay_position is inner
        to = DelayPosition.OUTPUT if inside else inner
        omega = np.geomspace(*MATCHED_BAND, 48) * math.sqrt(p.stiffness)
        given = second_order_response(p.gain, p.damping, p.stiffness, p.delay, inside, omega)
        errors = []
        for move in (delay_moved, first_order_moved):
            q = move(p, to)
            ratio = second_order_response(q.gain, q.damping, q.stiffness, q.delay, not inside,
                                          omega) / given
            errors.append(max(np.max(np.abs(np.log(np.abs(ratio)))),
                              np.max(np.abs(np.angle(ratio)))))
        assert errors[0] <= errors[1] + 1e-12
        if p.damping * p.delay <= 0.5:
            small += 1
            assert errors[0] <= 0.01, (p, errors)
            first_order_misses += errors[1] > 0.05
    assert small >= 10 and first_order_misses >= 1


def test_transferred_start_is_valid_for_every_structure_and_keeps_the_threshold():
    """Another structure's optimum carried over as a start (discovery's last cross-seeding): a
    valid parameter object of the target structure for every pair of the space; the threshold
    keeps its size in rad of error across dead-zone positions (z_error = (z - off) / g0) and a
    round trip velocity -> error -> velocity keeps the moving threshold z - off."""
    from tvcid.discovery.structure.transfer import transferred
    from tvcid.models import hypothesis
    from tvcid.models.hypotheses import DeadZonePosition
    from tvcid.models.structures import Structure, structure_space

    kept, _ = structure_space()
    m000 = hypothesis("M000")
    g0 = m000.gain / m000.stiffness
    sources = [m000, hypothesis("M002"), hypothesis("M001f")]
    for src in sources:
        for s in kept:
            p = transferred(src, s)
            assert Structure.of_params(p) == s, (src.name, s.name)
    err = Structure.parse("dz_error+delay_before_first_integrator+backlash")
    on_error = transferred(m000, err)
    assert on_error.dead_zone == pytest.approx((m000.dead_zone - m000.friction_offset) / g0, rel=1e-9)
    back = transferred(on_error, Structure.parse("dz_velocity+delay_before_first_integrator+backlash"))
    assert back.dead_zone_position is DeadZonePosition.VELOCITY
    assert back.dead_zone - back.friction_offset == pytest.approx(m000.dead_zone - m000.friction_offset,
                                                                  rel=1e-9)


def test_benchmark_counts_a_coordinate_moved_by_an_equally_good_fit_as_undecided():
    """The discovery benchmark's identifiability rule: a coordinate sharp at the truth but moved
    by over 5 % in a fit of the truth's structure that costs no more than the truth is left open
    by the recordings (not a discovery error); the same miss with a worse fit is an error."""
    from tvcid.studies.benchmarks.verdicts import undecided_marked

    def row(own_cost):
        return {"truth_structure_cost": own_cost, "cost_at_truth": 0.78,
                "coordinates": {"delay": {"identifiable": True, "within": False, "error": 0.46},
                                "log_K": {"identifiable": True, "within": True, "error": 0.003}}}

    as_good = undecided_marked(row(0.12))
    assert as_good["identifiable_within"] and not as_good["coordinates"]["delay"]["identifiable"]
    assert as_good["coordinates"]["log_K"]["identifiable"]
    assert not undecided_marked(row(1.5))["identifiable_within"]


def test_benchmark_scores_each_structural_choice_the_reported_set_decides():
    """A set that shares the truth's dead-zone position and band-pass loop but holds two delay
    positions and disagrees on the backlash decides two choices right, leaves two open, and
    decides the friction offset (absent in every member, present in the truth) wrong; a failed
    draw decides nothing."""
    from tvcid.studies.benchmarks.verdicts import choice_verdicts

    row = {"structure": "dz_velocity+delay_output+friction+bandpass",
           "set": ["dz_velocity+delay_output+bandpass", "dz_velocity+delay_before_integrator+bandpass",
                   "dz_velocity+delay_output+backlash+bandpass"]}
    assert choice_verdicts(row) == {"dead_zone_position": "right", "delay_position": "open",
                                    "friction": "wrong", "backlash": "open", "bandpass": "right"}
    assert set(choice_verdicts({"structure": row["structure"], "set": []}).values()) == {"open"}


@pytest.mark.slow
def test_open_loop_stage_reaches_the_open_loop_optimum(tmp_path):
    """Benchmark draw 1002 (two band-pass cycles of 0.37 mrad, a dead zone of 0.2 mrad of error,
    two open-loop sines; records shortened): the cycles' features jump within 1 % of the linear
    block, so the staged search first fits the open-loop tests alone, and the box it then keeps
    is centred on that fit. In each of 3 independent runs the open-loop stage must reach the
    truth's open-loop cost (within 0.3 per recording) and put every log coordinate the open-loop
    tests pin at the truth (local spread under 2 %, the benchmark's rule) within 5 % of it
    (~4 CPU-min)."""
    import math

    from tvcid.discovery.structure.coordinates import SearchSpace
    from tvcid.discovery.structure.search import Objective, local_sd
    from tvcid.discovery.structure.global_fit import GlobalFit
    from tvcid.discovery.structure.structure_search import SEARCHES, TEMPLATE, _fixed_for
    from tvcid.discovery.structure.targets import make_target
    from tvcid.models.hypotheses import ActuatorParams

    scenario = shortened(draw_scenario(1002, ranges="papers"), closed=12.0, open_=6.0)
    paths = write_recordings(scenario, tmp_path)
    disc = StructureDiscovery(seed=0, use_sindy=False)
    targets = [make_target(load, disc.dt) for load in _loaded(paths)]
    open_targets = [t for t in targets if t.kind == "open"]
    objective = Objective(targets)
    s = scenario.structure
    space = SearchSpace(s, ActuatorParams(**TEMPLATE), _fixed_for(s, {}), disc.dt)
    at_truth = float(objective.costs([scenario.truth], open_targets)[0].sum())
    truth = space.coordinates(scenario.truth)
    sd = local_sd(space, objective, truth, targets=open_targets)
    pinned = [j for j, n in enumerate(space.names) if n.startswith("log_") and sd[j] < 0.02]
    assert {"log_g0", "log_K"} <= {space.names[j] for j in pinned}
    for seed in range(3):
        search = GlobalFit(objective, SEARCHES["standard"], np.random.default_rng(seed))
        fit = search.fit_open_loop(space, open_targets, [])
        assert fit.cost <= at_truth + 0.3 * len(open_targets)
        for j in pinned:
            assert abs(math.expm1(fit.theta[j] - truth[j])) < 0.05, space.names[j]


def _loaded(paths):
    from tvcid.models.recording import load_recording

    return [load_recording(p) for p in paths]


@pytest.mark.parametrize("bad", [dict(damping=0.0), dict(damping=-5.0), dict(stiffness=-100.0),
                                 dict(stiffness=0.0, damping=0.0)])
def test_a_seed_with_an_unphysical_linear_block_starts_at_the_box_edge(bad):
    """SINDy can return K2 = 0 or a negative K3; such a seed must not stop discovery (the log
    coordinates of a value <= 0 would raise 'math domain error'). Its coordinates are finite,
    inside the box, and those that do not involve the bad value are the valid seed's."""
    from tvcid.discovery.structure.coordinates import SearchSpace
    from tvcid.discovery.structure.structure_search import TEMPLATE, _fixed_for
    from tvcid.models import hypothesis
    from tvcid.models.hypotheses import ActuatorParams
    from tvcid.models.structures import structure_space

    kept, _ = structure_space()
    for s in kept:
        good = s.to_params(hypothesis("M000"))
        space = SearchSpace(s, ActuatorParams(**TEMPLATE), _fixed_for(s, {}), 5e-4)
        ref = space.coordinates(good)
        theta = space.coordinates(good.replace(**bad))
        assert np.all(np.isfinite(theta)), s.name
        assert np.all((theta >= space.low) & (theta <= space.high)), s.name
        for j, name in enumerate(space.names):
            if name in ("log_K", "log_z", "log_r", "delay", "log_G", "log_off", "lam"):
                assert theta[j] == ref[j], (s.name, name)
        assert space.params(theta) is not None


def test_a_superset_of_a_member_joins_the_set_merged_whatever_its_own_fit_scored():
    """The set rule (:func:`tvcid.discovery.structure.indistinguishable.indistinguishable_set`): the best and a
    structure within the floor's margin are members; the best's backlash superset, whose fit
    scored far worse (a search failure: at zero backlash it is the best), is merged into it and
    so is an unranked friction superset; a structure with another delay position that scored
    worse than the margin stays out, and the winner is the best unmerged structure."""
    from tvcid.discovery.structure.indistinguishable import indistinguishable_set
    from tvcid.discovery.structure.ranking import StructureFit

    def fit(name, score):
        folds = np.full((2, 2), score / 2.0)
        return StructureFit(structure=Structure.parse(name), params=None, theta=np.zeros(1),
                            cost=score, cost_by_recording={}, origin="test", score=score,
                            fold_costs=folds)

    best = fit("dz_velocity+delay_output", 0.50)
    near = fit("dz_error+delay_output", 0.62)       # within 2 x TOL_ABS = 0.2
    superset = fit("dz_velocity+delay_output+backlash", 3.0)
    unranked = fit("dz_velocity+delay_output+friction+backlash", float("inf"))
    other = fit("dz_velocity+delay_before_integrator", 0.95)
    ranked = indistinguishable_set([best, near, other, superset, unranked], n_recordings=2)
    assert ranked[0] is best
    inside = {f.structure.name: f.merged_into for f in ranked if f.indistinguishable_from_best}
    assert inside == {"dz_velocity+delay_output": None, "dz_error+delay_output": None,
                      "dz_velocity+delay_output+backlash": "dz_velocity+delay_output",
                      "dz_velocity+delay_output+friction+backlash": "dz_velocity+delay_output"}
    assert not other.indistinguishable_from_best
    # the truth's structure is a superset of a member: the benchmark counts it inside the set
    assert shared_choices([f.structure for f in ranked if f.indistinguishable_from_best])[
        "backlash"] is None


def test_every_structure_within_the_screen_is_ranked_however_many_fit():
    """One cycle that every structure of the grammar fits about equally (costs of a few
    thousandths): all of them get the out-of-sample ranking, so none leaves the set by the
    order of its in-sample cost; a fit far outside the screen is still left unranked."""
    from tvcid.discovery.structure.ranking import (
        StructureFit,
        in_sample_screen,
        ranked_candidates,
    )
    from tvcid.models.structures import all_structures

    rng = np.random.default_rng(1009)
    names = [str(s) for s in all_structures()]
    costs = np.sort(rng.uniform(0.0005, 0.004, len(names) - 1))
    order = [StructureFit(structure=Structure.parse(n), params=None, theta=np.zeros(1), cost=c,
                          cost_by_recording={}, origin="test")
             for n, c in zip(names, costs)]
    far = in_sample_screen(costs[0], n_recordings=1) + 0.1
    order.append(StructureFit(structure=Structure.parse(names[-1]), params=None,
                              theta=np.zeros(1), cost=far, cost_by_recording={}, origin="test"))
    ranked = ranked_candidates(order, max_ranked=8, n_recordings=1)
    assert len(names) > 24 and ranked == order[:-1]
    assert ranked_candidates(order[:3] + order[-1:], max_ranked=8, n_recordings=1) == \
        order[:3] + order[-1:]


def test_recordings_that_do_not_discriminate_widen_the_margin_in_quadrature():
    """The margin's floors add like independent errors (:func:`.indistinguishable.indistinguishable_margin`):
    a structure worse by 0.07 on every one of five recordings, the two folds agreeing (benchmark
    draw 1017's dead zone on the error: +0.02 to +0.14 on each, 0.35 in all), is outside the
    margin of ``2 sqrt(5) TOL_ABS / 2`` = 0.224 (a linear sum of the floors, 0.5, kept it inside);
    the same 0.07 on one recording alone is inside; one recording's margin is two standard
    errors where its floor sets them, and Student's t quantile at one degree of freedom (13.97
    standard errors) where its folds' disagreement does: two folds estimate the noise from one
    difference."""
    from scipy import stats

    from tvcid.discovery.structure.indistinguishable import (
        MARGIN_QUANTILE,
        TOL_ABS,
        indistinguishable_margin,
        margin_degrees,
    )

    best = np.zeros((2, 5))
    everywhere = np.full((2, 5), 0.07)
    once = np.zeros((2, 5))
    once[:, 2] = 0.07
    margin = indistinguishable_margin(best, everywhere, 5)
    assert margin == pytest.approx(math.sqrt(5) * TOL_ABS)
    assert everywhere.mean(axis=0).sum() > margin > once.mean(axis=0).sum()
    t1 = stats.t.ppf(MARGIN_QUANTILE, 1)
    assert t1 == pytest.approx(13.97, abs=0.01)
    assert indistinguishable_margin(best[:, :1], np.array([[0.3], [0.1]]), 1) == pytest.approx(
        t1 * 0.1)
    assert indistinguishable_margin(best[:, :1], np.array([[0.11], [0.1]]), 1) == pytest.approx(TOL_ABS)
    # a recording's own floor (a wandering cycle's window cost) counts for that recording alone
    floors = np.array([0.4, TOL_ABS, TOL_ABS, TOL_ABS, TOL_ABS])
    assert indistinguishable_margin(best, everywhere, 5, floors) == pytest.approx(
        math.sqrt(0.4**2 + 4 * TOL_ABS**2))
    # two recordings whose folds set the error and three whose floors do: Welch-Satterthwaite
    mixed = np.zeros((2, 5))
    mixed[0, :2], mixed[1, :2] = 0.5, 0.1  # sd 0.2 each, estimated
    nu = (2 * 0.2**2 + 3 * 0.05**2) ** 2 / (2 * 0.2**4)
    assert margin_degrees([0.2, 0.2, 0.05, 0.05, 0.05], [True, True, False, False, False]) == \
        pytest.approx(nu)
    assert indistinguishable_margin(best, mixed, 5) == pytest.approx(
        stats.t.ppf(MARGIN_QUANTILE, nu) * math.sqrt(2 * 0.2**2 + 3 * 0.05**2))


def test_wandering_cycles_raise_the_margin_floor(tmp_path):
    """The bundled benchmark draw 1000 (two band-pass cycles at 200 Hz, which wander from period
    to period): each cycle's window cost, over windows of 24 periods, is above ``TOL_ABS``
    (measured 0.118 and 0.110), and a structure 0.15 worse than the best is inside the set with
    these floors, outside with the default ones. A periodic cycle (benchmark draw 1019's truth,
    no band-pass loop, 25 s at its first controller) keeps the default floor (its window cost
    under it, from the pieces' ends at sampled crossings)."""
    from pathlib import Path

    from tvcid.discovery.structure.indistinguishable import (
        TOL_ABS,
        indistinguishable_set,
        margin_floors,
    )
    from tvcid.discovery.structure.ranking import StructureFit
    from tvcid.discovery.structure.targets import make_target
    from tvcid.models import ClosedLoop, simulate
    from tvcid.models.recording import load_recording, recording_from_trajectory

    bundled = Path(__file__).resolve().parents[1] / "data" / "bench" / "draw1000"
    targets = [make_target(load_recording(p), 5e-4) for p in sorted(bundled.glob("rec*.csv"))]
    floors = margin_floors(targets)
    assert [t.window_periods for t in targets] == [24, 24]
    assert floors.shape == (2,) and np.all(floors > 1.05 * TOL_ABS)

    def fit(name, score):
        return StructureFit(structure=Structure.parse(name), params=None, theta=np.zeros(1),
                            cost=score, cost_by_recording={}, origin="test", score=score,
                            fold_costs=np.full((2, 2), score / 2.0))

    for given, inside in ((None, False), (floors, True)):
        best = fit("dz_velocity+delay_before_integrator+backlash+bandpass", 0.753)
        truth = fit("dz_velocity+delay_before_first_integrator+backlash+bandpass", 0.903)
        indistinguishable_set([best, truth], n_recordings=2, floors=given)
        assert truth.indistinguishable_from_best is inside

    scenario = draw_scenario(1019, ranges="papers")
    closed = next(r for r in scenario.recordings if r.kind == "closed")
    run = simulate(scenario.truth, ClosedLoop(closed.kp, closed.kd, closed.mu), 25.0, rate=1000.0)
    path = save_recording(tmp_path / "cycle.csv", *recording_from_trajectory(run))
    cycle = make_target(load_recording(path), 5e-4)
    assert cycle.window_cost < TOL_ABS and margin_floors([cycle])[0] == TOL_ABS


def _held_m000_records(tmp_path):
    """Paper 000's model recorded as the HWIL did (the held-out case ``m000_hwil``, made here by
    the kernel at 1e-4 s): controller held at 200 Hz, 40 s at 200 Hz after a 10 s lead, noise
    2e-5 rad, offset 1.5e-4 rad, quantisation 2e-5 rad; controllers A and B."""
    from tvcid.models import hypothesis
    from tvcid.models.recording import load_recording
    from tvcid.models.simulate import simulate
    from tvcid.models.synthetic import Acquisition
    from tvcid.studies.benchmarks.scenarios import CONTROLLERS, RecordingDesign

    truth, acq, recs = hypothesis("M000"), Acquisition(2e-5, 1.5e-4, 2e-5), []
    for i, (kp, kd, mu) in enumerate(CONTROLLERS):
        rd = RecordingDesign("closed", 40.0, 200.0, kp, kd, mu, controller_rate=200.0)
        tr = simulate(truth, rd.experiment(), 50.0, dt=1e-4, rate=200.0)
        keep = tr.t >= 10.0 - 1e-9
        path = tmp_path / f"held{i}.csv"
        save_recording(path, {"t": tr.t[keep] - tr.t[keep][0], "u": tr.u[keep],
                              "delta": acq.measure(tr.delta[keep], np.random.default_rng([7, i]))},
                       {"kind": "closed", "kp": kp, "kd": kd, "mu": mu, "controller_rate": 200.0})
        recs.append(load_recording(path))
    return truth, recs


def test_a_wandering_cycle_is_compared_over_enough_periods(tmp_path, monkeypatch):
    """Paper 000's band-pass cycle held at 200 Hz is not periodic; the record's features average
    its wander over 50 periods. The simulated window holds as many periods as the record's tail,
    up to ``MAX_WINDOW_PERIODS`` (24): the truth then lies within 0.1 units per recording of its
    own records whatever the transient (4-16 s); windows of 6 periods leave it 0.3-0.6 units off on
    controller A's record, where periodic wrong structures fit at 0.04-0.1 and take its place."""
    import tvcid.discovery.structure.targets as targets
    from tvcid.discovery.structure.search import Objective

    truth, recs = _held_m000_records(tmp_path)

    def costs(most=targets.MAX_WINDOW_PERIODS, least=targets.WINDOW_PERIODS):
        monkeypatch.setattr(targets, "WINDOW_PERIODS", least)
        monkeypatch.setattr(targets, "MAX_WINDOW_PERIODS", most)
        out = []
        for transient in (4.0, 8.0, 12.0, 16.0):
            monkeypatch.setattr(targets, "TRANSIENT", transient)
            made = [targets.make_target(r, 5e-4) for r in recs]
            out.append(Objective(made).costs([truth])[0])
        return np.array(out), made

    found, made = costs()
    # tails of over 24 periods; controller B's cycle still grows over its first periods, so its
    # run is compared as a transient over all of them
    assert [t.settling for t in made] == [False, True]
    assert made[0].window_periods == 24 and made[1].window_periods > 24
    assert found.max() < 0.1
    assert costs(6, 6)[0][:, 0].min() > 0.25


class _ScriptedSearch:
    """A search whose successive results have the given costs."""

    def __init__(self, costs):
        self.costs = list(costs)
        self.calls = 0

    def __call__(self):
        from types import SimpleNamespace

        self.calls += 1
        return SimpleNamespace(cost=self.costs[self.calls - 1])


@pytest.mark.parametrize("costs, n_recordings, least, most, calls, best", [
    ([5.0, 5.1, 0.1], 1, 2, 8, 2, 5.0),                # the first two agree: no third search
    ([5.0, 5.1, 0.1, 0.15], 1, 3, 8, 4, 0.1),          # ... unless three are required
    ([40.0, 27.0, 26.5, 1.2, 1.1], 2, 3, 8, 5, 1.1),   # draw 1019's pattern: on until two agree
    ([3.0, 9.0, 2.0, 7.0], 1, 2, 4, 4, 2.0),           # never agree: every allowed search runs
    ([3.0, 9.0], 1, 1, 1, 1, 3.0),                     # one allowed: one run
])
def test_restarted_searches_stop_when_the_best_two_agree(costs, n_recordings, least, most, calls,
                                                          best):
    from tvcid.discovery.structure.global_fit import best_of_restarts

    search = _ScriptedSearch(costs)
    fit = best_of_restarts(search, n_recordings, least, most)
    assert search.calls == calls
    assert fit.cost == best and fit.restarts == calls


def test_restarts_out_of_order_are_an_error():
    from tvcid.discovery.structure.global_fit import best_of_restarts

    with pytest.raises(ValueError, match="min"):
        best_of_restarts(_ScriptedSearch([1.0]), 1, 3, 2)
