"""Coverage of what ``tvcid discover`` prints: structure and linear block unknown.

``python -m tvcid.studies.benchmarks.set_coverage [--quick] [--draws N] [--seed S] [--ranges wide|papers]
[--jobs J | --dask ADDRESS] [--out DIR] [--rejudge]``

Each draw (:func:`tvcid.studies.benchmarks.scenarios.draw_scenario`, seeded; the discovery benchmark's
seeds by default) is a truth over every structure of the grammar and a test design over the
generator's ranges (``wide`` by default: thresholds and delays over a decade; limit cycles at
1-3 controller settings, continuous or held at 200 Hz, open-loop squares, sines and staircases or
none, acquisition at 200 Hz to 2 kHz, noise, sensor offset, quantisation). Its recordings are made
by the plain-Python reference simulator and written with measured-style sidecars (commands only as
samples); the whole ``tvcid discover`` runs on them (:func:`tvcid.pipeline.discover`): the
structure search, the set, the calibration of every member and their combination.

The row judges what the report prints for every quantity of the combined posterior
(:func:`tvcid.discovery.members.set_posterior.combine`: the dead zone at each place, the threshold,
the backlash, the friction offset, the band-pass gain, the delay, the DC gain and the bandwidth),
each by one rule of :mod:`tvcid.studies.benchmarks.set_judge`, named in the row: ``interval`` (a pinned
quantity on its printed 90 % interval), ``allowed`` (a not-pinned one on the range the
recordings allow, an open end judged on the prior's bound on its side, stored per quantity as
``prior_bounds``), ``absent`` (a component the truth lacks: not printed present) and ``lacking``
(the truth has it and nothing is printed, or it is printed absent). A judgement that cannot
fail (a truth of 0 against "present or absent"; a truth inside the prior against a range open
at both ends) is counted apart (``can_fail`` false) and left out of the goals.

A dead-zone place, or the threshold, that the truth does not have is printed but not judged
(``rule`` ``None``): the truth's own place is. Beside the verdict, each printed quantity records
its step error (the members' errors averaged by their weights), whether ``discover`` widened
it (each member's draws to at least its median +- its own error), and whether its printed
interval is narrower than twice the step error. An interval judged on its interval rule also
records its width relative to its median, ``(q95 - q05) / |q50|`` (in linear units, ``None`` for
a median of 0): the summary's median of it shows whether coverage is bought by width. The
summary also places each truth in its interval (:func:`truth_position`, -1 and 1 at the ends):
coverage counts only the truths outside, and over ten draws a 90 % interval's misses are one or
two, while the median distance of every truth from its median, against the 0.41 of calibrated
Gaussian intervals, says at any count whether the intervals are too wide or too narrow.

Each miss is explained by the truth's own member of the set (:mod:`.set_misses`, read from the
draw's ``discovery.json``, again at every ``--rejudge``), one of
:data:`.set_misses.CAUSES`; the table lists the misses by cause. Each structural choice as the
report prints it, by the set or by the weights (:func:`.verdicts.printed_choices`, from the same
file, by the judging commit's rule and by the run's stored one), is judged right, wrong or open.

Goals, over at least 30 finished draws: for each printed quantity, the truth covered in 80-97 %
of the draws whose judgement of it can fail; the truths' median distance from their interval's
median 0.3-0.5 half-widths (coverage not bought by width); no printed interval narrower than
twice its step error; no structural choice printed wrongly. The chains' convergence is reported, not a goal: the draws with a chain
stopped at its cap are counted apart (``by_chains``), not left out. Each row records what its
run cost (kernel steps, CPU and wall seconds, ``cost``). Rows are written to ``DIR/bench.json`` as each draw ends (a rerun
resumes; rows of an earlier layout, judged on the interval alone, are run again, and rows judged
without ``can_fail`` are judged again from the row); each names the commit that sampled its
chains (``commit``) and, where different, the one that judged it (``judged_commit``).
``--rejudge`` judges every row of ``DIR/bench.json`` again from the row alone
(:func:`tvcid.studies.benchmarks.set_judge.rejudge_row`: no recording, no chain), records the judging
commit and prints the table. A draw's directory without its row (``DIR/drawNNNN``, from an
interrupted run or copied from an earlier one) is resumed as ``discover`` resumes: its recordings
read back, its ranking, next test and finished chains carried over, the step errors, weights and
combined posterior computed again by this code (the row's ``chains_carried_over`` is then
true: its ``commit`` is this run's, not necessarily the one that sampled the chains). So the rows of a code change that leaves the
sampling alone are made again at the new commit in one to three minutes a draw, where a fresh
draw takes one to two hours.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from tvcid.models.quantities import COMPONENT_QUANTITIES, QUANTITY_UNITS, member_quantities
from tvcid.models.strict_json import write_json
from tvcid.run_record import RunCost

from ..common import code_commit, failure, machine
from .draws import add_draw_options, run_benchmark
from .goals import Goal
from .goals import report as goal_report
from .scenarios import draw_scenario, write_recordings
from .set_judge import (RULES, beyond_prior, inside_interval, narrower_than_step,  # noqa: F401
                        printed_as, quantity_entry, rejudge_row, row_verdicts)
from .set_misses import cause_counts, causes_text, with_miss_causes
from .verdicts import choices_text, printed_choice_counts, with_printed_choices

CODE_COMMIT = code_commit()
MACHINE = machine()
#: The files whose code judges a stored row (``--rejudge``): their commit is the judging one.
JUDGE_FILES = tuple(Path(__file__).with_name(n)
                    for n in ("set_judge.py", "set_misses.py", "set_coverage.py", "verdicts.py")) + (
    Path(__file__).parents[2] / "discovery" / "members" / "set_weights.py",)
#: The band the share of truths covered must fall in.
GOAL_BAND = (0.80, 0.97)
#: The quantities the report prints, each with its goal.
GOAL_QUANTITIES = tuple(QUANTITY_UNITS)
#: Draws at least, for the goals to be judged.
MIN_DRAWS = 30
#: The band the truths' median position in their intervals must fall in (calibrated Gaussian
#: intervals give :data:`GAUSSIAN_MEDIAN_POSITION`, 0.41): coverage not bought by width.
POSITION_BAND = (0.3, 0.5)


def truth_quantities(truth) -> dict:
    """The combined quantities the truth has (:func:`member_quantities` with no draws: a
    component the truth lacks is left out)."""
    return {k: float(v[0]) for k, v in member_quantities(truth.to_dict(), {}).items()}


def coverage_row(seed, truth, structure, summary) -> dict:
    """The row of one draw: per quantity printed or held by the truth, :func:`quantity_entry`;
    ``goals`` maps each judged quantity to its verdict and ``cannot_fail`` lists those whose
    judgement cannot fail; the members, their weights and which chains stopped at their cap."""
    values = truth_quantities(truth)
    sp = summary["set_posterior"]
    combined = sp["quantities"]
    # every component is judged, present in the truth or not
    seen = set(values) | set(combined) | set(COMPONENT_QUANTITIES.values())
    names = [n for n in QUANTITY_UNITS if n in seen] + sorted(seen - set(QUANTITY_UNITS))
    open_ = set(sp.get("left_open_uncalibrated") or ())
    quantities = {n: quantity_entry(n, values.get(n), combined.get(n), n in open_) for n in names}
    members = sp["members"]
    return {
        "seed": seed,
        "structure": structure.name,
        "truth_in_set": structure.name in set(summary["indistinguishable"]),
        "members": [m["structure"] for m in members],
        "weights": [m.get("weight") for m in members],
        "converged": all(m["converged"] for m in members),
        "stopped_at_cap": [m["structure"] for m in members if not m["converged"]],
        "not_pinned": sorted({n for m in members for n in m["posterior"].get("not_pinned", [])}),
        "quantities": quantities,
        **row_verdicts(quantities),
        "narrower_than_step": [n for n, e in quantities.items() if e["narrower_than_step"]],
        "commit": CODE_COMMIT,
        "machine": MACHINE,
    }


def run_draw(seed, out_dir, quick, ranges="wide") -> dict:
    """Make one draw's recordings, run ``tvcid discover`` on them, and judge what it prints."""
    from tvcid.pipeline import discover

    scenario = draw_scenario(seed, ranges=ranges)
    draw_dir = Path(out_dir) / f"draw{seed:03d}"
    carried = (draw_dir / "discover").exists()
    t0 = time.perf_counter()
    paths = write_recordings(scenario, draw_dir / "recordings", reuse=True)
    t_data = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = discover(paths, draw_dir / "discover", seed=seed, quick=quick, progress=False).summary
    row = coverage_row(seed, scenario.truth, scenario.structure, summary)
    row.update(design=scenario.to_dict(), chains_carried_over=carried, seconds_data=t_data,
               seconds_discover=time.perf_counter() - t0,
               cost=RunCost.from_dict(summary).totals(),
               seconds_by_stage={k: round(float(v), 1) for k, v in summary["timings"].items()
                                 if isinstance(v, (int, float))})
    return read_from_draw(row, draw_dir)


