"""What the draw benchmarks share: finished rows read back for a rerun, the ``--jobs`` and
``--dask`` options, and the draws run one after the other, in worker processes that end with the
benchmark, or on a Dask cluster (:mod:`tvcid.discovery.executors`)."""
from __future__ import annotations

import argparse
import functools
import json
from pathlib import Path

from .scenarios import RANGES

__all__ = ["add_draw_options", "add_executor_options", "add_ranges_option", "finished_rows",
           "row_ranges", "run_benchmark", "run_draws"]


def row_ranges(row) -> str:
    """The generator's ranges a row's draw was made with (a failed row's ``ranges``, else its
    ``design``'s; rows without either, and the coverage benchmark's, whose ``design`` is its list
    of recordings, were drawn within the papers')."""
    design = row.get("design")
    return row.get("ranges") or (design.get("ranges", "papers") if isinstance(design, dict)
                                 else "papers")


def finished_rows(path, quick, first, n, ranges=None) -> list:
    """Rows of ``path`` (a benchmark's ``bench.json``) of the same mode (``quick``) whose seeds
    lie in ``first .. first + n - 1`` (and drawn within ``ranges``, when given): what a rerun
    keeps."""
    path = Path(path)
    if not path.exists():
        return []
    old = json.loads(path.read_text())
    if old.get("quick") != quick:
        return []
    return [r for r in old["rows"] if first <= r["seed"] < first + n
            and (ranges is None or row_ranges(r) == ranges)]


def add_ranges_option(parser):
    """``--ranges NAME``: the generator's ranges of the draws (:data:`.scenarios.RANGES`)."""
    parser.add_argument("--ranges", choices=tuple(RANGES), default="wide",
                        help="the generator's ranges: wide (thresholds and delays over a decade, "
                             "200 Hz-2 kHz, staircase commands; default) or papers (near the "
                             "papers' rig)")


def _dask_address(text):
    """``--dask``'s value, checked as it is parsed (one line, naming the extra without Dask)."""
    from tvcid.discovery.executors import check_dask_address

    try:
        return check_dask_address(text)
    except (ValueError, ImportError) as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_executor_options(parser, jobs_help):
    """``--jobs J`` (help ``jobs_help``) and ``--dask ADDRESS`` on ``parser``: one or the other
    (argparse says so in one line)."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=int, default=1, help=jobs_help)
    where.add_argument("--dask", metavar="ADDRESS", type=_dask_address, default=None,
                       help="run the draws on the Dask scheduler at ADDRESS (tcp://HOST:8786), or "
                            "on a local cluster of N one-thread workers (local:N); needs "
                            "pip install tvcid[dask] (docs/cluster.md)")


def run_draws(draw, seeds, out, quick, jobs, record, dask=None, ranges=None):
    """``draw(seed, out, quick)`` (with ``ranges=ranges`` when given) for every seed, ``jobs`` at
    once in worker processes (:func:`tvcid.discovery.parallel.process_pool`: they end with this process)
    or on the Dask cluster ``dask`` (:func:`tvcid.discovery.executors.executor_from`);
    ``record(seed, row)`` as each ends, in seed order."""
    seeds = list(seeds)
    n = len(seeds)
    if not n:
        return
    from tvcid.discovery.executors import executor_from

    if ranges is not None:
        draw = functools.partial(draw, ranges=ranges)

    # locally, one draw (or --jobs 1 or less) runs in this process: a pool would only add its
    # start-up
    with executor_from(jobs if n > 1 and jobs > 1 else 1, dask) as executor:
        for seed, row in zip(seeds, executor.map(draw, seeds, [out] * n, [quick] * n)):
            record(seed, row)


def add_draw_options(parser, quick_help, quick_draws, out):
    """The options every draw benchmark takes: ``--quick`` (help ``quick_help``), ``--draws N``
    (default 30, ``quick_draws`` with ``--quick``), ``--seed S`` of the first draw (1000),
    ``--ranges NAME``, ``--jobs J`` or ``--dask ADDRESS``, and ``--out DIR`` (default ``out``)."""
    parser.add_argument("--quick", action="store_true", help=quick_help)
    parser.add_argument("--draws", type=int, default=None,
                        help=f"number of draws (default 30, quick {quick_draws})")
    parser.add_argument("--seed", type=int, default=1000, help="seed of the first draw")
    add_ranges_option(parser)
    add_executor_options(parser, "draws run at once, one process each")
    parser.add_argument("--out", default=out, help="output directory")
    parser.set_defaults(quick_draws=quick_draws)


def run_benchmark(args, draw, describe, save) -> list:
    """The draws ``args.seed .. args.seed + n - 1`` (``n`` from ``--draws``) of a benchmark whose
    options are :func:`add_draw_options`'s: the finished rows of ``args.out/bench.json`` kept, the others run
    (:func:`run_draws`); as each ends, its line printed (``describe(row)``, or its failure) and
    ``save(path, rows)`` called. Returns the rows, in seed order."""
    n = args.draws if args.draws is not None else (args.quick_draws if args.quick else 30)
    if n < 1:
        raise SystemExit(f"--draws must be at least 1 (got {n})")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench.json"
    # resume: finished draws of the same ranges are kept
    rows = finished_rows(path, args.quick, args.seed, n, args.ranges)

    def record(seed, row):
        rows.append(row)
        rows.sort(key=lambda r: r["seed"])
        print(f"draw {seed}: FAILED {row['error']}" if "error" in row else describe(row), flush=True)
        save(path, rows)

    done = {r["seed"] for r in rows}
    run_draws(draw, [s for s in range(args.seed, args.seed + n) if s not in done], out, args.quick,
              args.jobs, record, dask=args.dask, ranges=args.ranges)
    return rows
