"""Coverage of what ``tvcid discover`` prints: structure and linear block unknown.

``python -m studies.benchmarks.set_coverage [--quick] [--draws N] [--seed S] [--ranges wide|papers]
[--jobs J | --dask ADDRESS] [--out DIR]``

Each draw (:func:`studies.benchmarks.scenarios.draw_scenario`, seeded; the discovery benchmark's
seeds by default) is a truth over every structure of the grammar and a test design over the
generator's ranges (``wide`` by default: thresholds and delays over a decade; limit cycles at
1-3 controller settings, continuous or held at 200 Hz, open-loop squares, sines and staircases or
none, acquisition at 200 Hz to 2 kHz, noise, sensor offset, quantisation). Its recordings are made
by the plain-Python reference simulator and written with measured-style sidecars (commands only as
samples); the whole ``tvcid discover`` runs on them (:func:`tvcid.pipeline.discover`): the
structure search, the set, the calibration of every member and their combination.

The row judges what the report prints for every quantity of the combined posterior
(:func:`discovery.structure.set_posterior.combine`: the dead zone at each place, the threshold,
the backlash, the friction offset, the band-pass gain, the delay, the DC gain and the bandwidth),
each by one rule, named in the row:

* ``interval``: the truth has the quantity, the report prints it, and it is pinned (``pinned``
  true, or ``None`` where no prior judges it): covered when the truth lies inside the printed 90 %
  interval (widened to the step error where ``discover`` widens it). A component the set leaves
  open (``present`` under 1, or ``left_open``: printed "present or absent; if present, ...",
  whichever members calibrated) is judged on its interval if present.
* ``allowed``: as above, but not pinned: covered when the truth lies inside the range the
  recordings allow; an open end (the prior's floor or ceiling) bounds nothing on its side. A
  not-pinned quantity without an allowed range is judged on its interval and flagged
  ``allowed_missing``.
* ``absent``: the truth lacks the component (backlash, friction offset, band-pass loop): covered
  when the report prints it absent or "present or absent"; not when it prints it present.
* ``lacking``: the truth has the quantity and the report prints no interval for it (a component
  decided absent, one left open that no calibrated member has, the dead zone at a place no member
  puts it): not covered.

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

Goals, over at least 30 finished draws: for each printed quantity, the truth covered in 80-97 %
of the draws that judge it; no printed interval narrower than twice its step error. The chains'
convergence is reported, not a goal: the draws with a chain stopped at its cap are counted apart
(``by_chains``), not left out. Rows are written to ``DIR/bench.json`` as each draw ends (a rerun
resumes; rows of an earlier layout, judged on the interval alone, are run again); each names the
commit of the code that ran it. A draw's directory without its row (``DIR/drawNNNN``, from an
interrupted run or copied from an earlier one) is resumed as ``discover`` resumes: its recordings
read back, its ranking, next test and finished chains carried over, the step errors, weights and
combined posterior computed again by this code. So the rows of a code change that leaves the
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

from discovery.structure.set_posterior import (COMPONENT_QUANTITIES, QUANTITY_UNITS, member_quantities,
                                               printed_present_or_absent)
from models.strict_json import write_json

from ..common import code_commit
from .draws import add_draw_options, run_benchmark
from .goals import Goal
from .goals import report as goal_report
from .scenarios import draw_scenario, write_recordings

CODE_COMMIT = code_commit()
#: The band the share of truths covered must fall in.
GOAL_BAND = (0.80, 0.97)
#: The quantities the report prints, each with its goal.
GOAL_QUANTITIES = tuple(QUANTITY_UNITS)
#: Draws at least, for the goals to be judged.
MIN_DRAWS = 30
#: The rules a judged quantity is judged by (the module docstring).
RULES = ("interval", "allowed", "absent", "lacking")
#: A width within this relative slack of twice the step error is not narrower: the mixture's
#: draws are its members' taken at evenly spaced ranks, quantiles to a few parts in 10^4.
STEP_SLACK = 1e-3


def truth_quantities(truth) -> dict:
    """The combined quantities the truth has (:func:`member_quantities` with no draws: a
    component the truth lacks is left out)."""
    return {k: float(v[0]) for k, v in member_quantities(truth.to_dict(), {}).items()}


def printed_as(q, left_open=False) -> str:
    """How the report prints combined quantity ``q`` (``None``: no calibrated member has it):
    ``present or absent`` (``present`` under 1, or a component the set leaves open:
    ``left_open``, or ``q``'s own ``left_open``), ``absent`` or ``present``."""
    if left_open or (q is not None and printed_present_or_absent(q)):
        return "present or absent"
    return "absent" if q is None else "present"


def inside_interval(value, q) -> bool:
    """Whether ``value`` lies inside ``q``'s printed 90 % interval (none printed: no)."""
    return q["q05"] is not None and q["q95"] is not None and q["q05"] <= value <= q["q95"]


def inside_allowed(value, allowed, allowed_open=None) -> bool:
    """Whether ``value`` lies inside ``allowed`` (``[low, high]``); an end ``allowed_open`` marks
    as the prior's bound bounds nothing on its side."""
    low_open, high_open = allowed_open or (False, False)
    return bool((low_open or value >= allowed[0]) and (high_open or value <= allowed[1]))


def judge(name, value, q, left_open=False) -> tuple:
    """``(rule, covered, allowed_missing)`` for quantity ``name`` with truth ``value`` (``None``:
    the truth lacks it) against the combined summary ``q`` (``None``: the set lacks it); the rule
    ``None`` where the quantity is not judged."""
    component = name in COMPONENT_QUANTITIES.values()
    if value is None or not math.isfinite(value):
        if component and value is None:
            return "absent", printed_as(q, left_open) != "present", False
        return None, None, False
    if q is None:
        return "lacking", False, False
    if q.get("pinned") is False:
        if q.get("allowed") is not None:
            return "allowed", inside_allowed(value, q["allowed"], q.get("allowed_open")), False
        return "interval", inside_interval(value, q), True
    return "interval", inside_interval(value, q), False


def narrower_than_step(q):
    """Whether ``q``'s printed interval is narrower than twice its step error, or, where the
    quantity's support cuts ``q50 +- step error`` (a delay's prior floor), narrower than what
    the support leaves of it (``None`` without a step error or an interval)."""
    step = q.get("step_error")
    if not step or None in (q["q05"], q["q50"], q["q95"]):
        return None
    floor, ceiling = q.get("support") or (None, None)
    low = q["q50"] - step if floor is None else max(q["q50"] - step, floor)
    high = q["q50"] + step if ceiling is None else min(q["q50"] + step, ceiling)
    return bool(q["q95"] - q["q05"] < (high - low) * (1 - STEP_SLACK))


def quantity_entry(name, value, q, left_open=False) -> dict:
    """One quantity of a row: what is printed, the truth, the rule and the verdict, the step
    error's check and, for an interval the rule judges, its relative width."""
    rule, covered, allowed_missing = judge(name, value, q, left_open)
    q = q or {}
    q05, q50, q95 = q.get("q05"), q.get("q50"), q.get("q95")
    allowed = q.get("allowed")
    known = value is not None and math.isfinite(value)
    width = None
    if rule == "interval" and None not in (q05, q50, q95) and q50 != 0:
        width = (q95 - q05) / abs(q50)
    return {
        "truth": value, "printed": printed_as(q or None, left_open), "present": q.get("present", 0.0),
        "q05": q05, "q50": q50, "q95": q95, "pinned": q.get("pinned"),
        "allowed": allowed, "allowed_open": q.get("allowed_open"),
        "rule": rule, "covered": covered, "allowed_missing": allowed_missing,
        # both tests, whatever the rule: how the interval and the range would have judged
        "inside": inside_interval(value, q) if known and q else None,
        "inside_allowed": (inside_allowed(value, allowed, q.get("allowed_open"))
                           if known and allowed is not None else None),
        "relative_width": width, "step_error": q.get("step_error"),
        "widened": bool(q.get("widened", False)),
        "narrower_than_step": narrower_than_step(q) if q else None,
    }


def coverage_row(seed, truth, structure, summary) -> dict:
    """The row of one draw: per quantity printed or held by the truth, :func:`quantity_entry`;
    ``goals`` maps each judged quantity to its verdict; the members, their weights and which
    chains stopped at their cap."""
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
        "goals": {n: e["covered"] for n, e in quantities.items() if e["rule"] is not None},
        "narrower_than_step": [n for n, e in quantities.items() if e["narrower_than_step"]],
        "commit": CODE_COMMIT,
    }