def read_from_draw(row, draw_dir) -> dict:
    """``row`` with what its draw's directory tells beyond the printed quantities: its misses'
    causes (:func:`.set_misses.with_miss_causes`) and each structural choice as printed
    (:func:`.verdicts.with_printed_choices`)."""
    return with_printed_choices(with_miss_causes(row, draw_dir), draw_dir)


def guarded_draw(seed, out_dir, quick, ranges="wide") -> dict:
    """:func:`run_draw`, a failure recorded as a row (the benchmark goes on)."""
    try:
        return run_draw(seed, out_dir, quick, ranges=ranges)
    except Exception as exc:  # noqa: BLE001 - one draw's failure is a result, not a crash
        return {"seed": seed, **failure(exc), "ranges": ranges,
                "commit": CODE_COMMIT, "machine": MACHINE}


def cycles_only(row) -> bool:
    """Whether the draw's recordings are limit cycles alone (no open-loop test)."""
    kinds = [r["kind"] for r in (row.get("design") or {}).get("recordings", [])]
    return bool(kinds) and "open" not in kinds


def of_this_layout(row) -> bool:
    """Whether a finished row judges its quantities by rules (an earlier layout judged the
    interval alone and has no ``rule``)."""
    quantities = row.get("quantities") or {}
    return bool(quantities) and all("rule" in e for e in quantities.values())


