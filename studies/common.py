"""What every study script shares: its command line, and the commit and machine its records
name."""
from __future__ import annotations

import argparse
from pathlib import Path


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


def code_commit(paths=None):
    """The checkout's git commit, short, with ``+dirty`` when tracked files (those under
    ``paths``, where given) differ from it (``None`` outside git); benchmark rows record the
    commit of the code their process imported (rows of a resumed benchmark may come from
    several)."""
    import subprocess

    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).parent).stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
        changed = git("status", "--porcelain", "--untracked-files=no", "--", *map(str, paths or ()))
        return commit + ("+dirty" if changed else "")
    except (OSError, subprocess.CalledProcessError):
        return None


def failure(exc) -> dict:
    """A draw's failure as its row keeps it: ``error`` (the exception's type and message) and
    ``traceback`` (its last frames, the place it was raised; a long run's failure is then found
    without running it again)."""
    import traceback

    frames = traceback.format_exception(type(exc), exc, exc.__traceback__)
    return {"error": f"{type(exc).__name__}: {exc}", "traceback": "".join(frames[-8:])}


def machine() -> dict:
    """The arithmetic this process computes with, which benchmark rows record beside their
    commit: the processor's model (``cpu``), the widest SIMD target numpy dispatches its
    element-wise functions to (``numpy_simd``, e.g. ``X86_V3`` for AVX2, ``X86_V4`` for
    AVX-512) and the processor numba compiles its kernels for (``numba_cpu``).

    Two machines that differ in these can round the same operation differently; a search whose
    two best structures nearly tie can then rank them the other way round, and the chains that
    follow differ. On one machine a run is repeated step for step.
    """
    import platform

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f
                        if line.startswith("model name")), cpu)
    except OSError:
        pass
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
        found = [t for t in __cpu_dispatch__ if __cpu_features__.get(t)]
        simd = found[-1] if found else None
    except ImportError:  # numpy's private module moved: the field is then unknown
        simd = None
    try:
        from llvmlite.binding import get_host_cpu_name
        numba_cpu = get_host_cpu_name()
    except ImportError:
        numba_cpu = None
    return {"cpu": cpu, "numpy_simd": simd, "numba_cpu": numba_cpu}
