"""``tvcid discover``: structure and parameters from the user's own recordings, then MCMC
(:func:`tvcid.pipeline.discover`)."""
from __future__ import annotations

from pathlib import Path

from ._common import dask_address, parse_assignments


def register(sub):
    p = sub.add_parser(
        "discover",
        help="discover the actuator's structure and parameters from recordings, with the "
        "posterior over the structures they leave open",
        description="Fit every structure of the model's grammar (dead zone on the error or the "
        "velocity signal; delay at the output, before the integrator or before the first "
        "integrator; friction offset, backlash, band-pass loop on/off) to all recordings by "
        "simulation, rank them by two-fold out-of-sample error, report the set of structures the "
        "data cannot tell apart, calibrate each distinct member of that set with MCMC (best score "
        "first, up to a cap; the rest are named) and combine their posteriors. Prints what "
        "report.md's summary shows: the structural choices decided and open, and each physical "
        "quantity over the set (median, 90 % interval, unit, verdict); the winner's own "
        "posterior is a section of report.md. Sidecars need only kind (and kp, kd, mu, "
        "controller_rate in closed loop); hypothesis/parameters keys are ignored. The same "
        "command again resumes an interrupted run: the ranking is reused and every chain "
        "continues from its checkpoint.",
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
                   help="short chains (150 steps each) after the default searches (tests, CI)")
    p.add_argument("--thorough", action="store_true",
                   help="larger searches (about 1.6x the default's time; the discovery benchmark "
                   "measures the default)")
    p.add_argument("--max-steps", type=int, default=None,
                   help="MCMC step cap of each member's chain (default 2000, quick 150); the same "
                   "command with a larger cap continues the chains")
    p.add_argument("--no-mcmc", action="store_true",
                   help="stop after the ranking (no posterior; the summary shows the best fit)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--dask", metavar="ADDRESS", type=dask_address, default=None,
                   help="run the global searches and the members' chains on the Dask scheduler "
                   "at ADDRESS (tcp://HOST:8786), or on a local cluster of N one-thread "
                   "workers (local:N); the same result as without it; on a cluster, --out on a "
                   "file system the workers share; needs pip install tvcid[dask] "
                   "(docs/cluster.md)")
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
                                progress=not args.no_progress, dask=args.dask)
    else:
        if not args.files:
            raise ValueError("no recording given (FILE.csv ..., or --add NEW.csv with an earlier "
                             "run in --out)")
        result = discover(args.files, Path(args.out), fixed=fixed, seed=args.seed, quick=args.quick,
                          search="thorough" if args.thorough else "standard",
                          max_steps=args.max_steps, mcmc=not args.no_mcmc,
                          progress=not args.no_progress, dask=args.dask)
    print(console_summary(result, Path(args.out)))
    return 0


def console_summary(result, out) -> str:
    """What ``tvcid discover`` prints: ``report.md``'s summary without its heading
    (:func:`tvcid.report.summary_lines`: the choices decided and open, each quantity over the
    set), one line pointing to the winner's own posterior, and the files written.

    Parameters
    ----------
    result : tvcid.pipeline.DiscoveryResult
    out : str or Path
        The run's directory.

    Returns
    -------
    str
    """
    from ..report import summary_lines

    lines = summary_lines(result.to_dict())
    while lines and (not lines[0].strip() or lines[0].startswith("#")):
        lines.pop(0)
    while lines and not lines[-1].strip():
        lines.pop()
    report = Path(out) / "report.md"
    if result.posterior:
        lines += ["", f"The best structure's own posterior (`{result.best['structure']}`, one "
                  f"member of the set) is in {report}."]
    lines += [f"wrote {Path(out) / 'discovery.json'}, {report}"]
    return "\n".join(lines)
