"""``docs/results.md``: the claims the benchmark records hold, rendered from the records.

``python -m tvcid.studies.benchmarks.results_table [--check] [--records DIR] [--out FILE]``

Reads the stored benchmark rows (``studies/benchmarks/records/*.json``, :data:`CLAIMS`) and writes one
table, a row per claim: the claim; its current value, computed from the record's rows by the
benchmark's own functions, with the benchmark's goal met or NOT met where it has one; the command
that produces the record; the test that checks that computation (it must exist in ``tests/``:
:func:`find_test`); and the commits the rows were made at, "rows at N commits" where they
come from several. ``--check`` writes nothing and exits 1 when the file differs from the
rendering (so a quoted number cannot drift from its record). A record must be strict JSON (no
``NaN`` or ``Infinity`` tokens: the benchmarks write ``null``, :func:`tvcid.models.strict_json.write_json`).
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


def _goals_text(goals) -> str:
    return "; ".join(f"goal {g.text()}" for g in goals)


def _pct(x) -> str:
    return f"{100 * x:.0f} %"


# -- the claims: each a value from the records and the rows whose commits it shows ------------

def _coverage_value(record):
    from .coverage import coverage_goals, summarise

    s = summarise(record["rows"])
    cells = [v for k, v in s.items() if not k.startswith("_")]
    inside = sum(round(c["coverage"] * c["draws"]) for c in cells)
    total = sum(c["draws"] for c in cells)
    n = record["config"]["draws"]
    return (f"{len(record['rows'])} of {n} draws have rows; "
            + _goals_text(coverage_goals(s))
            + f"; all parameters: {inside} of {total} = {_pct(inside / total)}")


def coverage_features(records):
    return _coverage_value(records["bench_coverage"])


def coverage_waveform(records):
    return (_coverage_value(records["bench_coverage_waveform"])
            + " (draws with the band-pass loop are not run: no periodic cycle)")


def coverage_chains(records):
    from .coverage import summarise

    rows = records["bench_coverage"]["rows"]
    s = summarise(rows)
    infl = s["_inflation"]
    at_1 = round(infl["fraction_at_1"] * infl["records"])
    cap = records["bench_coverage"]["config"]["max_steps"]
    return (f"{s['_all']['converged']} of {s['_all']['draws']} chains converged within the "
            f"{cap}-step cap; discrepancy factor 1 on {at_1} of {infl['records']} records "
            f"(largest {infl['max']:.3g})")


def _widening(records):
    from .coverage import widening

    plain = records["bench_coverage_widening"]["plain_rows"]
    result = widening(records["bench_coverage"]["rows"], plain)
    paired = {d["index"] for d in result["draws"]}
    with_term = [r for r in records["bench_coverage"]["rows"] if r["index"] in paired]
    return result, with_term + [r for r in plain if r["index"] in paired]


def coverage_widening(records):
    from .coverage import widening_goal

    result, _ = _widening(records)
    draws = ", ".join(str(d["index"]) for d in result["draws"])
    return (f"draws {draws}: " + _goals_text([widening_goal(result)])
            + f"; median x{result['median_ratio']:.3g}, largest x{result['max_ratio']:.3g}")


def _discovery_rates(rows):
    from .discovery import discovery_goals, summarise

    o = summarise(rows)["overall"]
    n = o["draws"]
    return o, n, (_goals_text(discovery_goals(o))
                  + f"; right winner {round(o['right_winner'] * n)} of {n}, truth in the reported "
                  f"set {sum(bool(r['truth_in_set']) for r in rows)} of {n}; structural choices "
                  f"decided right {_pct(o['choices_decided_right'])}, decided wrong "
                  f"{o['choices_decided_wrong']}")


def discovery_quick(records):
    return _discovery_rates(records["bench_discovery_quick"]["rows"])[2]


def discovery_ceiling(records):
    o, n, _ = _discovery_rates(records["bench_discovery_quick"]["rows"])
    return (f"{round(o['ceiling_set_le3'] * n)} of {n} = {_pct(o['ceiling_set_le3'])}; against "
            f"the truth's structure's own fit (an oracle): {round(o['oracle_set_le3'] * n)} of {n}"
            f" = {_pct(o['oracle_set_le3'])}")


def discovery_fresh(records):
    rows = records["bench_discovery_fresh"]["rows"]
    o, n, text = _discovery_rates(rows)
    seeds = sorted(r["seed"] for r in rows)
    return (f"{n} draws finished (seeds {seeds[0]}-{seeds[-1]}): " + text
            + f"; at most 3 structures fit as well as the truth in "
            f"{round(o['ceiling_set_le3'] * n)} of {n}")


def discovery_short(records):
    """The set rule on short recordings (the ``short`` ranges): the draws finished so far, their
    sets derived by the rule named in each row's ``set_rule_check``."""
    rows = records["bench_discovery_short"]["rows"]
    o, n, text = _discovery_rates(rows)
    seeds = sorted(r["seed"] for r in rows)
    derived = sum(bool(r.get("set_rule_check")) for r in rows)
    return (f"{n} draws finished (seeds {seeds[0]}-{seeds[-1]}), the sets of {derived} derived "
            "again by the set rule each row's `set_rule_check` names: " + text)


