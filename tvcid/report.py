"""``report.md`` of ``tvcid discover``: what a user opens first.

It starts with a one-screen summary (what the recordings decided, the structures left open, each
physical parameter with its unit and 90 % interval, the next test), then the details: the ranking,
the decided choices, the test that would decide, the parameters, what was fixed or estimated, the
posterior and its figures. Numbers are printed to 4 significant digits.
"""
from __future__ import annotations

import dataclasses
import math

from tvcid.discovery.members.set_posterior import (decided_absent, partly_present,
                                               printed_present_or_absent)
from tvcid.discovery.members.set_weights import shown_choice
from tvcid.discovery.structure.indistinguishable import DECIDING_SHARE
from tvcid.models.quantities import COMPONENT_QUANTITIES, QUANTITY_UNITS
from tvcid.models.hypotheses import parameter_unit
from tvcid.models.structures import Structure, prune_reason

__all__ = ["discovery_report", "summary_lines"]

#: Parameters the summary lists, in this order, when the winner has them.
PHYSICAL = ("dead_zone", "backlash", "delay", "friction_offset", "gain", "damping", "stiffness",
            "feedback_gain", "bandpass_gain")


def _convergence_line(members) -> str:
    """Whether every calibrated member's chain converged, and what to do where one did not (a
    member screened by its weight is not run to convergence, and said so in its own line)."""
    screened = [m for m in members if not m["converged"] and m["posterior"].get("screened")]
    late = [m for m in members if not m["converged"] and m not in screened]
    tail = ("" if not screened else " Screened by their weight, not run to convergence: "
            + ", ".join(f"`{m['structure']}`" for m in screened) + ".")
    if not late:
        from tvcid.discovery.calibration.importance import GOOD_K
        from tvcid.discovery.calibration.importance_stage import IMPORTANCE_TARGET_ESS

        rule = ("converged (a chain more than 50 autocorrelation times long, or importance "
                f"sampling with at least {IMPORTANCE_TARGET_ESS} effective points and Pareto k "
                f"under {GOOD_K}, or a finished nested run with as many)")
        return (f"Every calibrated structure's posterior {rule}." if not screened else
                f"Every other calibrated structure's posterior {rule}." + tail)
    def alone(m):
        move = m["posterior"].get("laplace_move")
        return ("; without the Laplace move, whose proposal would be "
                "accepted too rarely" if move is not None and move["share"] == 0.0 else "")

    def drift(m):
        d = m["posterior"].get("interval_drift")
        return (f"; its 90 % intervals differ between the chain's two halves by up to "
                f"{100 * d['largest']:.0f} % of their width (`{d['parameter']}`)" if d else "")

    which = ", ".join(f"`{m['structure']}` ({m['posterior']['iterations']} steps, "
                      f"{m['posterior']['n_over_tau']:.3g} autocorrelation times{alone(m)}"
                      f"{drift(m)})" for m in late)
    return (f"**Not converged**: {which}; 50 autocorrelation times are needed. Their intervals, "
            "and the combined ones, are not yet their posteriors': the same command with a larger "
            "`--max-steps` continues the chains." + tail)


def _chain_cell(m) -> str:
    """A member's chain in the summary's table: converged, screened by its weight, or stopped at
    its cap with how far its intervals still move."""
    post = m["posterior"]
    if m["converged"]:
        return _sampled_by(post)
    screened = post.get("screened")
    if screened:
        run = (f"{post.get('iterations', '?')} {post['sampler']} points"
               if post.get("sampler") in ("importance", "nested") else f"{screened['steps']} steps")
        return (f"screened: under {100 * screened['share']:.0f} % of the weight after {run} (at "
                f"most {100 * screened['upper_weight']:.1f} % allowing for its estimate's error), "
                "so not run further; its ranges are its short run's")
    d = post.get("interval_drift")
    moves = (f"; its intervals move by up to {100 * d['largest']:.0f} % of their width between the "
             "chain's halves" if d else "")
    return (f"**stopped at its cap** ({post.get('iterations', '?')} steps): its intervals are lower "
            f"bounds on the width{moves}")