def run_draw(seed, out_dir, quick, ranges="wide") -> dict:
    """Make one draw's recordings, run ``tvcid discover`` on them, and judge what it prints."""
    from tvcid.pipeline import discover

    scenario = draw_scenario(seed, ranges=ranges)
    draw_dir = Path(out_dir) / f"draw{seed:03d}"
    t0 = time.perf_counter()
    paths = write_recordings(scenario, draw_dir / "recordings", reuse=True)
    t_data = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = discover(paths, draw_dir / "discover", seed=seed, quick=quick, progress=False).summary
    row = coverage_row(seed, scenario.truth, scenario.structure, summary)
    row.update(design=scenario.to_dict(), seconds_data=t_data,
               seconds_discover=time.perf_counter() - t0,
               seconds_by_stage={k: round(float(v), 1) for k, v in summary["timings"].items()
                                 if isinstance(v, (int, float))})
    return row


def guarded_draw(seed, out_dir, quick, ranges="wide") -> dict:
    """:func:`run_draw`, a failure recorded as a row (the benchmark goes on)."""
    try:
        return run_draw(seed, out_dir, quick, ranges=ranges)
    except Exception as exc:  # noqa: BLE001 - one draw's failure is a result, not a crash
        return {"seed": seed, "error": f"{type(exc).__name__}: {exc}", "ranges": ranges,
                "commit": CODE_COMMIT}


