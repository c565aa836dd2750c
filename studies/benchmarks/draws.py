"""What the draw benchmarks share: finished rows read back for a rerun, the ``--jobs`` and
``--dask`` options, and the draws run one after the other, in worker processes that end with the
benchmark, or on a Dask cluster (:mod:`discovery.executors`)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["add_executor_options", "finished_rows", "run_draws"]


def finished_rows(path, quick, first, n) -> list:
    """Rows of ``path`` (a benchmark's ``bench.json``) of the same mode (``quick``) whose seeds
    lie in ``first .. first + n - 1``: what a rerun keeps."""
    path = Path(path)
    if not path.exists():
        return []
    old = json.loads(path.read_text())
    if old.get("quick") != quick:
        return []
    return [r for r in old["rows"] if first <= r["seed"] < first + n]


def _dask_address(text):
    """``--dask``'s value, checked as it is parsed (one line, naming the extra without Dask)."""
    from discovery.executors import check_dask_address

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


def run_draws(draw, seeds, out, quick, jobs, record, dask=None):
    """``draw(seed, out, quick)`` for every seed, ``jobs`` at once in worker processes
    (:func:`discovery.parallel.process_pool`: they end with this process) or on the Dask
    cluster ``dask`` (:func:`discovery.executors.executor_from`); ``record(seed, row)`` as each
    ends, in seed order."""
    seeds = list(seeds)
    n = len(seeds)
    if not n:
        return
    from discovery.executors import executor_from

    # locally, one draw (or --jobs 1 or less) runs in this process: a pool would only add its
    # start-up
    with executor_from(jobs if n > 1 and jobs > 1 else 1, dask) as executor:
        for seed, row in zip(seeds, executor.map(draw, seeds, [out] * n, [quick] * n)):
            record(seed, row)
