"""Argument helpers shared by the subcommands."""
from __future__ import annotations

import argparse
import contextlib
import json

from models.experiments import CONTROLLER_A, ClosedLoop


def parse_assignments(pairs):
    """``["key=value", ...]`` -> dict; values become int, float, or stay strings (enum names)."""
    out = {}
    for pair in pairs or ():
        if "=" not in pair:
            raise ValueError(f"--set expects key=value, got {pair!r}")
        key, value = pair.split("=", 1)
        key, value = key.strip(), value.strip()
        for cast in (int, float):
            try:
                value = cast(value)
                break
            except ValueError:
                continue
        out[key] = value
    return out


def add_controller_arguments(parser):
    """``--kp --kd --mu`` (default: paper 002's controller A) and ``--controller-rate``."""
    parser.add_argument("--kp", type=float, default=CONTROLLER_A.kp, help="proportional gain (default 5.84)")
    parser.add_argument("--kd", type=float, default=CONTROLLER_A.kd, help="derivative time, s (default 0.062)")
    parser.add_argument("--mu", type=float, default=CONTROLLER_A.mu, help="vehicle effectiveness, 1/s^2 (default 12.3)")
    parser.add_argument(
        "--controller-rate", type=float, default=None, metavar="HZ",
        help="hold the controller output at this rate (e.g. 200 as in the HWIL); default continuous",
    )


def controller_from_args(args) -> ClosedLoop:
    return ClosedLoop(kp=args.kp, kd=args.kd, mu=args.mu, sample_rate=args.controller_rate)


def print_json(obj):
    print(json.dumps(obj, indent=2, sort_keys=True))


class Formatter(argparse.ArgumentDefaultsHelpFormatter):
    pass


def positive_seconds(text):
    """argparse type: a window length in seconds, > 0."""
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0 s (got {text})")
    return value


@contextlib.contextmanager
def about_file(path):
    """Name ``path`` in a ValueError raised while analysing it (unless the message names it)."""
    try:
        yield
    except ValueError as exc:
        message = str(exc)
        if str(path) in message:
            raise
        raise ValueError(f"{path}: {message}") from None
