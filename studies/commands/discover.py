"""``tvcid discover``: structure and parameters from the user's own recordings, then MCMC.

Screening (SINDy seeds), fitting every structure by closed- and open-loop simulation, ranking by
two-fold out-of-sample error (:class:`discovery.structure.StructureDiscovery`), then the MCMC
calibration of the winner on all recordings (:class:`discovery.calibration.Calibration`); where
the recordings leave several structures, the test that would tell them apart (:func:`next_test`).
Nothing is lost to a killed run: ``discovery.json`` is written as soon as the ranking is done and
carries a hash of the inputs, so a rerun with the same recordings and options reuses it instead of
searching again, and the chain is checkpointed, so the MCMC resumes where it stopped. Writes
``DIR/discovery.json`` and ``DIR/report.md`` with the figures beside them.
"""
from __future__ import annotations

import hashlib
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np

from ._common import parse_assignments

#: Parameters the MCMC samples when the winner has them (the linear block stays at its fit).
CALIBRATED = ("dead_zone", "friction_offset", "backlash", "delay")


def register(sub):
    p = sub.add_parser(
        "discover",
        help="discover the actuator's structure and parameters from recordings, then calibrate",
        description="Fit every structure of the model's grammar (dead zone on the error or the "
        "velocity signal; delay at the output, before the integrator or before the first "
        "integrator; friction offset, backlash, band-pass loop on/off) to all recordings by "
        "simulation, rank them by two-fold out-of-sample error, report the structures the data "
        "cannot tell apart, and calibrate the winner with MCMC. Sidecars need only kind (and kp, "
        "kd, mu, controller_rate in closed loop); hypothesis/parameters keys are ignored.",
    )
    p.add_argument("files", nargs="+", metavar="FILE.csv", help="recordings (CSV + JSON sidecar)")
    p.add_argument("--fix", action="append", default=[], metavar="KEY=VALUE",
                   help="a known parameter or structural choice, used in every structure "
                   "(repeatable), e.g. --fix gain=305500 --fix delay_position=output")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    p.add_argument("--quick", action="store_true",
                   help="a short chain (150 steps) after the default searches (tests, CI)")
    p.add_argument("--thorough", action="store_true",
                   help="larger searches (about 1.6x the default's time; the discovery benchmark "
                   "measures the default)")
    p.add_argument("--max-steps", type=int, default=None, help="MCMC step cap (default 2000, quick 150)")
    p.add_argument("--no-mcmc", action="store_true", help="stop after the ranking")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(func=run)


def run(args) -> int:
    fixed = parse_assignments(args.fix)
    summary = discover(args.files, Path(args.out), fixed=fixed, seed=args.seed, quick=args.quick,
                       search="thorough" if args.thorough else "standard",
                       max_steps=args.max_steps, mcmc=not args.no_mcmc,
                       progress=not args.no_progress)
    best = summary["structures"][0]
    print(f"best: {best['structure']} (score {best['score']:.3g}, {best['criterion']})")
    same = [s["structure"] for s in summary["structures"][1:] if s["indistinguishable_from_best"]]
    if same:
        print("indistinguishable from it: " + ", ".join(same))
    post = summary.get("posterior")
    if post:
        for n, q in post["parameters"].items():
            print(f"  {n:<16s} {q['q50']:.4g}  90 % [{q['q05']:.4g}, {q['q95']:.4g}]")
        print(f"  converged: {post['converged']}")
    print(f"wrote {Path(args.out) / 'discovery.json'}, {Path(args.out) / 'report.md'}")
    return 0


def _corrected(recordings, offsets):
    """The recordings with their estimated sensor offset removed from ``delta``."""
    from models.recording import Recording

    out = []
    for r in recordings:
        name = r.path.stem if r.path else "recording"
        cols = dict(r.columns)
        cols["delta"] = r.delta - offsets.get(name, 0.0)
        out.append(Recording(columns=cols, meta=r.meta, path=r.path))
    return out


