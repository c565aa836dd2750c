"""The ``tvcid simulate`` and ``tvcid features`` commands."""
import json

import numpy as np
import pytest

from tvcid.cli import main
from tvcid.models.recording import save_recording


def test_simulate_then_features_json(tmp_path, capsys):
    out = tmp_path / "m002.csv"
    assert main(["simulate", "m002", "--t-end", "20", "--out", str(out)]) == 0
    assert out.exists() and out.with_suffix(".json").exists()
    capsys.readouterr()
    assert main(["features", str(out), "--window", "10", "--json"]) == 0
    feats = json.loads(capsys.readouterr().out)
    assert feats["amplitude"] == pytest.approx(5.0e-3, rel=0.03)
    assert feats["frequency"] == pytest.approx(8.57, rel=0.01)


def test_simulate_at_a_rate_the_default_step_does_not_divide(tmp_path):
    """``--rate 2000`` with a controller held at 200 Hz: simulated at a step both divide."""
    from tvcid.models.recording import load_recording

    out = tmp_path / "fast.csv"
    assert main(["simulate", "M002", "--rate", "2000", "--controller-rate", "200", "--t-end", "1",
                 "--out", str(out)]) == 0
    rec = load_recording(out)
    assert rec.sample_rate == pytest.approx(2000.0) and rec.t.size == 2001


def test_simulate_open_loop_with_overrides(tmp_path):
    out = tmp_path / "sq.csv"
    args = ["simulate", "M001f", "--open-loop", "square", "--amplitude", "0.01", "--frequency", "2",
            "--set", "delay_position=output", "--set", "bandpass_gain=0", "--t-end", "2", "--out", str(out)]
    assert main(args) == 0
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["kind"] == "open" and meta["waveform"] == "square"
    assert meta["parameters"]["delay_position"] == "output"
    assert meta["parameters"]["bandpass_gain"] == 0.0


def test_simulate_with_compensator_and_bending_writes_them_to_the_sidecar(tmp_path):
    from tvcid.models.controllers import BendingMode, TransferFunction
    from tvcid.models.recording import load_recording

    out = tmp_path / "comp.csv"
    args = ["simulate", "M002", "--lead", "4,8", "--notch", "60,0.5,0.1", "--controller-tf", "1/0.001,1",
            "--bending", "60,0.02,0.002", "--controller-rate", "200", "--t-end", "3", "--out", str(out)]
    assert main(args) == 0
    exp = load_recording(out).experiment()
    expected = TransferFunction.series(TransferFunction.lead(4, 8), TransferFunction.notch(60, 0.5, 0.1),
                                       TransferFunction((1.0,), (0.001, 1.0)))
    assert exp.compensator == expected and exp.sample_rate == 200.0
    assert exp.bending == BendingMode(60.0, 0.02, 0.002)


def test_controller_option_helpers_parse_into_a_closed_loop():
    import argparse

    from tvcid.commands._common import add_controller_options, closed_loop_from_args
    from tvcid.models.controllers import TransferFunction

    parser = argparse.ArgumentParser()
    add_controller_options(parser)
    plain = closed_loop_from_args(parser.parse_args([]))
    assert plain.is_plain_pd and plain.kp == 5.84 and plain.sample_rate is None
    one = closed_loop_from_args(parser.parse_args(["--kp", "1", "--kd", "0", "--controller-tf", "2,3/1,4"]))
    assert one.compensator == TransferFunction((2.0, 3.0), (1.0, 4.0)) and one.bending is None


@pytest.mark.parametrize(
    "args, message",
    [
        (["simulate", "M9", "--out", "x.csv"], "unknown hypothesis 'M9'"),
        (["simulate", "M002", "--set", "backlash=-1", "--out", "x.csv"], "backlash must be >= 0"),
        (["simulate", "M002", "--dt", "0", "--out", "x.csv"], "dt must be"),
        # a loop that diverges: one line, not a SimulationDiverged traceback
        (["simulate", "M002", "--kp", "500", "--kd", "0.062", "--mu", "12.3", "--out", "x.csv"],
         "the loop is unstable with these parameters"),
        # compensator and bending options: the option and the fault named
        (["simulate", "M002", "--controller-tf", "1,0,0/1,1", "--out", "x.csv"],
         "--controller-tf 1,0,0/1,1: controller transfer function is improper"),
        (["simulate", "M002", "--controller-tf", "1;2", "--out", "x.csv"], "--controller-tf takes NUM/DEN"),
        (["simulate", "M002", "--lead", "4", "--out", "x.csv"], "--lead takes 2 comma-separated numbers"),
        (["simulate", "M002", "--notch", "60,0.5,1", "--out", "x.csv"], "notch depth must be in [0, 1)"),
        (["simulate", "M002", "--bending=-60,0.02,0.001", "--out", "x.csv"],
         "--bending -60,0.02,0.001: bending frequency must be > 0"),
        (["simulate", "M002", "--open-loop", "step", "--lead", "4,8", "--out", "x.csv"],
         "act in the closed loop"),
        # SINDy on a record that never moves: named, not a ZeroDivisionError
        (["sindy", "const.csv"], "const.csv: column 'delta' is constant"),
    ],
)
def test_cli_errors_name_the_culprit(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    if "const.csv" in args:
        t = np.arange(2000) / 1000.0
        save_recording(tmp_path / "const.csv", {"t": t, "u": 0 * t, "delta": 0 * t}, {"kind": "open"})
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_every_command_has_help(capsys):
    from tvcid.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name in sub.choices:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        assert "usage" in capsys.readouterr().out


def _command_paths(parser, prefix=()):
    """Every command path of the parser tree (the top level included)."""
    import argparse

    yield prefix
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from _command_paths(child, prefix + (name,))


def test_help_of_every_command_prints_and_exits_0(capsys):
    """``tvcid --help`` and ``tvcid COMMAND [SUBCOMMAND] --help`` over the whole command tree:
    each prints its usage and exits 0 (a help string with a bare ``%`` would raise instead)."""
    from tvcid.cli import build_parser

    paths = list(_command_paths(build_parser()))
    assert len(paths) > 5
    for path in paths:
        with pytest.raises(SystemExit) as exit_:
            main([*path, "--help"])
        assert exit_.value.code == 0, path
        out = capsys.readouterr().out
        assert out.startswith("usage: tvcid" + "".join(f" {p}" for p in path)), (path, out[:80])


def test_docs_cli_md_is_the_rendering_of_the_parsers():
    """docs/cli.md's command reference is every command's ``--help`` as the parsers print it now
    (``python -m tvcid.cli_docs`` rewrites it; ``--check`` is this test)."""
    from tvcid import cli_docs

    text = cli_docs.DOC.read_text()
    begin, end = cli_docs._span(text)
    assert text[begin:end] == cli_docs.render()
    paths = [" ".join(("tvcid",) + p) for p, _ in cli_docs.command_paths(cli_docs.build_parser())]
    assert all(f"### `{p}`" in text for p in paths) and len(paths) > 10
