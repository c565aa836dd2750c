"""``tvcid design``: rank candidate experiments by what they are expected to teach."""
from __future__ import annotations

from pathlib import Path


def register(sub):
    p = sub.add_parser(
        "design",
        help="rank candidate tests (controller settings, open-loop squares/sines) by expected "
        "information gain",
        description="Given a posterior (the --out directory of tvcid fit or tvcid discover) and a "
        "menu of candidate experiments (a JSON list of {\"kind\": \"closed\", \"kp\", \"kd\", "
        "\"mu\", ...} or {\"kind\": \"open\", \"waveform\": \"square\"|\"sine\"|\"step\", "
        "\"amplitude\", \"frequency\"}, each with optional name, duration (s) and sample_rate "
        "(Hz)), simulate the posterior draws through each candidate as a fit would see it and "
        "rank the candidates by expected information gain on --params, with the expected "
        "shrinkage of each parameter's 90 % width. On a discover directory whose set holds several "
        "structures, every member ranks the candidates with its own draws and the ranking puts "
        "first the tests that tell the members apart, then the members' mean gain. Writes "
        "DIR2/design.json and DIR2/design.png.",
    )
    p.add_argument("directory", metavar="DIR", help="output directory of tvcid fit or tvcid discover")
    p.add_argument("--candidates", required=True, metavar="FILE.json", help="menu of experiments")
    p.add_argument("--params", default=None, metavar="a,b",
                   help="parameters whose widths matter (default: every sampled one but sigma)")
    p.add_argument("--noise", type=float, default=None,
                   help="sensor-noise sd of the new tests, rad (default: the posterior's)")
    p.add_argument("--draws", type=int, default=300, help="posterior draws simulated")
    p.add_argument("--truths", type=int, default=24, help="hypothetical truths averaged per candidate")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, metavar="DIR2", help="output directory")
    p.set_defaults(func=run)


def run(args) -> int:
    from tvcid.discovery.prediction import load_set_draws
    from tvcid.discovery.prediction.design import load_candidates, rank_experiments
    from tvcid.discovery.prediction.discrimination import design_over_set
    from tvcid.models.strict_json import write_json

    candidates = load_candidates(args.candidates)
    params = [n.strip() for n in args.params.split(",") if n.strip()] if args.params else None
    if args.noise is not None and not args.noise > 0:
        raise ValueError(f"--noise must be > 0 (got {args.noise})")
    if args.draws < 10:
        raise ValueError(f"--draws must be >= 10 (got {args.draws})")
    if args.truths < 1:
        raise ValueError(f"--truths must be >= 1 (got {args.truths})")
    members = load_set_draws(args.directory, n_draws=args.draws, seed=args.seed)
    options = dict(params=params, noise=args.noise, seed=args.seed, n_truths=args.truths,
                   progress=not args.no_progress)
    if len(members) > 1:
        ranking = design_over_set(members, candidates, **options)
    else:
        ranking = rank_experiments(next(iter(members.values())), candidates, **options)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "design.json", ranking.to_dict())
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax = ranking.plot()
    ax.figure.tight_layout()
    ax.figure.savefig(out / "design.png", dpi=110)
    plt.close(ax.figure)
    if len(members) > 1:
        print(f"the set's {len(members)} structures: {', '.join(members)}")
    decides = "pairs_decided" in ranking.rows[0]
    print(f"{'rank':<5s}{'candidate':<34s}" + (f"{'pairs told apart':>18s}" if decides else "")
          + f"{'gain (nats)':>12s}  expected width ratio")
    for i, row in enumerate(ranking.rows, 1):
        ratios = ", ".join(f"{k} {v:.2f}" for k, v in row["shrinkage"].items())
        told = f"{row['pairs_decided']:>11d} of {row['n_pairs']:<3d}" if decides else ""
        print(f"{i:<5d}{row['name'][:33]:<34s}{told}{row['information_gain']:>12.3f}  {ratios}")
    print(f"wrote {out / 'design.json'}, {out / 'design.png'}")
    return 0
