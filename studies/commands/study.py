"""``tvcid study``: run one study, or all of them, writing under ``results/``."""
from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from ..registry import STUDIES
from ..report import write_report


def register(sub):
    p = sub.add_parser(
        "study",
        help="run a study (or all) and write its figures and numbers under results/",
        description="Run the studies of tvcid on the bundled data; outputs under RESULTS/<study>/.",
    )
    p.add_argument("name", metavar="NAME", help=f"'all' or one of: {', '.join(STUDIES)}")
    p.add_argument("--quick", action="store_true", help="short runs (CI)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    p.add_argument("--results", default="results", help="results directory")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.name == "all":
        names = list(STUDIES)
    elif args.name in STUDIES:
        names = [args.name]
    else:
        raise ValueError(f"unknown study {args.name!r}; choose 'all' or one of {', '.join(STUDIES)}")
    for name in tqdm(names, desc="studies", unit="study", disable=len(names) == 1):
        module = STUDIES[name]
        config = module.QUICK if args.quick else module.Config()
        out = Path(args.results) / name
        module.run(config, args.seed, out)
        tqdm.write(f"study {name}: wrote {out}")
    report = write_report(args.results)
    print(f"wrote {report}")
    return 0