def discovery_race(records):
    """The race's drop rule measured (``--race measure``: every class searched, what the race
    would drop recorded): per draw with open-loop tests, the structures it would drop, those
    among the reported set or the truth's, and whether its bound held."""
    from .discovery import race_summary

    rows = [r for r in records["bench_discovery_race"]["rows"] if r.get("race")]
    t = race_summary(rows)
    seeds = sorted(r["seed"] for r in rows)
    return (f"{t['draws']} draws with open-loop tests finished (seeds {seeds[0]}-{seeds[-1]}): "
            f"the race would drop structures in {t['dropping']} of them ({t['dropped']} "
            f"structures in all); a dropped structure in the reported set or the truth's in "
            f"{t['wrong']} of {t['draws']}; a searched top's open-loop share under its bound by "
            f"at most {t['worst_shortfall']:.3g}; the screen over the best cost by at least "
            f"{t['least_margin']:.3g}")


def rows_spread(records) -> float:
    """The evaluation-cost rows' spread of their points about the truth (one value)."""
    spreads = {r["spread"] for r in records["bench_evaluation_cost"]["rows"]}
    if len(spreads) != 1:
        raise ValueError(f"evaluation-cost rows at several spreads: {sorted(spreads)}")
    return spreads.pop()


def evaluation_cost(records):
    """Where one point of a member's posterior spends its kernel steps, and how far a simulated
    cycle's features move with the stretch they are read from."""
    from .evaluation_cost import summarise

    t = summarise(records["bench_evaluation_cost"]["rows"])
    share = t["share_by_part"]
    nxt, few, settling = t["next_window_sd"], t["six_periods_sd"], t["next_window_sd_settling"]
    text = (f"{t['draws']} draws: a point's kernel steps go {_pct(share.get('cycle:settle', 0))} to "
            f"the limit cycles' settling before their windows, "
            f"{_pct(share.get('cycle:window', 0))} to their 10 s windows, "
            f"{_pct(share.get('open:record', 0) + share.get('open:refined', 0))} to open-loop "
            f"records, {_pct(share.get('open:refined', 0))} of all in the finer steps their edges "
            "and solver checks chose")
    if nxt:
        text += (f"; at points {100 * rows_spread(records):.2g} % from the truth, a run's features move from one 10 s window "
                 f"to the next by a median {nxt['median']:.2g} of the data's sd (largest "
                 f"{nxt['largest']:.2g}, {nxt['records']} cycle records)")
    if few:
        text += (f", and from the window to its first six periods by a median "
                 f"{few['median']:.2g} (largest {few['largest']:.2g})")
    if settling:
        text += (f"; records that settle over their length (runs started where the record "
                 f"starts): a median {settling['median']:.2g} ({settling['records']} records)")
    return text


def next_test(records):
    rows = records["bench_next_test"]["rows"]
    cells, hits, kept = [], 0, 0
    for r in rows:
        b, s, a = r["before"], r.get("suggestion"), r.get("after")
        if s is None:
            cells.append(f"{r['seed']}: a set of one, no test")
            continue
        hits += bool(a["right_or_in_small_set"])
        kept += bool(a["truth_in_set"])
        cells.append(
            f"{r['seed']}: {s['name']}, set {b['set_size']} -> {a['set_size']} "
            f"({'truth inside' if a['truth_in_set'] else 'truth outside'}"
            f"{', right winner' if a['right_winner'] else ''}), pairs predicted decided "
            f"{s['pairs_decided']} of {s['n_pairs']}, decided {a['pairs_decided']}, agreeing "
            f"{a['pairs_agreeing_with_prediction']}")
    tested = sum(r.get("suggestion") is not None for r in rows)
    return (f"right winner or in a set of at most 3 after the test: {hits} of {tested}; truth kept "
            f"in the set: {kept} of {tested}. " + "; ".join(cells))


