"""The ``tvcid`` command line: one subcommand module per capability under ``tvcid/commands``.

Each command module exposes ``register(subparsers)``, which adds its parser and sets
``func(args) -> int`` as the handler. Packages above tvcid add commands through the
``tvcid.commands`` entry-point group (the studies add ``tvcid study``), so that the application
never imports them.

Errors reach the user as one line on stderr: exit status 2 for bad input (a file, an option, a
parameter; the line names it), 130 for an interruption (Ctrl-C, SIGINT or SIGTERM, whatever
handler the process started with; long commands resume when run again), 1 for an internal error
(a bug: ``TVCID_DEBUG=1`` shows its traceback).
"""
from __future__ import annotations

import argparse
import os
import sys

from .commands import COMMAND_MODULES

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
EXIT_INTERNAL = 1


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (the usage stays behind ``--help``)."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="tvcid",
        description="Discover and calibrate the nonlinear model of a TVC electro-hydraulic "
        "actuator from its closed-loop limit cycle.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True
    for module in COMMAND_MODULES + plugin_commands():
        module.register(sub)
    return parser


def plugin_commands() -> tuple:
    """Command modules that installed packages add through the ``tvcid.commands`` entry points."""
    from importlib.metadata import entry_points

    return tuple(ep.load() for ep in sorted(entry_points(group="tvcid.commands"), key=lambda e: e.name))


def main(argv=None) -> int:
    from tvcid.discovery.parallel import interruptions_raise

    parser = build_parser()
    args = parser.parse_args(argv)
    name = f"tvcid {args.command}"
    with interruptions_raise():
        return _run(args, name)


def _run(args, name) -> int:
    """The command's exit status, every error as one line (the module's rules)."""
    from tvcid.models import SimulationDiverged

    try:
        return int(args.func(args) or 0)
    except (ValueError, TypeError, OSError) as exc:
        # bad input: the validators' messages name the file, column, row or parameter
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SimulationDiverged as exc:  # a loop the parameters make unstable is the user's input
        print(f"{name}: error: {_one_line(exc)} (the loop is unstable with these parameters "
              "and controller settings)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM raised as one
        print(f"{name}: interrupted; what was saved is kept (run the same command again to resume "
              "a chain or a discovery)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # noqa: BLE001 - a bug still gets one line; the traceback on request
        if os.environ.get("TVCID_DEBUG"):
            raise
        print(f"{name}: internal error: {type(exc).__name__}: {_one_line(exc)} (a bug; rerun with "
              "TVCID_DEBUG=1 for the traceback and please report it)", file=sys.stderr)
        return EXIT_INTERNAL


def _one_line(exc) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, KeyError):  # str(KeyError('x')) is "'x'"
        text = f"unknown name {text}"
    return text or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
