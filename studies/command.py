"""``tvcid study``: run one study, or all of them, writing under ``results/``."""
from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from .registry import STUDIES
from .report import write_report


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
    p.add_argument("--skip", action="append", default=[], metavar="NAME",
                   help="with 'all': leave study NAME out (repeatable)")
    p.add_argument("--jobs", type=int, default=1,
                   help="studies run at once, one process each (default 1; the longest start first)")
    p.set_defaults(func=run)


def _run_one(name, quick, seed, results):
    """Run study ``name``; its output directory."""
    module = STUDIES[name]
    config = module.QUICK if quick else module.Config()
    out = Path(results) / name
    module.run(config, seed, out)
    return out


def run(args) -> int:
    if args.name not in STUDIES and args.name != "all":
        raise ValueError(f"unknown study {args.name!r}; choose 'all' or one of {', '.join(STUDIES)}")
    skip = list(getattr(args, "skip", []) or [])
    unknown = [n for n in skip if n not in STUDIES]
    if unknown:
        raise ValueError(f"--skip {unknown[0]!r}: not a study; choose from {', '.join(STUDIES)}")
    if skip and args.name != "all":
        raise ValueError("--skip goes with 'all' (name one study, or all but some)")
    names = [n for n in STUDIES if n not in skip] if args.name == "all" else [args.name]
    if args.jobs < 1:
        raise ValueError(f"--jobs {args.jobs}: need at least 1")
    if args.jobs > 1 and len(names) > 1:
        from concurrent.futures import as_completed

        from tvcid.discovery.parallel import process_pool

        # the long studies first, so that the short ones fill the other processes meanwhile
        names.sort(key=lambda n: not getattr(STUDIES[n], "LONG_RUNNING", False))
        with process_pool(min(args.jobs, len(names))) as pool:
            futures = {pool.submit(_run_one, n, args.quick, args.seed, args.results): n for n in names}
            try:
                for fut in tqdm(as_completed(futures), total=len(futures), desc="studies", unit="study"):
                    tqdm.write(f"study {futures[fut]}: wrote {fut.result()}")
            except BaseException:  # a failed study: do not start the ones still queued
                pool.shutdown(wait=False, cancel_futures=True)
                raise
    else:
        for name in tqdm(names, desc="studies", unit="study", disable=len(names) == 1):
            out = _run_one(name, args.quick, args.seed, args.results)
            tqdm.write(f"study {name}: wrote {out}")
    report = write_report(args.results)
    print(f"wrote {report}")
    return 0