def discover(files, out: Path, fixed=None, seed=0, quick=False, max_steps=None, mcmc=True,
             progress=True, search="standard"):
    """Run the whole discovery on ``files`` into ``out``; returns the ``discovery.json`` content.

    ``search`` names the search sizes (:data:`discovery.structure.discover.SEARCHES`); ``quick``
    only shortens the chain.

    A finished ranking of the same inputs already in ``out`` is reused (``resumed_ranking``), and
    an interrupted chain resumes from its checkpoint.
    """
    from discovery.structure import validate_recordings
    from discovery.structure.targets import make_target
    from models import params_from_dict
    from models.structures import Structure, shared_choices

    recs = validate_recordings(files)
    out.mkdir(parents=True, exist_ok=True)
    inputs = inputs_hash(recs, fixed, seed, search)
    previous = _previous_ranking(out, inputs)
    if previous is not None:
        summary = previous
        summary["resumed_ranking"] = True
        best_params = params_from_dict("custom", summary["structures"][0]["params"])
        best_structure = Structure.parse(summary["structures"][0]["structure"])
        closed = [make_target(r, 5e-4) for r in recs if r.kind == "closed"][:1]
        offsets = summary["sensor_offset"]
        t_disc = summary["timings"].get("discovery", 0.0)
        summary.setdefault("decided", shared_choices(summary["indistinguishable"]))
    else:
        summary, best_params, best_structure, closed, offsets, t_disc = _rank_structures(
            recs, fixed, seed, search, progress, inputs)
        _write(out, summary)  # the ranking survives whatever happens to the chain
    if "next_test" not in summary:
        t0 = time.perf_counter()
        summary["next_test"] = next_test(summary, recs, seed, out)
        summary["timings"]["next_test"] = time.perf_counter() - t0
        _write(out, summary)
    if mcmc:
        summary = _calibrate(summary, recs, best_params, best_structure, closed, offsets, fixed,
                             seed, quick, max_steps, progress, out)
    summary["timings"]["discovery"] = t_disc
    _write(out, summary)
    return summary


def next_test(summary, recs, seed, out):
    """The test that would tell apart the structures the recordings cannot
    (:func:`discovery.structure.discrimination.discriminating_tests` on the set's unmerged
    members at their fitted parameters, refitted to the recordings for the best
    candidates; the default menu acquired at the recordings' highest rate, the recordings'
    median noise); writes ``next_test.png``. ``None`` for a set of one."""
    from discovery.structure.discrimination import default_candidates, discriminating_tests
    from discovery.structure.targets import make_target
    from models import params_from_dict

    members = [params_from_dict("custom", s["params"]) for s in summary["structures"]
               if s["indistinguishable_from_best"] and s["merged_into"] is None]
    if len(members) < 2:
        return None
    noises = [float(v) for v in summary["sensor_noise"].values()
              if isinstance(v, (int, float)) and math.isfinite(v) and v > 0]
    if not noises:  # noise-free recordings: the code's own tolerance sets the units
        noises = [1e-6]
    noise = float(np.median(noises))
    rate = max(r.sample_rate for r in recs)
    recorded = [make_target(r, 5e-4) for r in recs]  # the targets ignore a constant offset
    ranking = discriminating_tests(members, default_candidates(rate), noise_sd=noise, seed=seed,
                                   recorded=recorded)
    from ..common import pyplot

    plt = pyplot()
    ax = ranking.plot()
    ax.figure.tight_layout()
    ax.figure.savefig(out / "next_test.png", dpi=90)
    plt.close(ax.figure)
    result = ranking.to_dict()
    result["tests"] = result["tests"][:8]  # the best few; the figure shows twelve
    return result


def inputs_hash(recs, fixed, seed, search) -> str:
    """Hash of what determines the ranking: every recording's data and sidecar, the options."""
    h = hashlib.sha256()
    for r in recs:
        for name in sorted(r.columns):
            h.update(name.encode())
            h.update(np.ascontiguousarray(r.columns[name], dtype=float).tobytes())
        h.update(json.dumps(r.meta, sort_keys=True, default=str).encode())
    h.update(json.dumps([{k: getattr(v, "value", v) for k, v in (fixed or {}).items()}, seed,
                         str(search)], sort_keys=True, default=str).encode())
    return h.hexdigest()


def _previous_ranking(out, inputs):
    """A finished ranking of the same inputs in ``out``, or ``None``."""
    path = out / "discovery.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if summary.get("inputs") != inputs or not summary.get("structures"):
        return None
    return summary


