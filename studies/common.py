"""What every study script shares: its command line and the non-interactive figure backend."""
from __future__ import annotations

import argparse
from pathlib import Path


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (studies write files, never open windows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def study_main(module, argv=None):
    """Command line of a study module: ``--quick``, ``--seed N``, ``--out DIR``; runs it.

    ``module`` exposes ``NAME``, ``Config``, ``QUICK``, ``run(config, seed, out_dir)`` and a
    docstring whose first line describes it; ``module.describe(summary)`` prints the result if
    present.
    """
    parser = argparse.ArgumentParser(description=module.__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="short runs (CI)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    parser.add_argument("--out", default=f"results/{module.NAME}", help="output directory")
    args = parser.parse_args(argv)
    config = module.QUICK if args.quick else module.Config()
    summary = module.run(config, args.seed, Path(args.out))
    if hasattr(module, "describe"):
        module.describe(summary)
    print(f"wrote {args.out}")
    return summary