def _sampled_by(post) -> str:
    """How a converged member was sampled: its chain, or importance or nested sampling with its
    diagnostic."""
    if post.get("sampler") == "nested":
        return (f"nested sampled: {post['iterations']} points, {post['n_over_tau']:.0f} effective, "
                f"Pareto k {post['pareto_k']:.2f}, log evidence {post['log_z']:.2f} ± "
                f"{post['log_z_se']:.2f}")
    if post.get("sampler") != "importance":
        return "converged"
    return (f"importance sampled: {post['iterations']} points in {post.get('rounds', '?')} "
            f"rounds, {post['n_over_tau']:.0f} effective, Pareto k {post['pareto_k']:.2f}")


def _num(value, digits=4) -> str:
    """``value`` to ``digits`` significant digits; ``-`` for a missing or non-finite number."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}g}"


def _allowed_text(q) -> str:
    """The range the recordings allow, from its lower end to its upper end. An end the prior
    sets is named as the prior's floor or ceiling, with its value; one where a chain's draws end
    before the profile falls is a bound at least that far out."""
    lo, hi = q["allowed"]
    low_open, high_open = q.get("allowed_open") or (False, False)
    low_prior, high_prior = q.get("allowed_at_prior") or (low_open, high_open)
    prior = q.get("prior_range") or (None, None)
    if low_prior and high_prior:
        return "they allow the prior's whole range" + (
            f" ({_num(prior[0])} to {_num(prior[1])})" if None not in prior else "")
    low = (f"the prior's floor{'' if prior[0] is None else ' (' + _num(prior[0]) + ')'}" if low_prior
           else f"{_num(lo)} or below (where the draws end)" if low_open else _num(lo))
    high = (f"the prior's ceiling{'' if prior[1] is None else ' (' + _num(prior[1]) + ')'}" if high_prior
            else f"{_num(hi)} or above (where the draws end)" if high_open else _num(hi))
    return f"they allow {low} to {high}"


def _verdict(q, capped=False) -> str:
    """What a combined quantity's row says beside its interval; ``capped``: members holding
    weight stopped at their step cap, so a quantity they agree on is not called decided (their
    intervals are lower bounds on the width, and the agreement may be the chains')."""
    if q["q05"] == q["q95"] and not q.get("widened"):
        return "fixed"
    parts = []
    if q["depends_on_structure"]:
        parts.append("depends on the structure")
    if q.get("pinned") is False:
        parts.append("not pinned by the recordings")
    elif (q["members"] > 1 and not q["depends_on_structure"] and q.get("pinned")
          and not printed_present_or_absent(q) and not decided_absent(q)):
        parts.append("the members agree, but their chains stopped at the cap: not yet decided"
                     if capped else "decided regardless of the structure")
    # a component left open always shows the range its richer members allow
    if q.get("allowed") and (q.get("pinned") is False or printed_present_or_absent(q)):
        parts.append(_allowed_text(q))
    if q.get("widened"):
        error = _num(q.get("step_error_widened") or q["step_error"], 2)
        parts.append(f"widened to the step error, +-{error}" if q["members"] == 1 else
                     f"members widened to their step errors (up to +-{error})")
    return "; ".join(parts)


def _weighting(sp) -> str:
    """How the members are weighted, in a phrase (the rule in full is ``criterion``)."""
    w = sp.get("weighting") or {}
    method = w.get("method")
    if method == "evidence":
        return "weighted by their posterior probabilities (each one's evidence)"
    if method == "held-out scores":
        return ("weighted by each one's probability of the lowest expected held-out score (no "
                "member's evidence could be estimated)")
    if method == "equal":
        return "with equal weights (neither the evidence nor the scores weigh them)"
    return sp["criterion"]


def _quantity_row(name, q, capped=False) -> str:
    """One row of the summary's table; a component the weights leave open reads "present or
    absent" with its interval if present, one they decide absent reads "absent" (``capped``:
    :func:`_verdict`'s)."""
    interval = f"[{_num(q['q05'])}, {_num(q['q95'])}]"
    if partly_present(q):
        return (f"| {name} | present or absent ({100 * q['present']:.0f} % of the weight present) | "
                f"if present, {interval} | {q['unit']} | {_verdict(q, capped)} |")
    if q.get("left_open") == "weight not final":
        return (f"| {name} | present or absent ({100 * q['present']:.1f} % of the weight present; "
                f"a member under {100 * DECIDING_SHARE:.0f} % stopped at its cap, has an "
                f"unreliable evidence or a weight the step does not resolve, so its weight is "
                f"not final) | if present, {interval} | "
                f"{q['unit']} | {_verdict(q, capped)} |")
    if q.get("left_open"):  # the members without it could not be calibrated
        return (f"| {name} | present or absent (the set leaves it open; only members with it "
                f"calibrated) | if present, {interval} | {q['unit']} | {_verdict(q, capped)} |")
    if decided_absent(q):
        return (f"| {name} | absent (the members with it hold {100 * q['present']:.1f} % of the "
                f"weight) | if present, {interval} | {q['unit']} | {_verdict(q, capped)} |")
    present = ("" if q.get("present", 1.0) >= 1.0 - 1e-9 else
               f"present ({100 * q['present']:.0f} % of the weight); ")
    return f"| {name} | {_num(q['q50'])} | {interval} | {q['unit']} | {present}{_verdict(q, capped)} |"


#: An equal-weight interval is printed beside the weighted one when an end moves by more than
#: this fraction of the weighted interval's width.
EQUAL_DIFFERS = 0.1


def _equal_weight_lines(sp) -> list:
    """The quantities whose equal-weight interval differs from the weighted one, both printed."""
    rows = []
    for name, q in sp["quantities"].items():
        e = q.get("equal_weights") or {}
        if None in (e.get("q05"), e.get("q95"), q.get("q05"), q.get("q95")):
            continue
        width = q["q95"] - q["q05"]
        if max(abs(e["q05"] - q["q05"]), abs(e["q95"] - q["q95"])) > EQUAL_DIFFERS * max(width, 0):
            rows.append(f"{name} [{_num(e['q05'])}, {_num(e['q95'])}] {q['unit']} (by weight "
                        f"[{_num(q['q05'])}, {_num(q['q95'])}])")
    if not rows:
        return []
    return ["", "With equal weights instead (1/n each, whatever the evidence): " + "; ".join(rows)
            + "."]


def _members_lines(sp) -> list:
    """The set's weighting, the members left out, the capped chains and the prior bounds."""
    lines = []
    dropped = sp.get("not_calibrated") or []
    if dropped:
        share = sp.get("not_calibrated_share")
        why = sp.get("calibrated_because") or {}
        if why and sp.get("distinct_members"):
            lines += ["", f"The recordings leave {sp['distinct_members']} distinct structures "
                      "open, more than the cap calibrates; calibrated: " + "; ".join(
                          f"`{n}` ({reason})" for n, reason in why.items()) + "."]
        lines += ["", "Not calibrated (more structures than the cap): " + ", ".join(
            f"`{n}`" for n in dropped) + (f", about {100 * share:.0f} % of the weight by their "
                                          "held-out scores (the table's intervals leave them out)."
                                          if share is not None else ".")]
    failed = sp.get("failed") or []
    if failed:
        lines += ["", "Could not be calibrated, and left out of the combined posterior: " + "; ".join(
            f"`{f['structure']}` ({f['reason']}: about its fit some recording's run fails or "
            "shows no cycle the likelihood can compare)" for f in failed) + "."]
    unresolved = [m for m in sp["members"]
                  if (m["posterior"].get("step_error") or {}).get("resolved") is False]
    if unresolved:
        lines += ["", "Not resolved by the integration step: " + "; ".join(
            f"`{m['structure']}` (halving the step changes its log posterior by "
            f"{m['posterior']['step_error']['residual_sd']:.3g} nats rms beyond a shift, more than "
            f"its draws' own spread, {m['posterior']['step_error']['log_prob_sd']:.3g})"
            for m in unresolved) + ": the half step reorders its draws rather than moving them, "
            "and its step errors, which widen its own intervals only, hold that noise."]
    lines += _pinned_lines(sp["members"])
    bounds = [(m["structure"], m["posterior"].get("at_prior_bound") or [])
              for m in sp["members"]]
    bounds = [(s, b) for s, b in bounds if b]
    if bounds:
        lines += ["", "At a prior bound (a tenth of the draws or more within a tenth of the prior "
                  "from it): " + "; ".join(f"`{s}`: {', '.join(b)}" for s, b in bounds) + "."]
    return lines


def _pinned_lines(members) -> list:
    """Per member holding at least the deciding share of the weight (every member where there
    are no weights), the combinations of parameters its draws pin beyond any one parameter and
    how many directions they leave free (:mod:`tvcid.discovery.calibration.pinned`), one line
    each; the members under that share are named, their combinations left to
    ``discovery.json``."""
    rows, figures, light = [], [], []
    for m in members:
        pm = m["posterior"].get("pinned")
        if not pm:
            continue
        combos = [c["text"] for c in pm["pinned"] if len(c["terms"]) > 1]
        weight = m.get("weight")
        if combos and weight is not None and weight < DECIDING_SHARE:
            light.append(f"`{m['structure']}`")
            continue
        if combos:
            held = "" if weight is None else f" ({100 * weight:.0f} % of the weight)"
            rows.append(f"- `{m['structure']}`{held}: " + "; ".join(combos)
                        + f"; {pm['free']} direction(s) free within the prior")
        if m["posterior"].get("pinned_figure"):
            figures.append(f"![pinned, {m['structure']}]({m['posterior']['pinned_figure']})")
    if not rows and not light:
        return []
    lines = ["", "Pinned together (directions of the draws that join several parameters and "
             "spread under a tenth of the prior's sd, in the coordinates the prior is flat in):",
             "", *rows]
    if light:
        lines += ["", f"Under {100 * DECIDING_SHARE:.0f} % of the weight, their combinations in "
                  "`discovery.json` (`set_posterior.members[].posterior.pinned`): "
                  + ", ".join(light) + "."]
    return lines + (["", *figures] if figures else [])


def summary_lines(summary) -> list:
    """The report's first screen: verdict, open structures, parameters with units, next test."""
    best = summary["structures"][0]
    members = [s for s in summary["structures"] if s["indistinguishable_from_best"]]
    distinct = [s for s in members if s["merged_into"] is None]
    lines = ["## Summary", ""]
    if len(distinct) <= 1:
        lines.append(f"The recordings name one structure: `{best['structure']}`.")
    else:
        lines.append(f"The recordings leave {len(distinct)} structures open; best `{best['structure']}`, "
                     "also " + ", ".join(f"`{s['structure']}`" for s in distinct[1:]) + ".")
    lines.append(_decided_line(summary, best))
    combined = (summary.get("set_posterior") or {}).get("quantities")
    if combined:
        sp = summary["set_posterior"]
        n = len(sp["members"])
        lines += ["", (f"Over the set's {n} calibrated structures, {_weighting(sp)}:"
                       if n > 1 else "The calibrated structure's posterior:"), "",
                  "| quantity | median | 90 % interval | unit | |", "|---|---|---|---|---|"]
        # weight on chains stopped at their cap (a member screened by its weight holds little)
        capped = sum(m.get("weight", 1.0 / n) for m in sp["members"]
                     if not m["converged"] and not m["posterior"].get("screened")) > DECIDING_SHARE
        lines += [_quantity_row(name, q, capped) for name, q in combined.items()]
        lines += [f"| {name} | present or absent (the set leaves it open; no member with it "
                  f"calibrated) | | {QUANTITY_UNITS.get(name, '')} | |"
                  for name in sp.get("left_open_uncalibrated") or ()]
        if any(q.get("pinned") is False for q in combined.values()):
            lines += ["", "Not pinned: the 90 % interval spans more than half the one the priors "
                      "imply, so it follows where the prior puts its mass; the range the "
                      "recordings allow is where the profile log posterior stays within 1.92 nats "
                      "of the best."]
        lines += _equal_weight_lines(sp) if n > 1 else []
        if n > 1 or not all(m["converged"] for m in sp["members"]):
            held = (sp.get("weighting") or {}).get("held_out") or {}
            lines += ["", "| structure | weight | by held-out score | equal weight | chain |",
                      "|---|---|---|---|---|"]
            lines += [f"| `{m['structure']}` | {m.get('weight', 1 / n):.2f} | "
                      f"{_num(held.get(m['structure']), 2)} | {m.get('equal_weight', 1 / n):.2f} | "
                      f"{_chain_cell(m)} |" for m in sp["members"]]
        lines += _members_lines(sp)
        lines += ["", _convergence_line(sp["members"])]
    else:
        lines += ["", "| parameter | value | 90 % interval | unit | from |", "|---|---|---|---|---|"]
        post = summary.get("posterior") or {}
        sampled = post.get("parameters", {})
        position = best["params"].get("dead_zone_position", "error")
        for name in PHYSICAL:
            if name not in best["params"]:
                continue
            unit = parameter_unit(name, position)
            if name in sampled:
                q = sampled[name]
                lines.append(f"| {name} | {_num(q['q50'])} | [{_num(q['q05'])}, {_num(q['q95'])}] | "
                             f"{unit} | MCMC of the best structure |")
            else:
                lines.append(f"| {name} | {_num(best['params'][name])} | not sampled | {unit} | "
                             "fit of the best structure |")
        if (summary.get("set_posterior") or {}).get("failed"):
            lines += _members_lines(summary["set_posterior"])
    return lines + ["", _next_test_headline(summary.get("next_test"), len(distinct)), ""]


def _decided_line(summary, best) -> str:
    """What the set and the weights decide, and what they leave open with each side's share:
    one rule (:func:`tvcid.discovery.members.set_weights.weighed_choices`) for this line and the
    table's "present or absent"."""
    choices = (summary.get("set_posterior") or {}).get("choices")
    if not choices:  # no calibration: the set's structures alone
        choices = {c: {"value": None if v is None else shown_choice(v), "by": "set" if v is not None
                       else "open", "weights": {}} for c, v in summary["decided"].items()}
    decided, open_, not_final = [], [], False
    for c, v in choices.items():
        if v["by"] == "set":
            raw = summary["decided"][c]
            decided.append(f"{CHOICE_LABELS[c]} {v['value']}{_structural(best['structure'], c, raw)}")
        elif v["by"] == "weights":
            decided.append(f"{CHOICE_LABELS[c]} {v['value']} ({100 * v['weights'][v['value']]:.0f} % "
                           "of the weight)")
        else:
            seen = v["weights"] or {s: None for s in _seen(summary, c)}
            # the largest share first, the values without a weight last
            seen = dict(sorted(seen.items(), key=lambda kv: (kv[1] is None, -(kv[1] or 0.0))))
            unsure = {u for u in v.get("unsure") or ()
                      if seen.get(u) is not None and seen[u] < DECIDING_SHARE}
            not_final = not_final or bool(unsure)
            open_.append(f"{CHOICE_LABELS[c]} " + " or ".join(
                f"{value} ({'uncalibrated' if w is None else _share(w)}"
                f"{', weight not final' if value in unsure else ''})"
                if v["weights"] else value for value, w in seen.items()))
    return ("Decided: " + (", ".join(decided) or "no structural choice") + ". Not decided: "
            + ("; ".join(open_) or "nothing") + "."
            + (" A weight not final is a member's whose chain stopped at its cap, whose "
               "evidence is unreliable, or whose weight halving the simulation step would lift "
               "over the share: the data do not yet decide against it." if not_final
               else ""))


def _share(w) -> str:
    """A share of the weight as a percentage, to one decimal under the deciding share."""
    return f"{100 * w:.1f} %" if w < DECIDING_SHARE else f"{100 * w:.0f} %"


def _seen(summary, choice) -> list:
    """The values the set's structures take for ``choice``, as shown."""
    members = [s for s in summary["structures"] if s["indistinguishable_from_best"]]
    return sorted({shown_choice(Structure.parse(m["structure"]).to_dict()[choice]) for m in members})


def _next_test_headline(nt, n_distinct) -> str:
    """The summary's line on the next test (``nt``: the summary's ``next_test``); where no
    candidate ran, the reasons the best structure gave."""
    if not nt:
        return ("Next test: none needed (one structure left)." if n_distinct <= 1
                else "Next test: not computed.")
    if nt.get("left_out") and len(nt["members"]) < 2:
        return (f"Next test: none needed: the weights leave one structure, `{nt['members'][0]}` "
                f"(the others hold under 5 % of the weight).")
    if nt.get("best") is None:
        reasons = sorted({t["skipped"] for t in nt["tests"] if "skipped" in t})
        return f"Next test: no candidate of the menu could be simulated ({'; '.join(reasons)})."
    if nt["best"]["pairs_decided"] == 0:
        return "Next test: no candidate of the menu decides any pair (see below)."
    return (f"Next test: **{nt['best']['name']}**, deciding {nt['best']['pairs_decided']} "
            f"of {nt['n_pairs']} pairs.")


CHOICE_LABELS = {"dead_zone_position": "dead zone on", "delay_position": "delay position",
                 "friction": "friction offset", "backlash": "backlash", "bandpass": "band-pass loop"}


def _structural(structure, choice, value) -> str:
    """Where a component decided off could not be on with the choices the set shares (a friction
    offset beside a dead zone on the error), the rule that decides it, not the data."""
    if value is not False or choice not in COMPONENT_QUANTITIES:
        return ""
    reason = prune_reason(dataclasses.replace(Structure.parse(structure), **{choice: True}))
    return "" if reason is None else f" (not by the data: {reason.split(':')[0]})"


def _next_test_lines(nt):
    """The report's section on the test that would tell the set's structures apart."""
    if not nt or len(nt.get("members") or ()) < 2:
        return []
    lines = ["", "## A test that would decide", "",
             f"The {len(nt['members'])} structures the recordings cannot tell apart, "
             f"{', '.join(f'`{m}`' for m in nt['members'])}, simulated through candidate tests "
             f"as the discovery would see them (sensor noise {nt['noise_sd']:.2g} rad). A pair is "
             f"decided when the cost one would add on the new recording if the other were the "
             f"truth is at least {nt['decides']:g} (the margin's floor is 0.1 a recording). The "
             "whole menu is compared at the fitted parameters; the best candidates again with "
             "every member refitted to all the recordings and the other's record of the test "
             "(what a rerun would do: a refit absorbs most of a difference at fixed parameters)."
             + (" Left out, the weights having decided against them: " + ", ".join(
                 f"`{x['structure']}` ({100 * x['weight']:.1f} %)" for x in nt["left_out"]) + "."
                if nt.get("left_out") else ""), ""]
    best = nt.get("best")
    if best is None:
        return lines + ["No candidate test ran (the best structure shows no cycle at the candidate "
                        "controller settings).", ""]
    if best["pairs_decided"] == 0:
        lines += [f"**No candidate decides any pair**: refitted, these structures reproduce each "
                  f"other's responses to the best tests of the menu (closest to deciding: "
                  f"{best['name']}, {best['closest_separation']:.3g} for "
                  f"`{best['closest_pair'][0]}` against `{best['closest_pair'][1]}`). At this "
                  "noise they are one model for such tests; a lower-noise or faster test, or a "
                  "known part (`--fix`), is what could separate them.", ""]
    else:
        lines += [f"Best: **{best['name']}**, deciding {best['pairs_decided']} of {nt['n_pairs']} "
                  "pairs" + ("." if not best["undecided"] else "; still open: " + "; ".join(
                      f"`{a}` / `{b}`" for a, b in best["undecided"]) + "."), ""]
    lines += ["| test | pairs decided | at fixed parameters | closest pair's cost difference |",
              "|---|---|---|---|"]
    for t in nt["tests"]:
        if "skipped" in t:
            continue
        refit = f"{t['pairs_decided']} of {nt['n_pairs']}" if t.get("refitted") else "(not refitted)"
        lines.append(f"| {t['name']} | {refit} | {t['pairs_decided_fixed']} of {nt['n_pairs']} | "
                     f"{_num(t['closest_separation'])} |")
    return lines + ["", "![next test](next_test.png)", ""]


def _pruned_line(pruned) -> str:
    """The structures pruned before the search, grouped by their reason (one reason usually
    prunes a dozen)."""
    by_reason = {}
    for name, reason in pruned.items():
        by_reason.setdefault(reason, []).append(f"`{name}`")
    return "Pruned structures: " + "; ".join(f"{', '.join(names)}: {reason}"
                                            for reason, names in by_reason.items())


def member_table_lines(sp) -> list:
    """The report's table of each calibrated structure's quantities (median and 90 % interval),
    an interval its own step error widened marked ``(w)``."""
    names = list(sp["quantities"])
    lines = ["## Each calibrated structure", "",
             "Median and 90 % interval of each quantity, per structure of the set; the "
             "summary's combined intervals mix them by their weights. An interval marked "
             "(w) is widened to that structure's own step error.", "",
             "| structure | weight | converged | " + " | ".join(names) + " |",
             "|---|---|---|" + "---|" * len(names)]
    for m in sp["members"]:
        cells = []
        for n in names:
            q = m["quantities"].get(n)
            cells.append("" if q is None or q["q50"] is None else
                         f"{_num(q['q50'])} [{_num(q['q05'])}, {_num(q['q95'])}]"
                         + (" (w)" if q.get("widened") else ""))
        lines.append(f"| `{m['structure']}` | {m.get('weight', 1 / len(sp['members'])):.2f} | "
                     f"{m['converged']} | " + " | ".join(cells) + " |")
    return lines + [""]


def discovery_report(summary) -> str:
    """``report.md``: a one-screen summary, then the ranking table, what the recordings decide,
    the next test, the best structure's parameters, what was fixed or estimated, the posterior
    and the figures."""
    lines = ["# tvcid discover", ""] + summary_lines(summary)
    lines += ["## Recordings", "", ", ".join(summary["recordings"]), ""]
    lines += ["## Ranking", "",
              f"Criterion: {summary['structures'][0]['criterion']}. Indistinguishable: score within "
              "the margin of the best: the standard error of the difference (from the disagreement "
              "of the two folds; at least 0.05 per recording) times Student's t quantile for the "
              "degrees of freedom it has (2 where the floors set it, up to 14 where one "
              "recording's folds do); a structure that only adds a component to one of those "
              "without beating it by that margin is merged into it.", "",
              "| rank | structure | score | in-sample cost | indistinguishable | merged into |",
              "|---|---|---|---|---|---|"]
    for i, s in enumerate(summary["structures"], 1):
        lines.append(f"| {i} | `{s['structure']}` | {_num(s['score'])} | {_num(s['cost'])} | "
                     f"{'yes' if s['indistinguishable_from_best'] else ''} | {s['merged_into'] or ''} |")
    lines += ["", "## What the recordings decide", "",
              "Each structural choice, over the structures the recordings cannot tell apart "
              "(the indistinguishable ones, merged ones included):", ""]
    members = [s for s in summary["structures"] if s["indistinguishable_from_best"]]
    for choice, value in summary["decided"].items():
        label = CHOICE_LABELS[choice]
        if value is None:
            seen = sorted({shown_choice(m["components"][choice]) for m in members})
            lines.append(f"- {label}: **not decided** ({' or '.join(seen)})")
        else:
            lines.append(f"- {label}: decided, {shown_choice(value)}")
    if all(v is None for v in summary["decided"].values()):
        lines += ["", "The recordings decide no structural choice."]
    lines += _next_test_lines(summary.get("next_test"))
    best = summary["structures"][0]
    lines += ["", "## Best structure's parameters", "", "| parameter | value | local spread (coordinate) |",
              "|---|---|---|"]
    for k, v in best["params"].items():
        lines.append(f"| {k} | {_num(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v} | |")
    for k, v in best["coordinate_sd"].items():
        lines.append(f"| ({k}) | | {_num(v)} |")
    lines += ["", "## Fixed and estimated", "",
              "Fixed: " + (", ".join(f"{k} = {v}" for k, v in summary["fixed"].items()) or "nothing"), ""]
    for name, off in summary["sensor_offset"].items():
        lines.append(f"- {name}: sensor offset {off:.3g} rad, noise sd {summary['sensor_noise'][name]:.3g} rad")
    lines += ["", f"Estimated: {summary['estimated']['sensor_offset']}; noise: "
              f"{summary['estimated']['sensor_noise']}.", ""]
    if summary.get("pruned"):
        lines += [_pruned_line(summary["pruned"]), ""]
    post = summary.get("posterior")
    if post:
        lines += ["## MCMC calibration of the best structure", "",
                  (f"Sampled by {post['sampler']} sampling ({_sampled_by(post).split(': ', 1)[1]})."
                   if post.get("sampler") in ("importance", "nested") else
                   f"Converged: {post['converged']} ({post['iterations']} steps, acceptance "
                   f"{post['acceptance']:.2f}).") + " Sampled: every parameter of the winner's structure "
                  "but the fixed ones, the linear block included; the sensor noise sd stays at the "
                  "records' noise estimate (second differences, rms over the records).", "",
                  "| parameter | median | 90 % interval |", "|---|---|---|"]
        for n, q in post["parameters"].items():
            lines.append(f"| {n} | {_num(q['q50'])} | [{_num(q['q05'])}, {_num(q['q95'])}] |")
        lines += ["", "![corner](corner.png)", "", "![posterior predictive](predictive.png)", "",
                  "![traces](traces.png)", ""]
    sp = summary.get("set_posterior")
    if sp and len(sp["members"]) > 1:
        lines += member_table_lines(sp)
    lines += ["## Time", "", f"Search sizes: {summary.get('search', 'standard')}.", "",
              ", ".join(f"{k} {v:.0f} s" for k, v in summary["timings"].items()
                        if isinstance(v, (int, float))), ""]
    if summary.get("simulated_seconds"):
        lines += ["Simulated seconds (every run of every recording): "
                  + ", ".join(f"{k} {v:,.0f} s" for k, v in summary["simulated_seconds"].items()), ""]
    return "\n".join(lines)

