"""Ctrl-C at every stage: each stage of ``tvcid discover`` (SINDy, the global search, the nested
structures, the ranking, the next test, a member's chain, the weights), ``tvcid predict`` and
``tvcid design`` stop within :data:`STOP_WITHIN` seconds of the signal, with status 130 and the
one-line message, and the same command again resumes or finishes.

Each test sends a real SIGINT to this process from inside the stage: from the first call of a
function the stage runs, in a pool's thread where the stage has one (the hard case: Python cannot
interrupt a thread, and the interpreter waits for a pool's running task at exit). There the
interrupted call stands for a task of minutes (it runs the stage's function :data:`REPEATS`
times): the test asserts that it was cut short and had ended when ``main`` returned, so that the
process exits at once.

The search stages run on a 14 s limit cycle with four structures left (friction offset and
backlash open) and searches cut short; the later stages on a stand-in ranking of two members
(:mod:`test_discover_resume`), their chains a few steps long.
"""
import contextlib
import io
import json
import os
import signal
import threading
import time
from types import SimpleNamespace

import pytest

import tvcid.discovery.structure
import tvcid.discovery.structure.ranking as ranking
import tvcid.discovery.structure.search as search
import tvcid.discovery.structure.structure_search as structure_search
import tvcid.pipeline
from test_discover_resume import FIXED, TRUTH, _Ranking
from tvcid.cli import main
from tvcid.discovery.calibration.backend import CheckpointBackend
from tvcid.discovery.structure.estimator import StructureDiscovery
from tvcid.discovery.threads import Stopped, thread_map
from tvcid.models import CONTROLLER_A, simulate
from tvcid.models.recording import recording_from_trajectory, save_recording

#: Seconds from the signal to ``main``'s return that the issue allows.
STOP_WITHIN = 10.0
#: Times the interrupted call runs the stage's function: far beyond STOP_WITHIN if it ran on.
REPEATS = 200
#: Seconds from the interrupted call's start to the signal: it comes amid the stage's work.
SIGNAL_AFTER = 0.2
#: The search stages' structures: everything but the friction offset, the backlash, the dead
#: zone and the delay fixed (four structures, two of them nested in another at one level).
SEARCH_FIXED = {k: FIXED[k] for k in ("dead_zone_position", "bandpass_gain", "gain", "damping",
                                      "stiffness", "feedback_gain")}
SEARCH_FIXED["delay_position"] = "before_first_integrator"
#: Chain length of the set's members, and the step after whose checkpoint Ctrl-C comes.
STEPS, STOP_AT = 6, 2


def _fixes(fixed):
    return [a for k, v in fixed.items() for a in ("--fix", f"{k}={v}")]


@pytest.fixture(autouse=True)
def ctrl_c_raises():
    """SIGINT raises KeyboardInterrupt, as in a ``tvcid`` started from a terminal (a test
    runner's worker may ignore it)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A 14 s limit cycle of :data:`test_discover_resume.TRUTH` under controller A."""
    columns, meta = recording_from_trajectory(simulate(TRUTH, CONTROLLER_A, 14.0, rate=1000.0))
    meta = {k: meta[k] for k in ("kind", "kp", "kd", "mu")}
    return str(save_recording(tmp_path_factory.mktemp("rec") / "rec.csv",
                              {k: columns[k] for k in ("t", "u", "delta")}, meta))


def signal_on_first_call(monkeypatch, owner, name, repeats=1, sig=signal.SIGINT):
    """Replace ``owner.name``: its first call runs the original ``repeats`` times, and
    :data:`SIGNAL_AFTER` seconds after it began, another thread sends ``sig`` to this process
    (as a terminal's Ctrl-C comes, whatever the stage is doing then); the other calls run the
    original once.

    Returns the record of the first call: ``thread`` (its name), ``sent`` (``time.monotonic()``
    at the signal), ``ended`` (when the call ended), ``cut_short`` (it ended by an interruption).
    """
    original = getattr(owner, name)
    record = SimpleNamespace(thread=None, sent=None, ended=None, cut_short=False)
    lock = threading.Lock()

    def send():
        record.sent = time.monotonic()
        os.kill(os.getpid(), sig)

    def first_call_signals(*args, **kwargs):
        with lock:
            first = record.thread is None
            if first:
                record.thread = threading.current_thread().name
        if not first:
            return original(*args, **kwargs)
        timer = threading.Timer(SIGNAL_AFTER, send)
        try:
            timer.start()
            for _ in range(repeats):
                result = original(*args, **kwargs)
            return result
        except KeyboardInterrupt:
            record.cut_short = True
            raise
        finally:
            record.ended = time.monotonic()
            timer.join()  # sent, if the call ended before it (the test then fails)

    monkeypatch.setattr(owner, name, first_call_signals)
    return record


