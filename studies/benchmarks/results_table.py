"""``docs/results.md``: the claims the benchmark records hold, rendered from the records.

``python -m tvcid.studies.benchmarks.results_table [--check] [--records DIR] [--out FILE]``

Reads the stored benchmark rows (``studies/benchmarks/records/*.json``, :data:`CLAIMS`) and
writes one table, a row per claim: the claim; its current value, computed from the record's rows
by the benchmark's own functions (:mod:`.claim_values`), with the benchmark's goal met or NOT met
where it has one; the command that produces the record; the test that checks that computation
(it must exist in ``tests/``: :func:`find_test`); and the commits the rows were made at, "rows at
N commits" where they come from several. ``--check`` writes nothing and exits 1 when the file
differs from the rendering (so a quoted number cannot drift from its record). A record must be
strict JSON (no ``NaN`` or ``Infinity`` tokens: the benchmarks write ``null``,
:func:`tvcid.models.strict_json.write_json`).
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .claim_values import (
    coverage_chains,
    coverage_features,
    coverage_waveform,
    coverage_widening,
    cycles_posterior,
    discover_speed,
    discovery_ceiling,
    discovery_fresh,
    discovery_quick,
    discovery_race,
    discovery_short,
    evaluation_cost,
    loop,
    next_test,
    set_coverage,
    widening_rows,
)

ROOT = Path(__file__).resolve().parents[2]
RECORDS = ROOT / "studies" / "benchmarks" / "records"
OUT = ROOT / "docs" / "results.md"


def _refuse_constant(token):
    raise ValueError(f"{token} is not JSON (write null)")


def load_records(directory=RECORDS) -> dict:
    """Every ``*.json`` of ``directory`` by its stem, parsed strictly (no NaN or Infinity)."""
    out = {}
    for path in sorted(Path(directory).glob("*.json")):
        try:
            out[path.stem] = json.loads(path.read_text(), parse_constant=_refuse_constant)
        except ValueError as err:
            raise ValueError(f"{path.name}: {err}") from None
    return out


def find_test(node_id, root=ROOT):
    """The definition of ``tests/FILE.py::test_name`` at the top level of that file (parsed, not
    imported), or ``None``."""
    file, _, name = node_id.partition("::")
    path = Path(root) / file
    if not name.startswith("test") or not path.is_file():
        return None
    tree = ast.parse(path.read_text(), filename=str(path))
    return next((n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
                 and n.name == name), None)


def is_slow(definition) -> bool:
    """Whether a test's definition is marked ``slow`` (left out of the default suite)."""
    return any(ast.unparse(d).endswith("mark.slow") for d in definition.decorator_list)


def commits_text(rows) -> str:
    """The rows' commits: one, or "rows at N commits" and how many rows each."""
    counts = Counter(r.get("commit") or "" for r in rows)

    def name(c):
        return f"`{c}`" if c else "no commit recorded"

    if len(counts) == 1:
        return name(next(iter(counts)))
    parts = ", ".join(f"{name(c)} ({n})" for c, n in sorted(counts.items(),
                                                             key=lambda x: (-x[1], x[0])))
    return f"**rows at {len(counts)} commits**: {parts}"


def ranges_text(rows) -> str:
    """The generator's ranges of the rows' draws (:func:`.draws.row_ranges`), for rows that are
    draws; empty otherwise."""
    from .draws import row_ranges

    counts = Counter(row_ranges(r) for r in rows if "design" in r or "ranges" in r)
    if not counts:
        return ""
    return "; draws within the generator's " + ", ".join(
        f"`{name}` ranges" + (f" ({n})" if len(counts) > 1 else "") for name, n in sorted(counts.items()))


@dataclass(frozen=True)
class Claim:
    """One row of the table.

    Attributes
    ----------
    claim : str
        What is claimed.
    value : callable
        Records (stem -> parsed JSON) -> the current value, as text.
    rows : callable
        Records -> the rows the value comes from (their ``commit`` shown).
    command : str
        The command that produces the record.
    record : str
        The record's stem in ``studies/benchmarks/records``.
    test : str
        ``tests/FILE.py::test_name`` of the test that checks the value's computation.
    """

    claim: str
    value: Callable
    rows: Callable
    command: str
    record: str
    test: str


