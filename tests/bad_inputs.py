"""The catalogue of bad inputs every ``tvcid`` command is fed.

One place defines what a user can get wrong and what tvcid must answer: ``tests/test_bad_input_cli.py``
runs every entry through the real command line, and ``python tests/bad_inputs.py --readme`` renders
docs/cli.md's table "Bad input, and what tvcid says" from the answers the commands actually give (the
test fails when that table and the rendered one differ).

Two kinds of entries:

* :data:`RECORDING_CASES`: a recording broken in one way (written into a fresh directory from a good
  simulated one); every command that reads recordings (:data:`RECORDING_COMMANDS`) gets each.
* :data:`OPTION_CASES`: one command with a bad option or parameter.

Each entry states a regular expression the one-line error must match: it names the file, the
column and row, or the option or parameter at fault.
"""
from __future__ import annotations

import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

#: A good closed-loop record: M002 at controller A, 12 s at 1 kHz, measured-style sidecar.
GOOD_SECONDS = 12.0
GOOD_RATE = 1000.0


@dataclass(frozen=True)
class GoodRecords:
    closed_columns: dict
    closed_meta: dict
    open_columns: dict
    open_meta: dict


def good_records() -> GoodRecords:
    """The unbroken records every case starts from (simulated once, sidecars without provenance)."""
    from tvcid.models import CONTROLLER_A, OpenLoop, hypothesis, simulate

    params = hypothesis("M002", noise_power=1e-12)
    cl = simulate(params, CONTROLLER_A, GOOD_SECONDS, rate=GOOD_RATE)
    op = simulate(params, OpenLoop.square(0.02, 1.0), 4.0, rate=GOOD_RATE)
    closed = {"t": cl.t, "u": cl.u, "delta": cl.delta}
    opened = {"t": op.t, "u": op.u, "delta": op.delta}
    closed_meta = {"kind": "closed", "kp": CONTROLLER_A.kp, "kd": CONTROLLER_A.kd, "mu": CONTROLLER_A.mu}
    return GoodRecords(closed, closed_meta, opened, {"kind": "open"})


def write_csv(path: Path, columns: dict, meta: dict | None = None) -> Path:
    """Write ``columns`` as CSV (no validation: broken records are the point) and the sidecar."""
    names = list(columns)
    n = len(columns[names[0]])
    lines = [",".join(names)]
    for i in range(n):
        lines.append(",".join(repr(float(columns[k][i])) if isinstance(columns[k][i], (float, np.floating))
                              else str(columns[k][i]) for k in names))
    path.write_text("\n".join(lines) + "\n")
    if meta is not None:
        path.with_suffix(".json").write_text(json.dumps(meta))
    return path


def _copy(cols):
    return {k: np.array(v, dtype=object if v.dtype == object else float) for k, v in cols.items()}


@dataclass(frozen=True)
class RecordingCase:
    """A recording broken in one way.

    Attributes
    ----------
    key : str
    title : str
        The bad input, as docs/cli.md's table names it.
    make : callable
        ``make(good, directory) -> Path`` writes the broken record and returns its CSV path.
    expect : str
        Regular expression the error line must match (after the file's path is shortened to its
        name). Commands may specialise it through ``expect_by_command``.
    expect_by_command : dict
        Command -> regular expression, where the command's answer differs (a record too short for
        one method may suit another).
    """

    key: str
    title: str
    make: Callable
    expect: str
    expect_by_command: tuple = ()

    def expected(self, command: str) -> str:
        return dict(self.expect_by_command).get(command, self.expect)


def _closed(mutate, *, meta=None, name="bad.csv"):
    """A case maker: mutate a copy of the good closed-loop columns (and optionally the sidecar)."""

    def make(good, directory):
        cols = _copy(good.closed_columns)
        cols = mutate(cols) or cols
        side = dict(good.closed_meta) if meta is None else meta(dict(good.closed_meta))
        return write_csv(Path(directory) / name, cols, side)

    return make


def _raw(text_bytes: bytes, meta=None, name="bad.csv"):
    def make(good, directory):
        path = Path(directory) / name
        path.write_bytes(text_bytes if not callable(text_bytes) else text_bytes(good))
        path.with_suffix(".json").write_text(json.dumps(good.closed_meta if meta is None else meta))
        return path

    return make


def _set(col, row, value):
    def mutate(cols):
        cols[col] = cols[col].astype(object)
        cols[col][row] = value
        return cols

    return mutate


def _gap(cols):
    t = cols["t"]
    keep = (t < 3.0) | (t >= 3.5)
    return {k: v[keep] for k, v in cols.items()}


