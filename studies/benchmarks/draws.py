"""What the draw benchmarks share: finished rows read back for a rerun, and the draws run one
after the other or in worker processes that end with the benchmark."""
from __future__ import annotations

import json
from pathlib import Path

__all__ = ["finished_rows", "run_draws"]


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


def run_draws(draw, seeds, out, quick, jobs, record):
    """``draw(seed, out, quick)`` for every seed, ``jobs`` at once in worker processes
    (:func:`discovery.parallel.process_pool`: they end with this process); ``record(seed, row)``
    as each ends, in seed order."""
    seeds = list(seeds)
    n = len(seeds)
    if jobs > 1 and n > 1:
        from discovery.parallel import process_pool

        with process_pool(jobs) as pool:
            for seed, row in zip(seeds, pool.map(draw, seeds, [out] * n, [quick] * n)):
                record(seed, row)
    else:
        for seed in seeds:
            record(seed, draw(seed, out, quick))