def set_coverage(records):
    """The discover path's coverage: per printed quantity, the truths covered by what the report
    prints over the finished draws whose judgement of it can fail (:func:`.set_coverage.summarise`),
    its goals, the judgements that cannot fail and the misses beyond the prior counted apart, the
    median relative width of the intervals judged, the draws' sets and chains, and the rows'
    sampling and judging commits; rows of an earlier layout are counted, not judged."""
    from .set_coverage import MIN_DRAWS, coverage_goals, summarise

    rows = records["bench_set_coverage"]["rows"]
    table = summarise(rows)
    seeds = sorted(r["seed"] for r in rows)
    sizes = [len(r["members"]) for r in rows if "error" not in r]
    wording = {"converged": "draws whose every chain converged",
               "stopped at the cap": "draws with a chain stopped at its cap"}
    split = "; ".join(
        f"{wording[label]}: {part['draws']}"
        + ("" if not part["draws"] else " (" + ", ".join(
            f"{q} {c['covered']} of {c['draws']} covered"
            for q, c in part["quantities"].items() if c["draws"]) + ")")
        for label, part in table["by_chains"].items())
    only = table["cycles_only"]
    cf = table["cannot_fail"]
    split += (f"; judgements that cannot fail, apart from the goals: {sum(cf.values())} (a truth "
              f"of 0 against \"present or absent\" {cf['present_or_absent']}, a truth inside the "
              f"prior against a range open at both ends {cf['open_at_both_ends']}); misses whose "
              f"truth lies beyond the prior's bound an open end stands for: "
              + (", ".join(f"{q} of draw {seed}" for seed, q in table["beyond_prior"]) or "none"))
    allowed = {q: a for q, a in table["allowed"].items() if a["draws"]}
    if allowed:
        split += "; truth inside the range the recordings allow: " + ", ".join(
            f"{q} {a['inside']} of {a['draws']}" for q, a in allowed.items())
    widths = {q: c["median_relative_width"] for q, c in table["quantities"].items()
              if c["median_relative_width"] is not None}
    if widths:
        split += "; median relative width of the intervals judged: " + ", ".join(
            f"{q} {w:.2g}" for q, w in widths.items())
    p = table["position"]
    if p["intervals"]:
        split += (f"; truth's median distance from the median in half-widths of its interval "
                  f"{p['median_abs']:.2f} over {p['intervals']} intervals "
                  f"({p['gaussian_median_abs']:.2f} for calibrated Gaussian intervals)")
    cost = table["cost"]
    if cost["draws"]:
        split += (f"; cost of a draw run in one piece ({cost['draws']} draws), median [largest]: "
                  f"{cost['kernel_steps']['median']:.3g} [{cost['kernel_steps']['max']:.3g}] "
                  f"kernel steps, {cost['cpu_seconds']['median']:.0f} "
                  f"[{cost['cpu_seconds']['max']:.0f}] CPU s, {cost['wall_seconds']['median']:.0f} "
                  f"[{cost['wall_seconds']['max']:.0f}] wall s")
    old = (f", {table['old_layout']} of an earlier layout, not counted"
           if table["old_layout"] else "")
    commits = "; ".join(f"rows {how} at " + ", ".join(f"`{c}` ({n})" for c, n in counts.items())
                        for how, counts in (("sampled", table["commits"]["sampled"]),
                                            ("judged", table["commits"]["judged"])))
    return (f"{table['draws']} of {MIN_DRAWS} draws finished (seeds {seeds[0]}-{seeds[-1]}, "
            f"{table['failed']} failed{old}; {commits}); " + _goals_text(coverage_goals(table))
            + f"; {split}; limit cycles alone in {only['draws']} draws, their chains converged "
            f"in {only['converged']}; truth's structure in the set in {table['truth_in_set']} of "
            f"{table['draws']}; members calibrated per draw {min(sizes)}-{max(sizes)}")


#: The stages whose kernel steps make up a whole ``tvcid discover`` (``mcmc`` holds the start's
#: and the evidence's).
_STEP_STAGES = ("global", "nested", "refit", "ranking", "mcmc", "next_test")