def run_cli(args):
    """``tvcid ARGS`` in this process: ``(status, time.monotonic() at its return, stderr)``."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        status = main(args)
    return status, time.monotonic(), err.getvalue()


def assert_stopped(outcome, record, command="discover"):
    """Status 130, the one-line message and no traceback, within :data:`STOP_WITHIN` seconds
    of the signal."""
    status, returned, err = outcome
    assert record.sent is not None, "the stage was not reached"
    assert status == 130, err[-800:]
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith(f"tvcid {command}: interrupted; what was "
                                                   "saved is kept")
    assert returned - record.sent < STOP_WITHIN


def assert_threads_stopped(outcome, record):
    """The interrupted call ran in a pool's thread, was cut short and had ended when ``main``
    returned: nothing of the stage runs on."""
    assert record.thread.startswith("tvcid-"), record.thread
    assert record.cut_short and record.ended is not None and record.ended <= outcome[1]


def test_thread_map_interrupted_stops_its_running_tasks_and_the_next_call_runs():
    """Ctrl-C while a :func:`thread_map` waits: its tasks, each of which would run for a minute
    (a check per 10 ms), raise :class:`Stopped` at their next check, and so do the tasks they
    started; the call raises KeyboardInterrupt once all have ended, and the next call runs."""
    ended = []

    def inner(i):
        time.sleep(0.01)

    def task(i):
        try:
            for _ in range(6000):
                thread_map("interrupt-test-inner", 2, inner, range(2))
        finally:
            ended.append(time.monotonic())

    timer = threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    with pytest.raises(KeyboardInterrupt) as info:
        thread_map("interrupt-test", 3, task, range(6))
    returned = time.monotonic()
    timer.join()
    assert not isinstance(info.value, Stopped)  # the caller's own interruption
    assert len(ended) == 3 and max(ended) <= returned  # the three running; three never started
    assert thread_map("interrupt-test", 3, lambda x: 2 * x, range(6)) == [0, 2, 4, 6, 8, 10]


def test_sindy_stops_at_once(tmp_path, recording, monkeypatch):
    """Ctrl-C in SINDy's screening: status 130 with the one line."""
    from tvcid.discovery.sindy import WeakSINDyActuator

    record = signal_on_first_call(monkeypatch, WeakSINDyActuator, "fit")
    outcome = run_cli(["discover", recording, *_fixes(SEARCH_FIXED), "--no-mcmc",
                       "--no-progress", "--out", str(tmp_path / "out")])
    assert_stopped(outcome, record)
    assert record.cut_short and not (tmp_path / "out" / "discovery.json").exists()


def test_a_command_started_with_sigint_ignored_still_stops_on_it(tmp_path, recording,
                                                                 monkeypatch):
    """A command started with SIGINT ignored (a background job of a non-interactive shell:
    ``tvcid discover ... &`` in a script) stops on it all the same, with the one line; the
    handler it started with is back once it returns."""
    from tvcid.discovery.sindy import WeakSINDyActuator

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    record = signal_on_first_call(monkeypatch, WeakSINDyActuator, "fit", repeats=REPEATS)
    outcome = run_cli(["discover", recording, *_fixes(SEARCH_FIXED), "--no-mcmc",
                       "--no-progress", "--out", str(tmp_path / "out")])
    assert_stopped(outcome, record)
    assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN


@pytest.fixture
def small_search(monkeypatch):
    """Searches cut short, no SINDy seeds, no next test: the search stages in a few seconds."""
    monkeypatch.setitem(structure_search.SEARCHES, "standard", structure_search.SearchSizes(
        pop=3, gens=4, open_pop=3, open_gens=4, nfev=6, rank_nfev=3))
    monkeypatch.setattr(StructureDiscovery, "_sindy_seeds", lambda self, recs: ({}, "not run"))
    monkeypatch.setattr(tvcid.pipeline, "next_test", lambda *args, **kwargs: None)


