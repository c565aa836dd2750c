"""The value of each claim of ``docs/results.md``: one function per benchmark record, computed
from the record's rows by the benchmark's own functions (:mod:`.results_table` renders them).
"""
from __future__ import annotations

def _goals_text(goals) -> str:
    return "; ".join(f"goal {g.text()}" for g in goals)


def _pct(x) -> str:
    return f"{100 * x:.0f} %"


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


def widening_rows(records):
    from .coverage import widening

    plain = records["bench_coverage_widening"]["plain_rows"]
    result = widening(records["bench_coverage"]["rows"], plain)
    paired = {d["index"] for d in result["draws"]}
    with_term = [r for r in records["bench_coverage"]["rows"] if r["index"] in paired]
    return result, with_term + [r for r in plain if r["index"] in paired]


def coverage_widening(records):
    from .coverage import widening_goal

    result, _ = widening_rows(records)
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
    from .set_misses import causes_text
    from .verdicts import choices_text

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
    misses = causes_text(table.get("misses") or {})
    if misses:
        split += f"; {misses}"
    choices = choices_text(table.get("choices"))
    if choices:
        split += f"; {choices}"
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


def loop(records):
    """The experiment loop: its goals (:func:`.loop.loop_goals`), then per round the draws with
    the truth in the set and with the set closed, the draws whose menu can decide, and what an
    ``--add`` costs against a fresh run on the same recordings."""
    from .loop import MIN_DRAWS, loop_goals, summarise

    rows = records["bench_loop"]["rows"]
    table = summarise(rows)
    rounds = "; ".join(
        f"round {r['round']}: truth in the set {r['truth_in_set']} of {r['draws']} (its member "
        f"counted {r['truth_counted']}), closed "
        f"{r['closed']}, set sizes {r['set_sizes']} (counted members {r['counted_sizes']}) "
        f"against fit ceilings {r['ceiling_sizes']}"
        for r in table["rounds"])
    ratios = ", ".join(f"{k.replace('_', ' ')} {v['median']:.2f} [{v['max']:.2f}]"
                       for k, v in table["add_over_fresh"].items() if v["median"] is not None)
    return (f"{table['draws']} of {MIN_DRAWS} draws finished ({table['failed']} failed); "
            + _goals_text(loop_goals(table, len(rows))) + f"; {rounds}; the menu can decide in "
            f"{table['menu_can_decide']} draws, of which closed "
            f"{table['closed_where_menu_can_decide']} "
            f"({table['closed_counting_every_member']} with every member counted); an --add over "
            f"a fresh run, median [largest]: {ratios or 'no --add run in one piece'}")


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