def _mixed_rate(cols):
    t = cols["t"]
    keep = (t < 6.0) | (np.arange(t.size) % 2 == 0)
    return {k: v[keep] for k, v in cols.items()}


def _duplicate_time(cols):
    cols["t"][1000] = cols["t"][999]
    return cols


def _decreasing_time(cols):
    cols["t"] = cols["t"][::-1].copy()
    return cols


def _constant(cols):
    cols["delta"] = np.full_like(cols["delta"], 1e-3)
    cols["u"] = np.zeros_like(cols["u"])
    return cols


def _first_seconds(seconds):
    def mutate(cols):
        keep = cols["t"] <= cols["t"][0] + seconds
        return {k: v[keep] for k, v in cols.items()}

    return mutate


def _drop(col):
    def mutate(cols):
        cols.pop(col)
        return cols

    return mutate


def _degrees(good, directory):
    cols = _copy(good.open_columns)
    cols["u"] = np.degrees(cols["u"])
    cols["delta"] = np.degrees(cols["delta"])
    return write_csv(Path(directory) / "bad.csv", cols, good.open_meta)


def _latin1(good):
    text = "t,u,delta,temp \u00b0C\n" + "".join(
        f"{t!r},{u!r},{d!r},20.0\n" for t, u, d in zip(*(good.closed_columns[k] for k in ("t", "u", "delta"))))
    return text.encode("latin-1")


def _utf16(good):
    text = "t,u,delta\n" + "".join(
        f"{t!r},{u!r},{d!r}\n" for t, u, d in zip(*(good.closed_columns[k] for k in ("t", "u", "delta"))))
    return text.encode("utf-16")


_PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)) * 4


def _huge(good, directory):
    from tvcid.models.recording import MAX_RECORDING_BYTES

    path = Path(directory) / "bad.csv"
    with open(path, "wb") as fh:  # sparse: the size is what the reader must refuse on
        fh.write(b"t,u,delta\n0.0,0.0,0.0\n")
        fh.truncate(MAX_RECORDING_BYTES + 1)
    path.with_suffix(".json").write_text(json.dumps(good.closed_meta))
    return path


def _missing_sidecar(good, directory):
    path = write_csv(Path(directory) / "bad.csv", _copy(good.closed_columns), None)
    return path


def _meta(update=None, drop=()):
    def meta(m):
        for k in drop:
            m.pop(k)
        m.update(update or {})
        return m

    return meta


def _bad_json(good, directory):
    path = write_csv(Path(directory) / "bad.csv", _copy(good.closed_columns), None)
    path.with_suffix(".json").write_text('{"kind": "closed", "kp": 5.84,}')
    return path