def _rank_structures(recs, fixed, seed, search, progress, inputs):
    from discovery.structure import StructureDiscovery

    t0 = time.perf_counter()
    disc = StructureDiscovery(fixed=fixed, seed=seed, search=search, progress=progress).fit(recs)
    t_disc = time.perf_counter() - t0
    summary = {
        "recordings": [str(r.path) for r in recs],
        "targets": [t.describe() for t in disc.targets_],
        "fixed": {k: (v if not hasattr(v, "value") else v.value) for k, v in (fixed or {}).items()},
        "structures": [f.to_dict() for f in disc.ranking_],
        "indistinguishable": [f.structure.name for f in disc.indistinguishable_],
        "decided": disc.decided_,
        "pruned": disc.pruned_,
        "sindy": disc.sindy_,
        "sensor_offset": disc.offsets_,
        "sensor_noise": disc.noise_,
        "estimated": {"sensor_offset": "per recording, profiled (least squares) at the best fit",
                      "sensor_noise": "open loop: rms output error at the best fit; closed loop: "
                                      "second differences"},
        "simulations": disc.n_simulations_,
        "searches": dict(disc.searches_),
        "timings": {**disc.timings_},
        "seed": seed,
        "search": search,
        "inputs": inputs,
        "resumed_ranking": False,
    }
    summary["timings"]["discovery"] = t_disc
    closed = [t for t in disc.targets_ if t.kind == "closed"]
    return summary, disc.best_.params, disc.best_.structure, closed, disc.offsets_, t_disc


def _calibrate(summary, recs, best_params, best_structure, closed, offsets, fixed, seed, quick,
               max_steps, progress, out):
    """MCMC of the winner on all recordings (offsets removed), checkpointed; adds ``posterior``."""
    from discovery.calibration import Calibration
    from discovery.calibration.priors import Uniform
    from discovery.calibration.runner import ConvergenceWarning

    t0 = time.perf_counter()
    # start the closed-loop runs on the first record's cycle (at rest the loop stays there)
    p = best_params.replace(**closed[0].initial_conditions(best_params)) if closed else best_params
    names = [n for n in CALIBRATED
             if n in best_structure.parameter_names() and n not in (fixed or {})]
    c = p.dead_zone - p.friction_offset
    priors, start = {}, {}
    if "delay" in names:
        priors["delay"] = Uniform(1.2e-3 if p.delay > 1.2e-3 else 6e-4, max(3 * p.delay, 0.01))
        start["delay"] = min(max(p.delay, priors["delay"].low * 1.05), priors["delay"].high * 0.95)
    if "friction_offset" in names:
        priors["friction_offset"] = Uniform(-1.5 * c, 0.3 * c)
    # sigma is not sampled: the records' own noise estimate sets it. Sampled, it mixed 5x slower
    # than the physical parameters (tau 40 against 6-9 on the M000 records), so the chain ran to
    # the 2000-step cap (13 min); without it the same chain converges in 100-110 steps (112 s).
    # A misfit beyond the noise is the discrepancy factor's business, not sigma's.
    sampled = tuple(names) or ("sigma",)
    tag = hashlib.sha256(json.dumps([summary["structures"][0]["params"], sampled, "sigma fixed"
                                     if "sigma" not in sampled else "", quick, seed],
                                    sort_keys=True, default=str).encode()).hexdigest()[:10]
    steps = max_steps or (150 if quick else 2000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        cal = Calibration(p, params=sampled, priors=priors, start=start,
                          likelihood="features", window=10.0, n_walkers=max(16, 4 * len(names) + 4),
                          max_steps=steps, seed=seed, backend=out / f"chain-{tag}.h5",
                          progress=progress, global_search=False).fit(_corrected(recs, offsets))
    post = cal.posterior_
    s = post.summary()
    summary["posterior"] = {k: s[k] for k in ("parameters", "converged", "tau", "correlation",
                                             "iterations", "acceptance", "n_over_tau")}
    summary["posterior"]["structure"] = best_structure.name
    summary["posterior"]["chain"] = f"chain-{tag}.h5"
    summary["timings"]["mcmc"] = time.perf_counter() - t0
    from ..common import write_posterior_figures

    write_posterior_figures(post, out, seed=seed)
    return summary


def _write(out, summary):
    (out / "discovery.json").write_text(json.dumps(summary, indent=2, default=_json_default))
    (out / "report.md").write_text(report(summary))


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    if hasattr(v, "value"):
        return v.value
    return str(v)


CHOICE_LABELS = {"dead_zone_position": "dead zone on", "delay_position": "delay position",
                 "friction": "friction offset", "backlash": "backlash", "bandpass": "band-pass loop"}


def _shown(value):
    return value if isinstance(value, str) else ("on" if value else "off")


def _next_test_lines(nt):
    """The report's section on the test that would tell the set's structures apart."""
    if not nt:
        return []
    lines = ["", "## A test that would decide", "",
             f"The {len(nt['members'])} structures the recordings cannot tell apart, "
             f"{', '.join(f'`{m}`' for m in nt['members'])}, simulated through candidate tests "
             f"as the discovery would see them (sensor noise {nt['noise_sd']:.2g} rad). A pair is "
             f"decided when the cost one would add on the new recording if the other were the "
             f"truth is at least {nt['decides']:g} (the margin's floor is 0.1 a recording). The "
             "whole menu is compared at the fitted parameters; the best candidates again with "
             "every member refitted to all the recordings and the other's record of the test "
             "(what a rerun would do: a refit absorbs most of a difference at fixed parameters).",
             ""]
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
                     f"{t['closest_separation']:.3g} |")
    return lines + ["", "![next test](next_test.png)", ""]


