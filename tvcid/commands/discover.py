"""``tvcid discover``: structure and parameters from the user's own recordings, then MCMC
(:func:`tvcid.pipeline.discover`)."""
from __future__ import annotations

from pathlib import Path

from ._common import parse_assignments


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
    p.add_argument("files", nargs="*", metavar="FILE.csv", help="recordings (CSV + JSON sidecar)")
    p.add_argument("--add", nargs="+", default=None, metavar="NEW.csv",
                   help="add these recordings to the earlier run in --out (the experiment loop: "
                   "every structure refitted from its earlier optimum, the set, its posterior "
                   "and the next test made again; the earlier --fix, --seed and search sizes "
                   "are kept)")
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
    from ..pipeline import add_recordings, discover

    fixed = parse_assignments(args.fix)
    if args.add is not None:
        if args.files:
            raise ValueError("--add takes the new recordings; the earlier ones are in --out's "
                             "discovery.json (give no FILE.csv)")
        result = add_recordings(args.add, Path(args.out), fixed=fixed, quick=args.quick,
                                max_steps=args.max_steps, mcmc=not args.no_mcmc,
                                progress=not args.no_progress)
    else:
        if not args.files:
            raise ValueError("no recording given (FILE.csv ..., or --add NEW.csv with an earlier "
                             "run in --out)")
        result = discover(args.files, Path(args.out), fixed=fixed, seed=args.seed, quick=args.quick,
                          search="thorough" if args.thorough else "standard",
                          max_steps=args.max_steps, mcmc=not args.no_mcmc,
                          progress=not args.no_progress)
    best = result.best
    print(f"best: {best['structure']} (score {best['score']:.4g}, {best['criterion']})")
    same = [s["structure"] for s in result.summary["structures"][1:] if s["indistinguishable_from_best"]]
    if same:
        print("indistinguishable from it: " + ", ".join(same))
    post = result.posterior
    if post:
        for n, q in post["parameters"].items():
            print(f"  {n:<16s} {q['q50']:.4g}  90 % [{q['q05']:.4g}, {q['q95']:.4g}]")
        print(f"  converged: {post['converged']}")
    print(f"wrote {Path(args.out) / 'discovery.json'}, {Path(args.out) / 'report.md'}")
    return 0
