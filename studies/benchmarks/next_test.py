"""Does the suggested test decide what the recordings could not? The next-test check.

``python -m tvcid.studies.benchmarks.next_test [--seeds 1004,1009,1010,1011,1016] [--out DIR]``

Hypothesis: where the discovery leaves several structures indistinguishable,
:func:`tvcid.discovery.prediction.discrimination.discriminating_tests` (the default menu, at the
recordings' highest rate and median estimated noise, the members refitted) predicts which pairs
of structures the best test of the menu would decide. Checked by running that test: it is
recorded from the draw's truth by the plain-Python reference path with the draw's own sensor,
and the discovery runs again on all the draw's recordings. A pair of the first set is decided in
fact when the second set keeps one of its two members and not the other
(:func:`pairs_decided_in_fact`). Deciding numbers: per draw, the set before and after (size,
truth inside, right winner), the pairs predicted decided against the pairs decided in fact, and
the pairs on which they agree.

The default seeds are the discovery benchmark's misses whose set holds the truth
(``studies/benchmarks/records/bench_discovery_quick.json``), sets of 6-10 structures drawn
within the generator's ``papers`` ranges. Each draw runs two discoveries with the benchmark's
quick settings (no SINDy seeds) and the suggestion's refits: about 5-20 minutes a draw on two
cores. Rows are written to ``DIR/bench.json`` as they finish, each with the commit of the code
that ran it (non-finite numbers as ``null``); a rerun keeps finished draws.

Goals: none (a hypothesis checked by its deciding numbers); the run ends by saying so
(:func:`tvcid.studies.benchmarks.goals.report`) and exits 0.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from tvcid.discovery.structure import StructureDiscovery
from tvcid.discovery.prediction.discrimination import default_candidates, discriminating_tests
from tvcid.models.strict_json import write_json

from ..common import code_commit
from .verdicts import set_verdict
from .goals import report as goal_report
from .scenarios import design_of, draw_scenario, record_added_test, write_recordings

DEFAULT_SEEDS = (1004, 1009, 1010, 1011, 1016)
#: The generator's ranges of those draws (the discovery benchmark's record's).
DRAW_RANGES = "papers"


def _set_of(disc, truth):
    """The discovery's set as this benchmark records it: ``set`` holds the unmerged members."""
    verdict = set_verdict(disc.ranking_, truth)
    verdict["set"] = verdict.pop("members")
    return {k: verdict[k] for k in ("winner", "set", "set_size", "truth_in_set", "truth_member",
                                    "right_winner")}


def pairs_decided_in_fact(first, second):
    """The pairs of the first set's members that the second discovery tells apart.

    ``first``: the first discovery's set, each structure's name -> the member it is merged into
    (itself for a member). ``second``: the names of every structure in the second set, merged
    ones too. A member is kept when the second set holds it or a structure the first set merged
    into it (a richer structure that was at its added components' zero, now needed); a pair is
    decided when one member is kept and the other is not.
    """
    members = [name for name, member in first.items() if member == name]
    kept = {first[name] for name in second if name in first}
    return [(a, b) for i, a in enumerate(members) for b in members[i + 1:]
            if (a in kept) != (b in kept)]


def run_draw(seed, out):
    """Discover, ask for the next test, record it from the truth, discover again."""
    scenario = draw_scenario(seed, ranges=DRAW_RANGES)
    truth = scenario.structure
    paths = write_recordings(scenario, out / f"draw{seed:03d}", reuse=True)
    t0 = time.perf_counter()
    disc = StructureDiscovery(seed=seed, use_sindy=False).fit(paths)
    before = _set_of(disc, truth)
    row = {"seed": seed, "structure": truth.name, "design": scenario.to_dict(), "before": before,
           "commit": code_commit()}
    members = [f.params for f in disc.indistinguishable_ if f.merged_into is None]
    names = [f.structure.name for f in disc.indistinguishable_ if f.merged_into is None]
    if len(members) < 2:
        row["suggestion"] = None
        row["seconds"] = time.perf_counter() - t0
        return row
    rate = max(r.rate for r in scenario.recordings)
    menu = {c.name: c for c in default_candidates(rate)}
    noise = float(np.median([v for v in disc.noise_.values() if v > 0]))
    ranking = discriminating_tests(members, list(menu.values()), noise_sd=noise, seed=seed,
                                   recorded=disc.targets_)
    best = ranking.best
    row["suggestion"] = {k: best[k] for k in ("name", "refitted", "pairs_decided",
                                              "pairs_decided_fixed", "undecided",
                                              "closest_separation", "separation")}
    row["suggestion"].update(n_pairs=ranking.n_pairs, noise_sd=noise,
                             seconds=time.perf_counter() - t0)
    # the suggested test recorded from the truth, beside the draw's recordings
    _, new_path = record_added_test(scenario, design_of(menu[best["name"]], rate),
                                    out / f"draw{seed:03d}_next")
    # the discovery again, on every recording with the new one
    disc2 = StructureDiscovery(seed=seed, use_sindy=False).fit(list(paths) + [new_path])
    after = _set_of(disc2, truth)
    first = {f.structure.name: f.merged_into or f.structure.name for f in disc.indistinguishable_}
    decided = pairs_decided_in_fact(first, [f.structure.name for f in disc2.indistinguishable_])
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    predicted_open = {tuple(sorted(u)) for u in best["undecided"]}
    agree = sum(((a, b) in decided) == (tuple(sorted((a, b))) not in predicted_open)
                for a, b in pairs)
    after.update(pairs_decided=len(decided), decided=[list(d) for d in decided],
                 pairs_agreeing_with_prediction=int(agree),
                 right_or_in_small_set=after["right_winner"]
                 or (after["truth_in_set"] and after["set_size"] <= 3))
    row["after"] = after
    row["seconds"] = time.perf_counter() - t0
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", default=",".join(map(str, DEFAULT_SEEDS)),
                        help="benchmark draws, comma separated")
    parser.add_argument("--out", default="results/bench_next_test", help="output directory")
    args = parser.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        parser.error(f"--seeds must be integers separated by commas (got {args.seeds!r})")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench.json"
    rows = json.loads(path.read_text())["rows"] if path.exists() else []
    rows = [r for r in rows if r["seed"] in seeds]
    for seed in seeds:
        if any(r["seed"] == seed for r in rows):
            continue
        rows.append(run_draw(seed, out))
        rows.sort(key=lambda r: r["seed"])
        write_json(path, {"rows": rows}, default=str)
    print(f"{'draw':>5s}  {'truth':45s}  set before -> after (truth in, right winner)  suggested "
          "test: pairs predicted decided (at fixed parameters), decided in fact, agreeing")
    for r in rows:
        b, s, a = r["before"], r.get("suggestion"), r.get("after")
        if s is None:
            print(f"{r['seed']:5d}  {r['structure']:45s}  {b['set_size']} (set of one)")
            continue
        print(f"{r['seed']:5d}  {r['structure']:45s}  {b['set_size']} -> {a['set_size']} "
              f"({a['truth_in_set']}, {a['right_winner']})  {s['name']}: {s['pairs_decided']} "
              f"({s['pairs_decided_fixed']}) of {s['n_pairs']}, {a['pairs_decided']}, "
              f"{a['pairs_agreeing_with_prediction']}")
    return goal_report([])


if __name__ == "__main__":
    sys.exit(main())