def judged_by_these_rules(row) -> bool:
    """Whether a finished row of this layout says which judgements can fail (a row that does not
    is judged again from the row, :func:`rejudge_rows`)."""
    return all("can_fail" in e for e in row["quantities"].values())


def judging_commit():
    """The checkout's commit, ``+dirty`` where the judge's own files (:data:`JUDGE_FILES`) differ
    from it: the commit a stored row is judged again at."""
    return code_commit(JUDGE_FILES)


def rejudge_rows(rows, everything=False, commit=None) -> tuple:
    """``(rows, n)``: ``rows`` with the finished rows of this layout judged again
    (:func:`rejudge_row`, at ``commit``, default :func:`judging_commit`): every one with
    ``everything``, else those not :func:`judged_by_these_rules`; ``n`` of them."""
    commit = judging_commit() if commit is None else commit
    out, n = [], 0
    for r in rows:
        if "error" not in r and of_this_layout(r) and (everything or not judged_by_these_rules(r)):
            r, n = rejudge_row(r, commit), n + 1
        out.append(r)
    return out, n


#: The median of ``|truth_position|`` for a calibrated Gaussian posterior's 90 % interval:
#: ``z_0.75 / z_0.95``. Below it the truths sit closer to the median than the intervals claim
#: (intervals too wide); above it, farther.
GAUSSIAN_MEDIAN_POSITION = 0.6745 / 1.6449