def cycles_posterior(records):
    """A member's posterior on limit cycles alone, per method against the reference chain: its
    goals (:func:`.cycles_posterior.cycles_goals`), then per draw what each method gave, its
    diagnostic, its cost and its largest move against the reference."""
    from .cycles_posterior import cycles_goals, summarise

    rows = records["bench_cycles_posterior"]["rows"]
    table = summarise(rows)
    draws = []
    for r in rows:
        parts = []
        for name in ("default", "nested"):
            m = r["methods"][name]
            nested = m["stages"].get("nested")
            ran = (f" after nested sampling of {nested['likelihood_calls']} calls "
                   f"({'finished' if nested['finished'] else 'unfinished'}, "
                   f"{nested['effective_points']:.0f} effective points)"
                   if nested and m["sampler"] != "nested" else "")
            cost = ("resumed, its cost not whole" if m.get("resumed") else
                    f"{m['cpu_seconds']:.0f} CPU s")
            parts.append(f"{name} {m['sampler']}{ran}, "
                         f"{'converged' if m['converged'] else 'not converged'}, "
                         f"{m['effective_points']:.0f} effective points, {cost}, "
                         f"largest move {m['largest_move']:.2f}")
        ref = r["methods"]["reference"]
        drift = (ref.get("interval_drift") or {}).get("largest")
        cost = ("resumed, its cost not whole" if ref.get("resumed") else
                f"{ref['cpu_seconds']:.0f} CPU s")
        parts.append(f"reference {r['reference_steps']} steps ({cost})"
                     + (f", its halves' largest drift {drift:.2f}" if drift is not None else ""))
        draws.append(f"draw {r['seed']} ({r['structure']}): " + "; ".join(parts))
    return (f"{table['draws']} draws; " + _goals_text(cycles_goals(table)) + "; "
            + "; ".join(draws))


def discover_speed(records):
    """The whole ``tvcid discover`` on the speed benchmark's four recordings: its goal, judged in
    kernel-reference seconds measured in the same run, and where the time went; a run its idle
    check flagged (``idle_check``) is shown as flagged, its goal not judged."""
    from .discover_speed import GOAL_SECONDS
    from .goals import Goal

    r = records["bench_discover_speed"]
    stages, simulated = r["stages"], r.get("simulated_seconds") or {}
    goal = Goal.speed("wall time on 2 cores", r["wall_seconds"],
                      r["kernel_seconds_per_simulated_second"], GOAL_SECONDS)
    search = stages["sindy"] + stages["global"] + stages["nested"] + stages["ranking"]
    flag = r.get("idle_check")
    judged = (_goals_text([goal]) if not flag or flag["passed"] else
              f"flagged, not the speed ({flag['reason']}): goal {goal.what}: "
              f"{goal.value_text()} ({goal.target_text()}) not judged")
    text = (judged + f"; structure search and ranking {search:.0f} s, next test "
            f"{stages['next_test']:.0f} s, the set's calibration {stages['mcmc']:.0f} s "
            + (f"(the winner importance sampled, {r['mcmc_steps']} points)"
               if r.get("sampler") == "importance" else
               f"({'converged' if r['converged'] else 'not converged'}, {r['mcmc_steps']} steps)"))
    if simulated:
        searched = sum(v for k, v in simulated.items()
                       if k in ("global", "nested", "refit", "ranking"))
        text += (f"; simulated {searched / 1e6:.2g} million seconds in the search, "
                 f"{simulated['mcmc'] / 1e6:.2g} million in the set's calibration")
    compared = r.get("compared_with")
    if compared:
        text += ("; against the answers of the earlier run on the same recordings that the "
                 f"record's `compared_with` names: {'the same' if compared['same_winner'] else 'another'} "
                 f"winner, {'the same' if compared['same_set'] else 'another'} set, the 90 % "
                 f"intervals of the members carrying weight in either run moved by at most "
                 f"{compared['largest_move']:.2f} of their width")
        for name in compared.get("missing") or ():
            side = compared["moves"][name]["missing"]
            here, there = ("here", "there") if side == "before" else ("there", "here")
            text += f"; `{name}` carries weight {here} and is not calibrated {there}"
        was = compared.get("simulated_steps") or {}
        now = r.get("simulated_steps") or {}
        if was and now:
            total = {k: sum(v for s, v in d.items() if s in _STEP_STAGES) for k, d in
                     (("was", was), ("now", now))}
            text += (f"; kernel steps {total['now'] / 1e9:.3g} billion against "
                     f"{total['was'] / 1e9:.3g} billion there ({total['now'] / total['was']:.2f} "
                     f"of them; the set's calibration {now['mcmc'] / was['mcmc']:.2f})")
    steps = r.get("simulated_steps") or {}
    if steps:
        searched = sum(v for k, v in steps.items() if k in ("global", "nested", "refit", "ranking"))
        text += (f"; kernel steps {searched / 1e9:.3g} billion in the search, "
                 f"{steps['mcmc'] / 1e9:.3g} billion in the set's calibration")
    return text


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
          coverage_widening, lambda r: _widening(r)[1],
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
          "step error)",
          set_coverage, lambda r: r["bench_set_coverage"]["rows"],
          "python -m tvcid.studies.benchmarks.set_coverage --seed 3000 --draws 10 --jobs 2",
          "bench_set_coverage",
          "tests/test_bench_set_coverage.py::test_the_claim_counts_the_stored_draws_and_judges_none"
          "_under_thirty"),
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