def cycles_only(row) -> bool:
    """Whether the draw's recordings are limit cycles alone (no open-loop test)."""
    kinds = [r["kind"] for r in (row.get("design") or {}).get("recordings", [])]
    return bool(kinds) and "open" not in kinds


def of_this_layout(row) -> bool:
    """Whether a finished row judges its quantities by this module's rules (an earlier layout
    judged the interval alone and has no ``rule``)."""
    quantities = row.get("quantities") or {}
    return bool(quantities) and all("rule" in e for e in quantities.values())


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


def _tally(rows, names) -> dict:
    """Per quantity, the draws covering it over the draws judging it."""
    out = {}
    for q in names:
        judged = [r["quantities"][q] for r in rows
                  if q in r["quantities"] and r["quantities"][q]["rule"] is not None]
        out[q] = {"covered": sum(bool(e["covered"]) for e in judged), "draws": len(judged)}
    return out


def summarise(rows) -> dict:
    """The table over the rows.

    Returns
    -------
    dict
        ``draws`` (finished rows of this layout), ``failed``, ``old_layout`` (finished rows of an
        earlier layout: not judged); ``quantities``: per quantity ``covered`` of ``draws`` (those
        judging it), ``by_rule`` (the same per rule), ``allowed_missing`` (not pinned, judged on
        the interval for want of a range), ``median_relative_width`` over ``widths`` intervals
        judged on the interval rule; ``by_chains``: ``converged`` and ``stopped at the cap``,
        each ``draws`` and per quantity ``covered`` of ``draws``; ``allowed``: per quantity the
        truths ``inside`` the range the recordings allow over the ``draws`` that print one;
        ``step``: printed ``intervals`` with a step error, those ``narrower`` than twice it,
        those ``widened``, and those ``without_step_error``; ``position``: over the
        ``intervals`` judged on the interval rule, the ``median_abs`` of
        :func:`truth_position` and the share ``within_half`` (``|position| < 0.5``), beside
        ``gaussian_median_abs`` (:data:`GAUSSIAN_MEDIAN_POSITION`; the quantities of one draw
        share its fit, so the intervals are not independent); ``converged``, ``truth_in_set``,
        ``cycles_only`` (``draws`` and their ``converged``).
    """
    finished = [r for r in rows if "error" not in r]
    done = [r for r in finished if of_this_layout(r)]
    extra = sorted({q for r in done for q in r["quantities"]} - set(GOAL_QUANTITIES))
    names = list(GOAL_QUANTITIES) + extra
    tally = _tally(done, names)
    quantities = {}
    for q in names:
        judged = [r["quantities"][q] for r in done
                  if q in r["quantities"] and r["quantities"][q]["rule"] is not None]
        widths = [e["relative_width"] for e in judged if e["relative_width"] is not None]
        quantities[q] = {
            **tally[q],
            "by_rule": {rule: {"covered": sum(bool(e["covered"]) for e in judged if e["rule"] == rule),
                               "draws": sum(e["rule"] == rule for e in judged)} for rule in RULES},
            "allowed_missing": sum(bool(e["allowed_missing"]) for e in judged),
            "median_relative_width": float(np.median(widths)) if widths else None,
            "widths": len(widths),
        }
    by_chains = {}
    for label, converged in (("converged", True), ("stopped at the cap", False)):
        part = [r for r in done if bool(r["converged"]) is converged]
        by_chains[label] = {"draws": len(part), "quantities": _tally(part, names)}
    allowed = {}
    for q in names:
        judged = [r["quantities"][q] for r in done
                  if q in r["quantities"] and r["quantities"][q]["rule"] is not None
                  and r["quantities"][q]["inside_allowed"] is not None]
        allowed[q] = {"inside": sum(e["inside_allowed"] for e in judged), "draws": len(judged)}
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
    return {"draws": len(done), "failed": len(rows) - len(finished),
            "old_layout": len(finished) - len(done), "quantities": quantities,
            "by_chains": by_chains, "allowed": allowed, "step": step, "position": position,
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
        goals.append(Goal(f"{q}: truth covered by what the report prints",
                          share if enough else None, low=lo, high=hi, fmt="{:.0%}",
                          shown=f"{k} of {m}" + (f" = {share:.0%}" if share is not None else ""),
                          target=f"{lo:.0%} to {hi:.0%} over >= {MIN_DRAWS} draws"))
    s = table["step"]
    goals.append(Goal("printed intervals narrower than twice their step error",
                      s["narrower"] if enough else None, high=0, fmt="{:d}",
                      shown=f"{s['narrower']} of {s['intervals']}",
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_draw_options(parser, "short chains (150 steps), 2 draws", 2, "results/bench_set_coverage")
    args = parser.parse_args(argv)
    dropped = drop_old_layout(Path(args.out) / "bench.json")
    if dropped:
        print(f"{dropped} draws of an earlier layout run again")

    def describe(row):
        verdicts = ", ".join(f"{q} {'in' if v else 'OUT'}" for q, v in row["goals"].items())
        stopped = len(row["stopped_at_cap"])
        return (f"draw {row['seed']}: truth {row['structure']}, set of {len(row['members'])}, "
                f"{stopped} chains stopped at the cap: {verdicts} [{row['seconds_discover']:.0f} s]")

    def save(path, rows):
        write_json(path, {"quick": args.quick, "rows": rows, "table": summarise(rows)})

    rows = run_benchmark(args, guarded_draw, describe, save)
    table = summarise(rows)
    print(f"\n{table['draws']} draws ({table['failed']} failed); truth in the set "
          f"{table['truth_in_set']}; every chain converged in {table['converged']}")
    for q, c in table["quantities"].items():
        rules = ", ".join(f"{rule} {r['covered']} of {r['draws']}"
                          for rule, r in c["by_rule"].items() if r["draws"])
        width = c["median_relative_width"]
        print(f"  {q:22s} covered {c['covered']} of {c['draws']} ({rules or 'none judged'}); "
              f"median relative width {'-' if width is None else f'{width:.2g}'}")
    for label, part in table["by_chains"].items():
        print(f"  {label}: {part['draws']} draws")
    p = table["position"]
    if p["intervals"]:
        print(f"  truth's position in its interval (|truth - median| over the half-width on its "
              f"side): median {p['median_abs']:.2f} over {p['intervals']} intervals "
              f"({p['gaussian_median_abs']:.2f} for calibrated Gaussian intervals)")
    s = table["step"]
    print(f"  printed intervals narrower than twice the step error: {s['narrower']} of "
          f"{s['intervals']} ({s['widened']} widened, {s['without_step_error']} without a step error)")
    return goal_report(coverage_goals(table))


if __name__ == "__main__":
    from discovery.parallel import run_interruptible

    raise SystemExit(run_interruptible(main))