def truth_position(entry):
    """Where the truth lies in its printed 90 % interval: ``(truth - q50)`` over the half-width on
    the truth's side (``q50 - q05`` or ``q95 - q50``), so that -1 and 1 are the interval's ends;
    ``None`` where the entry is not judged on its interval or a half-width is 0."""
    if entry.get("rule") != "interval" or entry.get("truth") is None:
        return None
    t, q05, q50, q95 = entry["truth"], entry["q05"], entry["q50"], entry["q95"]
    if None in (q05, q50, q95) or not math.isfinite(t):
        return None
    half = q50 - q05 if t < q50 else q95 - q50
    return (t - q50) / half if half > 0 else None


def _judged(rows, q) -> list:
    """The entries of quantity ``q`` the rows judge."""
    return [r["quantities"][q] for r in rows
            if q in r["quantities"] and r["quantities"][q]["rule"] is not None]


def _tally(rows, names) -> dict:
    """Per quantity, the draws covering it over the draws whose judgement of it can fail
    (``covered`` of ``draws``, the goals' counts), and apart those whose judgement cannot fail
    (``cannot_fail``) or that the row leaves undecided (``undecided``)."""
    out = {}
    for q in names:
        judged = _judged(rows, q)
        can = [e for e in judged if e["can_fail"]]
        out[q] = {"covered": sum(bool(e["covered"]) for e in can), "draws": len(can),
                  "cannot_fail": sum(e["can_fail"] is False for e in judged),
                  "undecided": sum(e["covered"] is None for e in judged)}
    return out


def _count(values) -> dict:
    """How many of ``values`` each distinct value is, most first."""
    counts = {}
    for v in values:
        counts[v] = counts.get(v, 0) + 1
    return dict(sorted(counts.items(), key=lambda x: (-x[1], str(x[0]))))