RECORDING_CASES = (
    RecordingCase("nan", "NaN in a column", _closed(_set("delta", 100, math.nan)),
                  r"bad\.csv: column 'delta' holds NaN or infinite values .*first at data row 101"),
    RecordingCase("inf", "infinite value", _closed(_set("u", 5, math.inf)),
                  r"bad\.csv: column 'u' holds NaN or infinite values .*first at data row 6"),
    RecordingCase("empty", "empty file", _raw(b""), r"bad\.csv: file is empty"),
    RecordingCase("header_only", "header only", _raw(b"t,u,delta\n"),
                  r"bad\.csv: recording is empty or has a single sample \(0 rows\)"),
    RecordingCase("single_row", "a single row", _raw(b"t,u,delta\n0.0,0.0,0.001\n"),
                  r"bad\.csv: recording is empty or has a single sample \(1 rows\)"),
    RecordingCase("duplicate_time", "duplicate time", _closed(_duplicate_time),
                  r"bad\.csv: column 't' is not strictly increasing \(data row 1001\)"),
    RecordingCase("decreasing_time", "decreasing time", _closed(_decreasing_time),
                  r"bad\.csv: column 't' is not strictly increasing \(data row 2\)"),
    RecordingCase("gap", "a 0.5 s gap in time", _closed(_gap),
                  r"bad\.csv: column 't' is not uniformly sampled: step 0\.501 s between data rows "
                  r"3000 and 3001"),
    RecordingCase("mixed_rate", "sample rate changing mid-record", _closed(_mixed_rate),
                  r"bad\.csv: column 't' is not uniformly sampled: step 0\.002 s"),
    RecordingCase("text", "text in a numeric column", _closed(_set("delta", 41, "n/a")),
                  r"bad\.csv: data row 42, column 'delta': not a number \('n/a'\)"),
    RecordingCase("missing_column", "a required column missing", _closed(_drop("u")),
                  r"bad\.csv: missing column 'u' \(columns: t, delta\)"),
    RecordingCase("not_csv", "a file that is not CSV (PNG bytes)", _raw(_PNG),
                  r"bad\.csv: not a text CSV file \(it holds NUL bytes"),
    RecordingCase("latin1", "wrong encoding (Latin-1)", _raw(_latin1),
                  r"bad\.csv: not UTF-8 text \(byte 0xb0 on line 1\)"),
    RecordingCase("utf16", "wrong encoding (UTF-16)", _raw(_utf16),
                  r"bad\.csv: not a text CSV file \(it holds NUL bytes: binary, or UTF-16"),
    RecordingCase("degrees", "angles in degrees", _degrees,
                  r"bad\.csv: column 'u' reaches .* at data row \d+, above 0\.5 rad: degrees\?"),
    RecordingCase("huge", "a file beyond 256 MiB", _huge,
                  r"bad\.csv: file holds 268,435,457 bytes, more than the 268,435,456 \(256 MiB\) tvcid reads at once"),
    RecordingCase("missing_sidecar", "no sidecar", _missing_sidecar,
                  r"bad\.csv: missing sidecar bad\.json"),
    RecordingCase("sidecar_json", "sidecar not valid JSON", _bad_json, r"bad\.json: invalid JSON"),
    RecordingCase("sidecar_missing_key", "sidecar key missing (closed loop without kp)",
                  _closed(lambda c: c, meta=_meta(drop=("kp",))),
                  r"bad\.json: closed-loop sidecar needs a finite number 'kp' \(got None\)"),
    RecordingCase("sidecar_unknown_key", "sidecar key misspelt",
                  _closed(lambda c: c, meta=_meta({"controler_rate": 200})),
                  r"bad\.json: unknown sidecar key 'controler_rate' \(did you mean 'controller_rate'\?\)"),
    RecordingCase("sidecar_compensator", "sidecar compensator improper (numerator degree above the denominator's)",
                  _closed(lambda c: c, meta=_meta({"compensator": {"num": [1, 0, 0], "den": [1, 1]}})),
                  r"bad\.json: sidecar 'compensator': controller transfer function is improper"),
    RecordingCase("sidecar_kind", "sidecar of an unknown kind",
                  _closed(lambda c: c, meta=_meta({"kind": "closed-loop"})),
                  r"bad\.json: sidecar 'kind' must be one of closed, open \(got 'closed-loop'\)"),
    RecordingCase("sidecar_rate", "sidecar sample rate contradicting the time column",
                  _closed(lambda c: c, meta=_meta({"sample_rate": 200})),
                  r"bad\.csv: sidecar 'sample_rate' 200 Hz disagrees with column 't' \(1000 Hz"),
    RecordingCase("constant", "constant signals (no motion)", _closed(_constant),
                  r"bad\.csv: .*(constant|never moves|no limit cycle)"),
    RecordingCase("one_period", "a single period of the cycle", _closed(_first_seconds(0.9)),
                  r"bad\.csv: .*\b1 whole period.*at least two"),
    RecordingCase("too_short", "a record too short for the method (40 samples)",
                  _closed(_first_seconds(0.039)),
                  r"bad\.csv: .*\b0 (whole period|test-function supports).*at least"),
)

#: Commands that read recordings: argv with ``{file}`` and ``{out}`` placeholders.
RECORDING_COMMANDS = {
    "features": ["features", "{file}"],
    "spectrum": ["spectrum", "{file}"],
    "sindy": ["sindy", "--no-rank", "{file}"],
    "fit": ["fit", "{file}", "--hypothesis", "M002", "--params", "dead_zone,backlash", "--max-steps",
            "2", "--walkers", "8", "--no-progress", "--out", "{out}"],
    "discover": ["discover", "{file}", "--quick", "--no-mcmc", "--no-progress", "--out", "{out}"],
}


@dataclass(frozen=True)
class OptionCase:
    """One command given a bad option or parameter (``{file}``: a good closed-loop record;
    ``{dir}``: its directory, which holds no chain; ``{out}``: a fresh path)."""

    key: str
    title: str
    argv: tuple
    expect: str