@pytest.mark.parametrize("owner, sig", [
    (search, signal.SIGINT),  # a refinement of the search's best members (refine_all)
    (structure_search, signal.SIGINT),  # a nested structure refined from its parent's optimum
    (ranking, signal.SIGINT),  # one structure's refit on one fold
    (ranking, signal.SIGTERM),
], ids=["global", "nested", "ranking", "ranking-sigterm"])
def test_a_search_stage_stops_its_threads_and_the_same_command_finishes(
        tmp_path, recording, monkeypatch, small_search, owner, sig):
    """Ctrl-C (or SIGTERM) while a refinement runs in a pool's thread: status 130 and the one
    line within seconds, the refinement cut short at its next batch of simulations; no ranking
    written. The same command again, in the same process, runs to its end and writes the four
    structures' ranking."""
    args = ["discover", recording, *_fixes(SEARCH_FIXED), "--seed", "1", "--no-mcmc",
            "--no-progress", "--out", str(tmp_path / "out")]
    with monkeypatch.context() as m:
        record = signal_on_first_call(m, owner, "refine", repeats=REPEATS, sig=sig)
        outcome = run_cli(args)
    assert_stopped(outcome, record)
    assert_threads_stopped(outcome, record)
    assert not (tmp_path / "out" / "discovery.json").exists()
    status, _, err = run_cli(args)
    assert status == 0, err[-800:]
    summary = json.loads((tmp_path / "out" / "discovery.json").read_text())
    assert len(summary["structures"]) == 4 and not summary["resumed_ranking"]


@pytest.fixture
def stand_in_ranking(monkeypatch):
    """The stand-in ranking of two members (:class:`test_discover_resume._Ranking`)."""
    monkeypatch.setattr(tvcid.discovery.structure, "StructureDiscovery", _Ranking)


def test_the_next_test_stops_at_once_and_the_same_command_reuses_the_ranking(
        tmp_path, recording, monkeypatch, stand_in_ranking):
    """Ctrl-C while the next test weighs its first candidate: status 130 with the one line, the
    ranking written before it kept. The same command again reuses that ranking and makes the
    next test (stubbed here: its cost is not at issue)."""
    from tvcid.discovery.prediction import discrimination

    out = tmp_path / "out"
    args = ["discover", recording, *_fixes(FIXED), "--seed", "1", "--no-mcmc", "--no-progress",
            "--out", str(out)]
    with monkeypatch.context() as m:
        record = signal_on_first_call(m, discrimination, "_weighed", repeats=REPEATS)
        outcome = run_cli(args)
    assert_stopped(outcome, record)
    assert record.cut_short
    summary = json.loads((out / "discovery.json").read_text())
    assert len(summary["indistinguishable"]) == 2 and "next_test" not in summary
    monkeypatch.setattr(tvcid.pipeline, "next_test", lambda *args: {"best": None, "tests": []})
    status, _, err = run_cli(args)
    assert status == 0, err[-800:]
    summary = json.loads((out / "discovery.json").read_text())
    assert summary["resumed_ranking"] and summary["next_test"] == {"best": None, "tests": []}


@pytest.fixture(scope="module")
def set_runs(tmp_path_factory, recording):
    """The set stage of the stand-in ranking run three times in one directory: stopped by Ctrl-C
    after step :data:`STOP_AT` of the first member's chain, stopped again in the first member's
    weights (its evidence's importance draws), then run to its end. Each run's outcome and the
    chain steps it saved, ``(chain file, iteration)``, and the directory."""
    from tvcid.discovery.members import member_evidence

    out = tmp_path_factory.mktemp("set") / "out"
    args = ["discover", recording, *_fixes(FIXED), "--quick", "--seed", "1", "--max-steps",
            str(STEPS), "--no-progress", "--out", str(out)]
    runs = {}
    for name in ("chain", "weights", "end"):
        saved, record = [], SimpleNamespace(sent=None)
        save_step = CheckpointBackend.save_step

        def recording_save_step(self, state, accepted, saved=saved, record=record,
                                interrupt=name == "chain"):
            save_step(self, state, accepted)
            saved.append((os.path.basename(self.filename), self.iteration))
            if interrupt and self.iteration == STOP_AT and record.sent is None:
                record.sent = time.monotonic()
                os.kill(os.getpid(), signal.SIGINT)  # the chain stops after this checkpoint

        with pytest.MonkeyPatch.context() as m:
            m.setattr(tvcid.discovery.structure, "StructureDiscovery", _Ranking)
            m.setattr(tvcid.pipeline, "next_test", lambda *args, **kwargs: None)
            m.setattr(CheckpointBackend, "save_step", recording_save_step)
            if name == "weights":
                record = signal_on_first_call(m, member_evidence, "member_importance_draws",
                                              repeats=REPEATS)
            previous = signal.signal(signal.SIGINT, signal.default_int_handler)
            try:
                runs[name] = SimpleNamespace(outcome=run_cli(args), record=record, saved=saved)
            finally:
                signal.signal(signal.SIGINT, previous)
    runs["out"] = out
    return runs


