"""The ``tvcid`` command line: one subcommand module per capability under ``studies/commands``.

Each command module exposes ``register(subparsers)``, which adds its parser and sets
``func(args) -> int`` as the handler.
"""
from __future__ import annotations

import argparse
import sys

from .commands import COMMAND_MODULES


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tvcid",
        description="Discover and calibrate the nonlinear model of a TVC electro-hydraulic "
        "actuator from its closed-loop limit cycle.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in COMMAND_MODULES:
        module.register(sub)
    return parser


def main(argv=None) -> int:
    from models import SimulationDiverged

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"tvcid {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except SimulationDiverged as exc:  # a loop the parameters make unstable is the user's input
        print(f"tvcid {args.command}: error: {exc} (the loop is unstable with these parameters "
              "and controller settings)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