OPTION_CASES = (
    OptionCase("unknown_option", "an unknown option", ("features", "{file}", "--windw", "3"),
               r"tvcid: error: unrecognized arguments: --windw 3"),
    OptionCase("unknown_command", "an unknown command", ("fitt",),
               r"tvcid: error: argument COMMAND: invalid choice: 'fitt'"),
    OptionCase("unknown_hypothesis", "an unknown hypothesis",
               ("simulate", "M003", "--out", "{out}/x.csv"),
               r"unknown hypothesis 'M003'.*M002, M001i, M001f, M000"),
    OptionCase("unknown_parameter", "an unknown parameter name",
               ("simulate", "M002", "--set", "dead_zonee=1e-3", "--out", "{out}/x.csv"),
               r"unknown parameter.*dead_zonee"),
    OptionCase("negative_dead_zone", "a negative dead zone",
               ("simulate", "M002", "--set", "dead_zone=-1e-3", "--out", "{out}/x.csv"),
               r"dead_zone must be >= 0"),
    OptionCase("nan_parameter", "a NaN parameter",
               ("simulate", "M002", "--set", "backlash=nan", "--out", "{out}/x.csv"),
               r"backlash is NaN"),
    OptionCase("diverging_loop", "parameters that make the loop diverge",
               ("simulate", "M002", "--kp", "500", "--out", "{out}/x.csv"),
               r"M002 diverged: .* \(the loop is unstable with these parameters"),
    OptionCase("improper_controller", "an improper controller transfer function",
               ("simulate", "M002", "--controller-tf", "1,0,0/1,1", "--out", "{out}/x.csv"),
               r"--controller-tf 1,0,0/1,1: controller transfer function is improper"),
    OptionCase("bending_frequency", "a bending mode at 0 rad/s",
               ("simulate", "M002", "--bending=0,0.02,0.001", "--out", "{out}/x.csv"),
               r"--bending 0,0\.02,0\.001: bending frequency must be > 0"),
    OptionCase("nonpositive_dt", "a step of 0 s", ("simulate", "M002", "--dt", "0", "--out", "{out}/x.csv"),
               r"dt must be a finite number > 0"),
    OptionCase("negative_window", "a negative window", ("features", "{file}", "--window", "-2"),
               r"argument --window: must be > 0 s \(got -2\)"),
    OptionCase("reversed_band", "a noise band with low > high", ("spectrum", "{file}", "--band", "80", "20"),
               r"good\.csv: band 80-20 Hz must satisfy 0 <= low < high"),
    OptionCase("df_unknown_parameter", "df: an unknown parameter",
               ("df", "predict", "M002", "--set", "backlsh=1e-4"), r"unknown parameter.*backlsh"),
    OptionCase("df_negative_amplitude", "df family: a negative amplitude",
               ("df", "family", "--amplitude=-4.89e-3", "--frequency", "8.57"), r"amplitude must be a finite number > 0 \(got -0.00489\)"),
    OptionCase("fit_unknown_param", "fit: a parameter the hypothesis lacks",
               ("fit", "{file}", "--hypothesis", "M002", "--params", "dead_zone,frictin", "--out", "{out}/fit"),
               r"frictin"),
    OptionCase("fit_bad_prior", "fit: a malformed prior",
               ("fit", "{file}", "--hypothesis", "M002", "--params", "dead_zone", "--prior", "dead_zone=1:",
                "--out", "{out}/fit"), r"prior.*dead_zone=1:"),
    OptionCase("fit_prior_excludes_start", "fit: a prior that excludes the start",
               ("fit", "{file}", "--hypothesis", "M002", "--params", "dead_zone", "--prior",
                "dead_zone=0.1:0.2", "--out", "{out}/fit"), r"dead_zone"),
    OptionCase("fit_walkers", "fit: too few walkers",
               ("fit", "{file}", "--hypothesis", "M002", "--params", "dead_zone,backlash", "--walkers", "2",
                "--out", "{out}/fit"), r"walkers"),
    OptionCase("discover_unknown_fix", "discover: an unknown fixed parameter",
               ("discover", "{file}", "--fix", "gian=3e5", "--out", "{out}/disc"), r"gian"),
    OptionCase("discover_bad_choice", "discover: an unknown structural choice",
               ("discover", "{file}", "--fix", "delay_position=somewhere", "--out", "{out}/disc"),
               r"delay_position.*somewhere"),
    OptionCase("study_unknown", "study: an unknown study", ("study", "h9_nothing"),
               r"h9_nothing"),
    OptionCase("sindy_bootstrap", "sindy: a negative bootstrap count",
               ("sindy", "{file}", "--bootstrap", "-3"), r"bootstrap must be >= 0 \(got -3\)"),
    OptionCase("predict_no_chain", "predict: a directory without a posterior chain",
               ("predict", "{dir}", "--kp", "7"), r"holds no chain \(chain\.h5 from tvcid fit"),
    OptionCase("predict_grid_one_point", "predict: a grid with one point",
               ("predict", "{dir}", "--grid", "kp=3:9:1", "--out", "{out}"),
               r"--grid 'kp=3:9:1': a grid needs at least 2 points"),
    OptionCase("predict_improper", "predict: an improper controller transfer function",
               ("predict", "{dir}", "--controller-tf", "1,0,0/1,1"),
               r"--controller-tf 1,0,0/1,1: controller transfer function is improper"),
    OptionCase("design_candidates", "design: a candidates file that is not JSON",
               ("design", "{dir}", "--candidates", "{file}", "--out", "{out}"),
               r"good\.csv: not valid JSON"),
)


