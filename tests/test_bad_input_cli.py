"""Every ``tvcid`` command, fed the catalogue of bad inputs (``tests/bad_inputs.py``), ends with
exit status 2 and one line on stderr naming the file, column/row, option or parameter at fault;
no traceback; a failing run leaves what an earlier run wrote untouched; docs/cli.md's table is
the catalogue's answers, rendered."""
import hashlib
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import bad_inputs as cat
import pytest

CLI_DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


@pytest.fixture(scope="module")
def good():
    return cat.good_records()


def _assert_one_line_error(status, err, expect):
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert status == 2, f"exit status {status}, stderr {err!r}"
    assert len(lines) == 1, f"{len(lines)} lines on stderr: {err!r}"
    assert re.search(expect, lines[0]), f"{lines[0]!r} does not match {expect!r}"


@pytest.mark.parametrize("command", list(cat.RECORDING_COMMANDS))
@pytest.mark.parametrize("case", cat.RECORDING_CASES, ids=lambda c: c.key)
def test_bad_recording_is_one_line_naming_the_culprit(case, command, good, tmp_path):
    status, err = cat.answer(case, command, good, tmp_path)
    _assert_one_line_error(status, err, case.expected(command))


@pytest.mark.parametrize("case", cat.OPTION_CASES, ids=lambda c: c.key)
def test_bad_option_or_parameter_is_one_line_naming_it(case, good, tmp_path):
    status, err = cat.option_answer(case, good, tmp_path)
    _assert_one_line_error(status, err, case.expect)


def test_every_command_is_in_the_catalogue():
    """A new command must join the catalogue (recording cases or option cases)."""
    from tvcid.cli import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    covered = set(cat.RECORDING_COMMANDS) | {c.argv[0] for c in cat.OPTION_CASES}
    assert set(sub.choices) <= covered, sorted(set(sub.choices) - covered)


def test_declared_degrees_are_converted_not_refused(good, tmp_path):
    """The degrees case is refused only when undeclared: ``"units": {"u": "deg", "delta": "deg"}``
    reads back the radians."""
    import numpy as np

    from tvcid.models.recording import load_recording

    path = cat._degrees(good, tmp_path)
    path.with_suffix(".json").write_text('{"kind": "open", "units": {"u": "deg", "delta": "deg"}}')
    rec = load_recording(path)
    assert np.allclose(rec.u, good.open_columns["u"], rtol=1e-12, atol=1e-15)
    assert rec.meta["units"]["delta"] == "rad"


def _digest(directory: Path) -> dict:
    return {p.relative_to(directory).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(directory.rglob("*")) if p.is_file()}


def test_failing_runs_keep_what_was_written(good, tmp_path):
    """A chain and its summary written by ``tvcid fit``, and a results directory of ``tvcid
    discover``, survive failing runs into the same output byte for byte: a broken recording, a
    different set-up (refused: the stored chain is not overwritten), an unknown parameter."""
    good_csv = cat.write_csv(tmp_path / "good.csv", cat._copy(good.closed_columns), good.closed_meta)
    broken = cat.RECORDING_CASES[0].make(good, tmp_path)  # NaN in delta
    out = tmp_path / "fit"
    base = ["fit", "--hypothesis", "M002", "--walkers", "8", "--window", "3", "--transient", "2",
            "--max-steps", "4", "--no-progress", "--out", str(out)]
    status, err = cat.run_cli([*base, str(good_csv), "--params", "dead_zone,backlash"])
    assert status == 0, err
    before = _digest(out)
    assert "chain.h5" in before and "summary.json" in before
    for argv, expect in (
        ([*base, str(broken), "--params", "dead_zone,backlash"], r"holds NaN"),
        ([*base, str(good_csv), "--params", "dead_zone,delay"], r"chain\.h5 holds a run with a different set-up"),
        ([*base, str(good_csv), "--params", "dead_zone,frictin"], r"frictin"),
    ):
        status, err = cat.run_cli(argv)
        _assert_one_line_error(status, err, expect)
        assert _digest(out) == before

    disc = tmp_path / "disc"
    disc.mkdir()
    (disc / "discovery.json").write_text('{"structures": ["an earlier run"]}')
    (disc / "chain-earlier.h5").write_bytes(b"an earlier chain")
    before = _digest(disc)
    status, err = cat.run_cli(["discover", str(broken), "--quick", "--out", str(disc)])
    _assert_one_line_error(status, err, r"holds NaN")
    assert _digest(disc) == before


def test_internal_error_is_one_line_with_exit_1(monkeypatch, capsys):
    """A bug (an exception no validator raised) still reaches the user as one line, exit 1, with
    the way to see its traceback."""
    from tvcid import cli
    from tvcid.commands import features

    def broken(args):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(features, "run", broken)
    status = cli.main(["features", "whatever.csv"])
    err = capsys.readouterr().err
    assert status == 1 and len(err.strip().splitlines()) == 1
    assert "internal error: ZeroDivisionError: division by zero" in err and "TVCID_DEBUG=1" in err


def test_sigterm_during_discovery_ranking_exits_cleanly(good, tmp_path):
    """SIGTERM while ``discover`` is searching (not sampling): status 130, one line, and no
    half-written ranking left behind for a rerun to trust."""
    from sigkill import CLI

    rec = cat.write_csv(tmp_path / "good.csv", cat._copy(good.closed_columns), good.closed_meta)
    out = tmp_path / "disc"
    err_path = tmp_path / "stderr.txt"
    with open(err_path, "w") as err_file:
        proc = subprocess.Popen([*CLI, "discover", str(rec), "--quick", "--no-progress", "--out", str(out)],
                                stdout=subprocess.DEVNULL, stderr=err_file)
    deadline = time.time() + 120
    while time.time() < deadline and not out.exists() and proc.poll() is None:
        time.sleep(0.05)
    time.sleep(3.0)  # inside the search
    assert proc.poll() is None, open(err_path).read()
    proc.send_signal(signal.SIGTERM)
    status = proc.wait(timeout=60)
    err = open(err_path).read()
    assert status == 130 and "Traceback" not in err, err
    assert err.strip().splitlines()[-1].startswith("tvcid discover: interrupted")
    assert not (out / "discovery.json").exists()


def test_cli_doc_table_is_the_catalogues_answers(tmp_path):
    """docs/cli.md's "Bad input" table equals the one rendered from the commands' answers now
    (regenerate with ``python tests/bad_inputs.py --readme``)."""
    text = CLI_DOC.read_text()
    span = cat.readme_table_span(text)
    assert span is not None, "docs/cli.md lacks the bad-input table markers"
    assert text[span[0]:span[1]] == cat.render_table(cat.table_rows(tmp_path))


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