def test_a_members_chain_stops_after_its_step_and_resumes_from_it(set_runs):
    """Ctrl-C in the first member's chain: status 130 with the one line, the chain stopped after
    the step whose checkpoint was being written; the same command again continues that chain
    from the next step to its cap (no step taken again)."""
    chain = set_runs["chain"]
    assert_stopped(chain.outcome, chain.record)
    first = chain.saved[0][0]
    assert chain.saved == [(first, i) for i in range(1, STOP_AT + 1)]
    resumed = set_runs["weights"].saved
    assert resumed == [(first, i) for i in range(STOP_AT + 1, STEPS + 1)]


def test_the_weights_stop_at_once_and_the_same_command_finishes_the_set(set_runs):
    """Ctrl-C in the first member's importance draws (its weight's evidence): status 130 with the
    one line, the draws cut short. The same command again adds no step to the first member's
    finished chain, runs the second's and writes the set's posterior over both members."""
    weights = set_runs["weights"]
    assert_stopped(weights.outcome, weights.record)
    assert weights.record.cut_short
    end = set_runs["end"]
    status, _, err = end.outcome
    assert status == 0, err[-800:]
    first = set_runs["chain"].saved[0][0]
    assert end.saved and all(name != first for name, _ in end.saved)
    assert [i for _, i in end.saved] == list(range(1, STEPS + 1))
    summary = json.loads((set_runs["out"] / "discovery.json").read_text())
    assert summary["resumed_ranking"]
    assert len(summary["set_posterior"]["members"]) == 2


def test_predict_stops_at_once_and_runs_again(set_runs, monkeypatch):
    """Ctrl-C in ``tvcid predict``'s first batch of simulations: status 130 with the one line;
    the same command again prints the prediction."""
    from tvcid.discovery.prediction import cycles

    args = ["predict", str(set_runs["out"]), "--draws", "10", "--pilot", "0", "--transient",
            "1", "--window", "2", "--no-df", "--json", "--no-progress"]
    with monkeypatch.context() as m:
        record = signal_on_first_call(m, cycles, "simulate_batch", repeats=REPEATS)
        outcome = run_cli(args)
    assert_stopped(outcome, record, "predict")
    assert record.cut_short
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status, _, err = run_cli(args)
    assert status == 0, err[-800:]
    assert "members" in json.loads(out.getvalue())


def test_design_stops_at_once_and_runs_again(set_runs, tmp_path, monkeypatch):
    """Ctrl-C while ``tvcid design`` simulates the draws through its first candidate: status 130
    with the one line, no ``design.json``; the same command again writes it."""
    from tvcid.discovery.prediction import design

    menu = tmp_path / "menu.json"
    menu.write_text(json.dumps([{"kind": "open", "waveform": "square", "amplitude": 0.01,
                                 "frequency": 1.0, "duration": 4.0}]))
    args = ["design", str(set_runs["out"]), "--candidates", str(menu), "--draws", "20",
            "--truths", "2", "--no-progress", "--out", str(tmp_path / "design")]
    with monkeypatch.context() as m:
        record = signal_on_first_call(m, design, "_observables", repeats=REPEATS)
        outcome = run_cli(args)
    assert_stopped(outcome, record, "design")
    assert record.cut_short and not (tmp_path / "design" / "design.json").exists()
    with contextlib.redirect_stdout(io.StringIO()):
        status, _, err = run_cli(args)
    assert status == 0, err[-800:]
    assert json.loads((tmp_path / "design" / "design.json").read_text())["ranking"]


def test_a_benchmark_started_with_sigint_ignored_still_stops_on_it(capsys):
    """A benchmark script's entry (:func:`tvcid.discovery.parallel.run_interruptible`) started
    with SIGINT ignored stops on it as a command does: status 130 and the one line, within a
    second of the signal; the handler it started with is back once it returns."""
    from tvcid.discovery.parallel import EXIT_INTERRUPTED, run_interruptible

    def main(argv):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(10.0)  # reached only if the signal is ignored
        return 0

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    t0 = time.perf_counter()
    status = run_interruptible(main, [])
    assert time.perf_counter() - t0 < 1.0
    assert status == EXIT_INTERRUPTED
    assert "interrupted" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