CLAIMS = (
    Claim("calibration coverage, features likelihood (true structure given, seeded draws): the "
          "truth inside its 90 % interval, per parameter (goal 80-97 %)",
          coverage_features, lambda r: r["bench_coverage"]["rows"],
          "python -m tvcid.studies.benchmarks.coverage --jobs 2", "bench_coverage",
          "tests/test_bench_coverage.py::"
          "test_stored_record_covers_the_truth_80_to_97_percent_per_parameter"),
    Claim("calibration coverage draws: chains converged, discrepancy factor",
          coverage_chains, lambda r: r["bench_coverage"]["rows"],
          "python -m tvcid.studies.benchmarks.coverage --jobs 2", "bench_coverage",
          "tests/test_bench_coverage.py::"
          "test_summary_counts_coverage_ranks_and_inflation_of_known_rows"),
    Claim("calibration coverage, waveform likelihood (`tvcid fit`'s default): the truth inside "
          "its 90 % interval, per parameter (goal 80-97 %)",
          coverage_waveform, lambda r: r["bench_coverage_waveform"]["rows"],
          "python -m tvcid.studies.benchmarks.coverage --likelihood waveform --jobs 2",
          "bench_coverage_waveform",
          "tests/test_bench_coverage.py::"
          "test_quick_run_with_the_waveform_likelihood_enters_each_record_its_own_way"),
    Claim("the discrepancy term widens right models' 90 % intervals by at most 20 % (rows with "
          "the term from `bench_coverage.json`)",
          coverage_widening, lambda r: widening_rows(r)[1],
          "python -m tvcid.studies.benchmarks.coverage --widening --jobs 2",
          "bench_coverage_widening",
          "tests/test_bench_coverage.py::"
          "test_widening_compares_interval_widths_with_and_without_the_discrepancy_term"),
    Claim("discovery on random truths and designs (quick searches, seeds 1000-1029)",
          discovery_quick, lambda r: r["bench_discovery_quick"]["rows"],
          "python -m tvcid.studies.benchmarks.discovery --quick --draws 30 --ranges papers --jobs 2",
          "bench_discovery_quick",
          "tests/test_bench_discovery.py::"
          "test_a_draw_with_its_positions_fixed_decides_the_loop_and_keeps_the_truth"),
    Claim("discovery's fit ceiling: draws where at most 3 minimal structures fit the recordings "
          "as well as the truth itself (what a fit-based set rule can reach)",
          discovery_ceiling, lambda r: r["bench_discovery_quick"]["rows"],
          "python -m tvcid.studies.benchmarks.discovery --quick --draws 30 --ranges papers --jobs 2",
          "bench_discovery_quick",
          "tests/test_bench_discovery.py::test_structures_fitting_as_well_as_the_truth_bound_the_set"),
    Claim("discovery on fresh draws the set rule is not weighed on",
          discovery_fresh, lambda r: r["bench_discovery_fresh"]["rows"],
          "python -m tvcid.studies.benchmarks.discovery --quick --seed 1030 --draws 10 --ranges papers "
          "--jobs 2",
          "bench_discovery_fresh",
          "tests/test_bench_discovery.py::"
          "test_a_draw_with_its_positions_fixed_decides_the_loop_and_keeps_the_truth"),
    Claim("the set rule on short recordings (5-15 s each, 200 Hz to 2 kHz): the truth's "
          "structure in the reported set, and the set's median size",
          discovery_short, lambda r: r["bench_discovery_short"]["rows"],
          "python -m tvcid.studies.benchmarks.discovery --quick --ranges short --seed 4000 --draws 40 "
          "--jobs 2, then --rederive",
          "bench_discovery_short",
          "tests/test_discover.py::"
          "test_recordings_that_do_not_discriminate_widen_the_margin_in_quadrature"),
    Claim("the structure search's race (`StructureDiscovery(race=...)`): on drawn truths and "
          "designs with open-loop tests, the classes it drops and whether any holds the truth's "
          "structure or a member of the reported set",
          discovery_race, lambda r: [x for x in r["bench_discovery_race"]["rows"] if x.get("race")],
          "python -m tvcid.studies.benchmarks.discovery --race measure --seed 6015 --draws 10 "
          "--jobs 2",
          "bench_discovery_race",
          "tests/test_race.py::test_the_stored_race_measurement_is_its_rows_summary"),
    Claim("one point of a member's posterior (features likelihood, 10 s windows, the truth's "
          "structure, seeded draws over the generator's ranges): its kernel steps by record "
          "and part, and how far a simulated cycle's features move with the stretch they are "
          "read from",
          evaluation_cost, lambda r: r["bench_evaluation_cost"]["rows"],
          "python -m tvcid.studies.benchmarks.evaluation_cost --draws 12 --points 12",
          "bench_evaluation_cost",
          "tests/test_work_counts.py::test_stored_evaluation_cost_record_is_its_rows_summary"),
    Claim("the next test `tvcid discover` names, recorded from the truth, on the discovery "
          "benchmark's misses: the set after the discovery runs again",
          next_test, lambda r: r["bench_next_test"]["rows"],
          "python -m tvcid.studies.benchmarks.next_test --seeds 1004,1009,1016", "bench_next_test",
          "tests/test_discrimination.py::test_discover_names_the_test_that_would_decide_its_set"),
    Claim("coverage of what `tvcid discover` prints (the combined 90 % interval where pinned, "
          "the range the recordings allow where not, present or absent), structure and linear "
          "block unknown, truths and designs drawn over the generator's ranges (goal 80-97 % for "
          "every printed quantity over >= 30 draws, the truths' median distance from their "
          "interval's median 0.3-0.5 half-widths, no printed interval narrower than twice its "
          "step error, no structural choice printed wrongly)",
          set_coverage, lambda r: r["bench_set_coverage"]["rows"],
          "python -m tvcid.studies.benchmarks.set_coverage --seed 3000 --draws 30",
          "bench_set_coverage",
          "tests/test_bench_set_coverage.py::test_the_claim_counts_the_stored_draws_and_judges_none"
          "_under_thirty"),
    Claim("the experiment loop: after `tvcid discover`, the test the run suggests (at most two "
          "in turn) recorded from the truth by the reference path and added with `--add`, "
          "truths and designs drawn over the generator's ranges (goals over >= 10 draws: the "
          "truth in the set, its member counted, at every round in every draw; the set closed in "
          ">= 80 % of the draws whose menu can decide; an --add's kernel steps at most a third "
          "of a fresh run's on the same recordings in the median, never above it)",
          loop, lambda r: r["bench_loop"]["rows"],
          "python -m tvcid.studies.benchmarks.loop --seed 3000 --draws 10",
          "bench_loop",
          "tests/test_bench_loop.py::test_the_loops_claim_states_each_goal_round_and_cost_ratio"),
    Claim("a member's posterior on limit cycles alone (the truth's structure on drawn designs "
          "without open-loop tests, data from the reference path read back as measured), the "
          "default calibration and nested sampling against a reference chain five times the "
          "cap (goal: every 90 % interval end within 0.2 of the reference's width in <= 600 CPU "
          "s, no miss the method's own diagnostic passes)",
          cycles_posterior, lambda r: r["bench_cycles_posterior"]["rows"],
          "python -m tvcid.studies.benchmarks.cycles_posterior --draws 10",
          "bench_cycles_posterior",
          "tests/test_bench_cycles_posterior.py::test_the_claim_names_each_methods_cost_and_move"),
    Claim("`tvcid discover` on four M000 recordings (two 40 s limit cycles, two 10 s open-loop "
          "tests), the set's calibration included (goal 600 s on 2 cores)",
          discover_speed, lambda r: [r["bench_discover_speed"]],
          "python -m tvcid.studies.benchmarks.discover_speed", "bench_discover_speed",
          "tests/test_results_table.py::test_speed_claim_judges_the_stored_run_in_reference_seconds"),
)