def shorten(line: str, directory) -> str:
    """The error line with the temporary directory removed (paths reduced to their names)."""
    return line.replace(str(directory) + "/", "").replace(str(directory), "")


def run_cli(argv):
    """Run ``tvcid argv`` in this process; return ``(status, stderr)``."""
    import contextlib
    import io

    from tvcid.cli import main

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            status = main(list(argv))
        except SystemExit as exc:  # argparse
            status = exc.code
    return status, err.getvalue()


def answer(case, command, good, directory):
    """Run one recording case through one command: ``(status, shortened stderr)``."""
    directory = Path(directory)
    path = case.make(good, directory)
    argv = [a.format(file=path, out=directory / "out") for a in RECORDING_COMMANDS[command]]
    status, err = run_cli(argv)
    return status, shorten(err, directory)


def option_answer(case, good, directory):
    directory = Path(directory)
    path = write_csv(directory / "good.csv", _copy(good.closed_columns), good.closed_meta)
    argv = [a.format(file=path, out=directory / "out", dir=directory) for a in case.argv]
    status, err = run_cli(argv)
    return status, shorten(err, directory)


README_BEGIN = "<!-- bad-input table: generated by `python tests/bad_inputs.py --readme`; do not edit -->"
README_END = "<!-- end of bad-input table -->"


def render_table(rows) -> str:
    """Markdown table from ``[(bad input, command, status, message)]``."""
    lines = [README_BEGIN, "", "| bad input | command | exit | what tvcid says |", "|---|---|---|---|"]
    for title, command, status, message in rows:
        message = message.strip().replace("|", "\\|")
        lines.append(f"| {title} | `{command}` | {status} | {message} |")
    lines += ["", README_END]
    return "\n".join(lines)


#: The command whose answer docs/cli.md shows for each recording case.
TABLE_COMMAND = {"constant": "features", "one_period": "features", "too_short": "features"}


def table_rows(directory) -> list:
    import tempfile

    good = good_records()
    rows = []
    for case in RECORDING_CASES:
        command = TABLE_COMMAND.get(case.key, "features")
        with tempfile.TemporaryDirectory(dir=directory) as d:
            status, err = answer(case, command, good, d)
        rows.append((case.title, f"tvcid {command}", status, err))
    for case in OPTION_CASES:
        with tempfile.TemporaryDirectory(dir=directory) as d:
            status, err = option_answer(case, good, d)
        rows.append((case.title, "tvcid " + case.argv[0], status, err))
    return rows


def readme_table_span(text: str):
    begin, end = text.find(README_BEGIN), text.find(README_END)
    if begin < 0 or end < 0:
        return None
    return begin, end + len(README_END)


def main(argv=None) -> int:
    import argparse
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--readme", action="store_true", help="rewrite README.md's table in place")
    parser.add_argument("--probe", action="store_true", help="print every command's answer to every case")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        if args.probe:
            good = good_records()
            for case in RECORDING_CASES:
                for command in RECORDING_COMMANDS:
                    with tempfile.TemporaryDirectory(dir=tmp) as d:
                        status, err = answer(case, command, good, d)
                    ok = status == 2 and len(err.strip().splitlines()) == 1 and re.search(case.expected(command), err)
                    print(f"{'OK ' if ok else 'BAD'} {case.key:20s} {command:9s} {status} {err.strip()[:300]}")
            for case in OPTION_CASES:
                with tempfile.TemporaryDirectory(dir=tmp) as d:
                    status, err = option_answer(case, good, d)
                ok = status == 2 and len(err.strip().splitlines()) == 1 and re.search(case.expect, err)
                print(f"{'OK ' if ok else 'BAD'} {case.key:20s} {status} {err.strip()[:300]}")
            return 0
        table = render_table(table_rows(tmp))
    readme = Path(__file__).resolve().parents[1] / "docs" / "cli.md"
    if args.readme:
        text = readme.read_text()
        span = readme_table_span(text)
        if span is None:
            print(f"{readme}: no table markers; add {README_BEGIN!r} and {README_END!r}", file=sys.stderr)
            return 1
        readme.write_text(text[: span[0]] + table + text[span[1]:])
        print(f"rewrote the table in {readme}")
    else:
        print(table)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