def report(summary) -> str:
    """``report.md``: ranking table, what was fixed or estimated, posterior and figures."""
    lines = ["# tvcid discover", "", "Recordings: " + ", ".join(summary["recordings"]), ""]
    lines += ["## Ranking", "",
              f"Criterion: {summary['structures'][0]['criterion']}. Indistinguishable: score within "
              "twice the standard error of the difference from the best (from the disagreement of "
              "the two folds; at least 0.1 per recording); a structure that only adds a component "
              "to one of those without beating it by that margin is merged into it.", "",
              "| rank | structure | score | in-sample cost | indistinguishable | merged into |",
              "|---|---|---|---|---|---|"]
    for i, s in enumerate(summary["structures"], 1):
        lines.append(f"| {i} | `{s['structure']}` | {s['score']:.4g} | {s['cost']:.4g} | "
                     f"{'yes' if s['indistinguishable_from_best'] else ''} | {s['merged_into'] or ''} |")
    lines += ["", "## What the recordings decide", "",
              "Each structural choice, over the structures the recordings cannot tell apart "
              "(the indistinguishable ones, merged ones included):", ""]
    members = [s for s in summary["structures"] if s["indistinguishable_from_best"]]
    for choice, value in summary["decided"].items():
        label = CHOICE_LABELS[choice]
        if value is None:
            seen = sorted({_shown(m["components"][choice]) for m in members})
            lines.append(f"- {label}: **not decided** ({' or '.join(seen)})")
        else:
            lines.append(f"- {label}: decided, {_shown(value)}")
    if all(v is None for v in summary["decided"].values()):
        lines += ["", "The recordings decide no structural choice."]
    lines += _next_test_lines(summary.get("next_test"))
    best = summary["structures"][0]
    lines += ["", "## Best structure's parameters", "", "| parameter | value | local spread (coordinate) |",
              "|---|---|---|"]
    for k, v in best["params"].items():
        lines.append(f"| {k} | {v} | |")
    for k, v in best["coordinate_sd"].items():
        lines.append(f"| ({k}) | | {v:.3g} |")
    lines += ["", "## Fixed and estimated", "",
              "Fixed: " + (", ".join(f"{k} = {v}" for k, v in summary["fixed"].items()) or "nothing"), ""]
    for name, off in summary["sensor_offset"].items():
        lines.append(f"- {name}: sensor offset {off:.3g} rad, noise sd {summary['sensor_noise'][name]:.3g} rad")
    lines += ["", f"Estimated: {summary['estimated']['sensor_offset']}; noise: "
              f"{summary['estimated']['sensor_noise']}.", ""]
    if summary.get("pruned"):
        lines += ["Pruned structures: " + "; ".join(f"`{k}`: {v}" for k, v in summary["pruned"].items()), ""]
    post = summary.get("posterior")
    if post:
        lines += ["## MCMC calibration of the best structure", "",
                  f"Converged: {post['converged']} ({post['iterations']} steps, acceptance "
                  f"{post['acceptance']:.2f}). Sampled: the winner's thresholds, friction offset and "
                  "delay; its linear block and band-pass loop stay at their fit, the sensor noise "
                  "sd at the records' noise estimate (second differences, rms over the records).", "",
                  "| parameter | median | 90 % interval |", "|---|---|---|"]
        for n, q in post["parameters"].items():
            lines.append(f"| {n} | {q['q50']:.4g} | [{q['q05']:.4g}, {q['q95']:.4g}] |")
        lines += ["", "![corner](corner.png)", "", "![posterior predictive](predictive.png)", "",
                  "![traces](traces.png)", ""]
    lines += ["## Time", "", f"Search sizes: {summary.get('search', 'standard')}.", "",
              ", ".join(f"{k} {v:.0f} s" for k, v in summary["timings"].items()
                        if isinstance(v, (int, float))), ""]
    return "\n".join(lines)

