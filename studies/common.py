"""What every study script shares: its command line and the non-interactive figure backend."""
from __future__ import annotations

import argparse
from pathlib import Path


def process_pool(jobs):
    """A pool of ``jobs`` spawned processes (benchmarks and ``tvcid study all --jobs``).

    Spawned, not forked: a process whose numba kernels already ran OpenMP threads cannot fork
    safely (libgomp terminates the child: seen under pytest-xdist).
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"))


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (studies write files, never open windows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_posterior_figures(post, out_dir, seed=0, n_draws=30):
    """``corner.png``, ``traces.png`` and ``predictive.png`` (one panel per recording) of a
    :class:`discovery.calibration.Posterior` into ``out_dir``."""
    plt = pyplot()
    fig = post.plot_corner()
    fig.savefig(out_dir / "corner.png", dpi=90)
    plt.close(fig)
    axes = post.plot_traces()
    axes[0].figure.savefig(out_dir / "traces.png", dpi=90)
    plt.close(axes[0].figure)
    pred = post.predictive(n_draws=n_draws, seed=seed)
    fig, axs = plt.subplots(len(pred.curves), 1, figsize=(8, 2.8 * len(pred.curves)), squeeze=False)
    for ax, name in zip(axs[:, 0], pred.curves):
        pred.plot(name, ax=ax)
    fig.tight_layout()
    fig.savefig(out_dir / "predictive.png", dpi=90)
    plt.close(fig)


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


def code_commit():
    """The checkout's git commit, short, with ``+dirty`` when tracked files differ from it
    (``None`` outside git); benchmark rows record the commit of the code their process imported
    (rows of a resumed benchmark may come from several)."""
    import subprocess

    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).parent).stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
        return commit + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "")
    except (OSError, subprocess.CalledProcessError):
        return None