HEADER = """# Results

<!-- Written by `python -m tvcid.studies.benchmarks.results_table` from studies/benchmarks/records/*.json: do not edit. -->

Each value is computed from a benchmark's stored rows (`studies/benchmarks/records/`, described in its
`README.md`) by the benchmark's own functions, with the benchmark's goal met or NOT met where it
has one; the rows' commits, and the generator's ranges of the draws
(`studies/benchmarks/scenarios.py`), are in the last column. `python -m tvcid.studies.benchmarks.results_table --check`
exits 1 when this file differs from that rendering (`tests/test_results_table.py`).

| claim | current value | the command that produces it | the test that checks it | record commit(s), ranges |
|---|---|---|---|---|
"""


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def render(records=None, claims=CLAIMS, root=ROOT) -> str:
    """The markdown of ``claims`` on ``records`` (default: :func:`load_records`); a claim whose
    test does not exist is refused (``ValueError``)."""
    records = load_records() if records is None else records
    lines = []
    for c in claims:
        definition = find_test(c.test, root)
        if definition is None:
            raise ValueError(f"claim {c.claim!r}: no test {c.test}")
        command = f"`{c.command}` (`studies/benchmarks/records/{c.record}.json`)"
        test = f"`{c.test}`" + (" (slow: `pytest -m slow`)" if is_slow(definition) else "")
        lines.append("| " + " | ".join(_cell(x) for x in (
            c.claim, c.value(records), command, test,
            commits_text(c.rows(records)) + ranges_text(c.rows(records)))) + " |")
    return HEADER + "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 if the file differs from the rendering")
    parser.add_argument("--records", default=str(RECORDS), help="directory of the records")
    parser.add_argument("--out", default=str(OUT), help="the markdown file")
    args = parser.parse_args(argv)
    text = render(load_records(args.records))
    out = Path(args.out)
    if args.check:
        same = out.is_file() and out.read_text() == text
        print(f"{out}: " + ("up to date" if same else
                            "differs from the records' rendering: python -m tvcid.studies.benchmarks.results_table"))
        return 0 if same else 1
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