def summarise(rows) -> dict:
    """The table over the rows.

    Returns
    -------
    dict
        ``draws`` (finished rows of this layout), ``failed``, ``old_layout`` (finished rows of an
        earlier layout, or not saying which judgements can fail: not counted); ``commits``: rows per ``sampled`` commit (``commit``) and
        per ``judged`` one (``judged_commit``, else ``commit``); ``quantities``: per quantity
        ``covered`` of ``draws`` (those whose judgement can fail: the goals' counts),
        ``cannot_fail`` and ``undecided`` (counted apart), ``by_rule`` (``covered`` of
        ``draws`` per rule over the judgements that can fail, and the rule's ``cannot_fail``),
        ``allowed_missing`` (not pinned, judged on the interval for want of a range),
        ``median_relative_width`` over ``widths`` intervals judged on the interval rule;
        ``cannot_fail``: the judgements that cannot fail, ``present_or_absent`` (a truth of 0
        against "present or absent") and ``open_at_both_ends`` (a truth inside the prior against
        a range open at both ends); ``beyond_prior``: the misses whose truth lies beyond the
        prior's bound an open end stands for, each ``[seed, quantity]``; ``by_chains``:
        ``converged`` and ``stopped at the cap``, each ``draws`` and per quantity the counts
        above; ``allowed``: per quantity the truths ``inside`` the range the recordings allow
        (judged on the prior's bounds at its open ends) over the ``draws`` that print one and
        decide it; ``step``: printed ``intervals`` with a step error, those ``narrower`` than
        twice it, those ``widened``, and those ``without_step_error``; ``position``: over the
        ``intervals`` judged on the interval rule, the ``median_abs`` of
        :func:`truth_position` and the share ``within_half`` (``|position| < 0.5``), beside
        ``gaussian_median_abs`` (:data:`GAUSSIAN_MEDIAN_POSITION`; the quantities of one draw
        share its fit, so the intervals are not independent); ``cost``: over the ``draws`` run
        in one piece (a draw resumed from an earlier run's directory counts only what its last
        run did), the ``median``, ``max`` and ``sum`` of the whole run's ``kernel_steps``,
        ``cpu_seconds`` and ``wall_seconds`` (:meth:`tvcid.run_record.RunCost.totals`);
        ``misses``: the misses of the rows that explain them, by cause
        (:func:`.set_misses.cause_counts`); ``choices``: the structural choices as printed,
        right, open or wrong (:func:`.verdicts.printed_choice_counts`); ``converged``, ``truth_in_set``, ``cycles_only``
        (``draws`` and their ``converged``).
    """
    finished = [r for r in rows if "error" not in r]
    done = [r for r in finished if of_this_layout(r) and judged_by_these_rules(r)]
    extra = sorted({q for r in done for q in r["quantities"]} - set(GOAL_QUANTITIES))
    names = list(GOAL_QUANTITIES) + extra
    tally = _tally(done, names)
    quantities = {}
    for q in names:
        judged = _judged(done, q)
        widths = [e["relative_width"] for e in judged if e["relative_width"] is not None]
        quantities[q] = {
            **tally[q],
            "by_rule": {rule: {"covered": sum(bool(e["covered"]) for e in judged
                                              if e["rule"] == rule and e["can_fail"]),
                               "draws": sum(e["rule"] == rule and bool(e["can_fail"]) for e in judged),
                               "cannot_fail": sum(e["rule"] == rule and e["can_fail"] is False
                                                  for e in judged)} for rule in RULES},
            "allowed_missing": sum(bool(e["allowed_missing"]) for e in judged),
            "median_relative_width": float(np.median(widths)) if widths else None,
            "widths": len(widths),
        }
    entries = [e for r in done for e in r["quantities"].values() if e["can_fail"] is False]
    cannot_fail = {"present_or_absent": sum(e["rule"] == "absent" for e in entries),
                   "open_at_both_ends": sum(e["rule"] == "allowed" for e in entries)}
    beyond = [[r["seed"], q] for r in done for q, e in r["quantities"].items() if beyond_prior(e)]
    by_chains = {}
    for label, converged in (("converged", True), ("stopped at the cap", False)):
        part = [r for r in done if bool(r["converged"]) is converged]
        by_chains[label] = {"draws": len(part), "quantities": _tally(part, names)}
    allowed = {}
    for q in names:
        tested = [e for e in _judged(done, q) if e["inside_allowed"] is not None]
        allowed[q] = {"inside": sum(e["inside_allowed"] for e in tested), "draws": len(tested)}
    printed = [e for r in done for e in r["quantities"].values() if e["printed"] != "absent"]
    step = {"intervals": sum(e["narrower_than_step"] is not None for e in printed),
            "narrower": sum(bool(e["narrower_than_step"]) for e in printed),
            "widened": sum(e["widened"] for e in printed),
            "without_step_error": sum(e["narrower_than_step"] is None for e in printed)}
    positions = [truth_position(e) for r in done for e in r["quantities"].values()]
    positions = np.abs([p for p in positions if p is not None])
    position = {"intervals": int(positions.size),
                "median_abs": float(np.median(positions)) if positions.size else None,
                "within_half": float(np.mean(positions < 0.5)) if positions.size else None,
                "gaussian_median_abs": GAUSSIAN_MEDIAN_POSITION}
    only = [r for r in done if cycles_only(r)]
    fresh = [r["cost"] for r in done if r.get("cost") and not r.get("chains_carried_over")]
    cost = {"draws": len(fresh), **{
        key: {"median": float(np.median(v)), "max": float(np.max(v)), "sum": float(np.sum(v))}
        for key in ("kernel_steps", "cpu_seconds", "wall_seconds")
        for v in [[c[key] for c in fresh]] if v}}
    commits = {"sampled": _count(r.get("commit") for r in done),
               "judged": _count(r.get("judged_commit", r.get("commit")) for r in done)}
    return {"draws": len(done), "failed": len(rows) - len(finished),
            "old_layout": len(finished) - len(done), "commits": commits, "quantities": quantities,
            "cannot_fail": cannot_fail, "beyond_prior": beyond,
            "by_chains": by_chains, "allowed": allowed, "step": step, "position": position,
            "cost": cost, "misses": cause_counts(done), "choices": printed_choice_counts(done),
            "converged": sum(r["converged"] for r in done),
            "truth_in_set": sum(r["truth_in_set"] for r in done),
            "cycles_only": {"draws": len(only), "converged": sum(r["converged"] for r in only)}}


def coverage_goals(table) -> list:
    """The goals of the module's docstring; not met under :data:`MIN_DRAWS` draws."""
    n = table["draws"]
    enough = n >= MIN_DRAWS
    lo, hi = GOAL_BAND
    goals = []
    for q in GOAL_QUANTITIES:
        c = table["quantities"][q]
        k, m = c["covered"], c["draws"]
        share = k / m if m else None
        apart = ", ".join(f"{c[key]} {text}" for key, text in (
            ("cannot_fail", "that cannot fail"), ("undecided", "undecided")) if c[key])
        goals.append(Goal(f"{q}: truth covered by what the report prints, where that can fail",
                          share if enough else None, low=lo, high=hi, fmt="{:.0%}",
                          shown=f"{k} of {m}" + (f" = {share:.0%}" if share is not None else "")
                          + (f" ({apart} apart)" if apart else ""),
                          target=f"{lo:.0%} to {hi:.0%} over >= {MIN_DRAWS} draws"))
    p = table["position"]
    lo, hi = POSITION_BAND
    goals.append(Goal("the truths' median distance from their interval's median, in half-widths",
                      p["median_abs"] if enough else None, low=lo, high=hi, fmt="{:.2f}",
                      shown=f"{p['median_abs']:.2f} over {p['intervals']} intervals"
                      if p["median_abs"] is not None else "no interval",
                      target=f"{lo} to {hi} over >= {MIN_DRAWS} draws "
                             f"({GAUSSIAN_MEDIAN_POSITION:.2f} for calibrated intervals)"))
    s = table["step"]
    goals.append(Goal("printed intervals narrower than twice their step error",
                      s["narrower"] if enough else None, high=0, fmt="{:d}",
                      shown=f"{s['narrower']} of {s['intervals']}",
                      target=f"none over >= {MIN_DRAWS} draws"))
    c = table.get("choices") or {}
    if c.get("draws"):
        goals.append(Goal("structural choices printed wrongly (by the set or the weights)",
                          len(c["wrong"]) if enough else None, high=0, fmt="{:d}",
                          shown=f"{len(c['wrong'])} of {c['right'] + len(c['wrong'])} decided, "
                                f"over {c['draws']} draws",
                          target=f"none over >= {MIN_DRAWS} draws"))
    return goals


def drop_old_layout(path) -> int:
    """Remove from ``path`` (a ``bench.json``) the finished rows of an earlier layout, so that a
    rerun runs their draws again; returns how many."""
    path = Path(path)
    if not path.exists():
        return 0
    record = json.loads(path.read_text())
    keep = [r for r in record["rows"] if "error" in r or of_this_layout(r)]
    dropped = len(record["rows"]) - len(keep)
    if dropped:
        write_json(path, {**record, "rows": keep, "table": summarise(keep)})
    return dropped


def rejudge_record(path, everything=False) -> int:
    """Judge the rows of ``path`` (a ``bench.json``) again (:func:`rejudge_rows`), explain their
    misses and read their printed choices from their draws' directories beside it
    (:func:`read_from_draw`) and
    write it back with its table; returns how many rows were judged."""
    path = Path(path)
    if not path.exists():
        return 0
    record = json.loads(path.read_text())
    rows, n = rejudge_rows(record["rows"], everything=everything)
    rows = [r if "error" in r else read_from_draw(r, path.parent / f"draw{r['seed']:03d}")
            for r in rows]
    if n or rows != record["rows"]:
        write_json(path, {**record, "rows": rows, "table": summarise(rows)})
    return n


def print_table(table) -> None:
    """The table's lines: per quantity the counts of :func:`summarise`, the judgements apart, the
    chains, the truths' positions and the step errors."""
    sampled = ", ".join(f"{c} ({n})" for c, n in table["commits"]["sampled"].items())
    judged = ", ".join(f"{c} ({n})" for c, n in table["commits"]["judged"].items())
    print(f"\n{table['draws']} draws ({table['failed']} failed); sampled at {sampled}; judged at "
          f"{judged}; truth in the set {table['truth_in_set']}; every chain converged in "
          f"{table['converged']}")
    for q, c in table["quantities"].items():
        rules = ", ".join(f"{rule} {r['covered']} of {r['draws']}"
                          for rule, r in c["by_rule"].items() if r["draws"])
        width = c["median_relative_width"]
        print(f"  {q:22s} covered {c['covered']} of {c['draws']} ({rules or 'none judged'}); "
              f"cannot fail {c['cannot_fail']}; undecided {c['undecided']}; "
              f"median relative width {'-' if width is None else f'{width:.2g}'}")
    cf = table["cannot_fail"]
    print(f"  judgements that cannot fail: a truth of 0 against \"present or absent\" "
          f"{cf['present_or_absent']}, a truth inside the prior against a range open at both "
          f"ends {cf['open_at_both_ends']}")
    print(f"  misses beyond the prior's bound an open end stands for: "
          + (", ".join(f"draw {seed} {q}" for seed, q in table["beyond_prior"]) or "none"))
    for label, part in table["by_chains"].items():
        print(f"  {label}: {part['draws']} draws")
    p = table["position"]
    if p["intervals"]:
        print(f"  truth's position in its interval (|truth - median| over the half-width on its "
              f"side): median {p['median_abs']:.2f} over {p['intervals']} intervals "
              f"({p['gaussian_median_abs']:.2f} for calibrated Gaussian intervals)")
    c = table["cost"]
    if c["draws"]:
        print(f"  cost of a draw run in one piece ({c['draws']} draws), median [max]: "
              f"{c['kernel_steps']['median']:.3g} [{c['kernel_steps']['max']:.3g}] kernel steps, "
              f"{c['cpu_seconds']['median']:.0f} [{c['cpu_seconds']['max']:.0f}] CPU s, "
              f"{c['wall_seconds']['median']:.0f} [{c['wall_seconds']['max']:.0f}] wall s")
    if causes_text(table["misses"]):
        print(f"  {causes_text(table['misses'])}")
    if choices_text(table.get("choices")):
        print(f"  {choices_text(table['choices'])}")
    s = table["step"]
    print(f"  printed intervals narrower than twice the step error: {s['narrower']} of "
          f"{s['intervals']} ({s['widened']} widened, {s['without_step_error']} without a step error)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_draw_options(parser, "short chains (150 steps), 2 draws", 2, "results/bench_set_coverage")
    parser.add_argument("--rejudge", action="store_true",
                        help="judge every row of DIR/bench.json again from the row alone (no "
                             "sampling), write it back and print the table")
    args = parser.parse_args(argv)
    path = Path(args.out) / "bench.json"
    if args.rejudge:
        n = rejudge_record(path, everything=True)
        print(f"{n} rows of {path} judged again at {judging_commit()}")
        table = summarise(json.loads(path.read_text())["rows"]) if path.exists() else summarise([])
        print_table(table)
        return goal_report(coverage_goals(table))
    stale = rejudge_record(path)
    if stale:
        print(f"{stale} rows judged again from the row (they did not say which judgements can fail)")
    dropped = drop_old_layout(path)
    if dropped:
        print(f"{dropped} draws of an earlier layout run again")

    def describe(row):
        verdicts = ", ".join(f"{q} {'in' if v else 'undecided' if v is None else 'OUT'}"
                             for q, v in row["goals"].items())
        stopped = len(row["stopped_at_cap"])
        return (f"draw {row['seed']}: truth {row['structure']}, set of {len(row['members'])}, "
                f"{stopped} chains stopped at the cap: {verdicts} [{row['seconds_discover']:.0f} s]")

    def save(path, rows):
        write_json(path, {"quick": args.quick, "rows": rows, "table": summarise(rows)})

    rows = run_benchmark(args, guarded_draw, describe, save)
    table = summarise(rows)
    print_table(table)
    return goal_report(coverage_goals(table))


if __name__ == "__main__":
    from tvcid.discovery.parallel import run_interruptible

    raise SystemExit(run_interruptible(main))
