"""Argument helpers shared by the subcommands."""
from __future__ import annotations

import argparse
import contextlib
import json

from tvcid.models.controllers import BendingMode, TransferFunction
from tvcid.models.experiments import CONTROLLER_A, ClosedLoop
from tvcid.models.strict_json import jsonable


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


def dask_address(text):
    """``--dask``'s value (:func:`tvcid.discovery.executors.check_dask_address`), refused as it is
    parsed with one line: a bad address, or Dask not installed (naming the extra)."""
    from tvcid.discovery.executors import check_dask_address

    try:
        return check_dask_address(text)
    except (ValueError, ImportError) as err:
        raise argparse.ArgumentTypeError(str(err)) from None


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
    """The plain PD loop of ``--kp --kd --mu --controller-rate`` (no compensator options read)."""
    return ClosedLoop(kp=args.kp, kd=args.kd, mu=args.mu, sample_rate=args.controller_rate)


def add_controller_options(parser):
    """Every closed-loop option: :func:`add_controller_arguments` and :func:`add_compensator_options`."""
    add_controller_arguments(parser)
    add_compensator_options(parser)


def add_compensator_options(parser):
    """``--lead``, ``--notch``, ``--controller-tf`` (in series with the PD) and ``--bending``."""
    g = parser.add_argument_group(
        "compensator and bending mode",
        "u = -Kp (1 + Kd s) F(s) theta_m: F is the product of the --lead, --notch and "
        "--controller-tf blocks given (none: F = 1), theta_m the sensed attitude (theta plus the "
        "--bending mode). Frequencies in rad/s. With --controller-rate, F runs as its Tustin "
        "(bilinear) realisation at that rate and u is held between samples; the bending mode is "
        "always continuous.",
    )
    g.add_argument("--lead", action="append", default=[], metavar="ZERO,POLE",
                   help="lead (zero < pole) or lag (zero > pole) (1 + s/ZERO)/(1 + s/POLE), unit DC "
                   "gain; repeatable")
    g.add_argument("--notch", action="append", default=[], metavar="FREQ,DAMPING,DEPTH",
                   help="notch (s^2 + 2 DEPTH DAMPING FREQ s + FREQ^2)/(s^2 + 2 DAMPING FREQ s + "
                   "FREQ^2): gain DEPTH (0 <= DEPTH < 1) at FREQ; repeatable")
    g.add_argument("--controller-tf", action="append", default=[], metavar="NUM/DEN",
                   help="any proper F(s) as comma-separated coefficients, highest power of s first, "
                   "numerator/denominator: '1,2/1,3,4' is (s + 2)/(s^2 + 3 s + 4); a whole "
                   "controller C(s) is --kp 1 --kd 0 --controller-tf ...; write --controller-tf=-1,... when "
                   "it starts with a minus sign; repeatable")
    g.add_argument("--bending", default=None, metavar="FREQ,DAMPING,GAIN",
                   help="bending mode in the sensed attitude: q'' = -2 DAMPING FREQ q' - FREQ^2 q + "
                   "GAIN FREQ^2 delta, theta_m = theta + q")


def _numbers(option, text, count=None):
    """``"1,2,3"`` -> floats; ValueError naming ``option`` otherwise."""
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = None
    if values is None or (count is not None and len(values) != count):
        shape = f"{count} comma-separated numbers" if count else "comma-separated numbers"
        raise ValueError(f"{option} takes {shape} (got {text!r})")
    return values


def _named(option, build, *values):
    """Build a block; a ValueError names the option it came from."""
    try:
        return build(*values)
    except ValueError as exc:
        raise ValueError(f"{option}: {exc}") from None


def compensator_from_args(args):
    """The compensator (:class:`TransferFunction`) of ``--lead/--notch/--controller-tf``, or None.

    Raises
    ------
    ValueError
        One line naming the option (malformed numbers, an improper transfer function, ...).
    """
    blocks = []
    for text in getattr(args, "lead", None) or ():
        blocks.append(_named(f"--lead {text}", TransferFunction.lead, *_numbers("--lead", text, 2)))
    for text in getattr(args, "notch", None) or ():
        blocks.append(_named(f"--notch {text}", TransferFunction.notch, *_numbers("--notch", text, 3)))
    for text in getattr(args, "controller_tf", None) or ():
        if text.count("/") != 1:
            raise ValueError(f"--controller-tf takes NUM/DEN, e.g. '1,2/1,3,4' (got {text!r})")
        num, den = text.split("/")
        blocks.append(_named(f"--controller-tf {text}", TransferFunction,
                             _numbers("--controller-tf", num), _numbers("--controller-tf", den)))
    if not blocks:
        return None
    return blocks[0] if len(blocks) == 1 else TransferFunction.series(*blocks)


def bending_from_args(args):
    """The :class:`BendingMode` of ``--bending FREQ,DAMPING,GAIN``, or None."""
    text = getattr(args, "bending", None)
    if text is None:
        return None
    return _named(f"--bending {text}", BendingMode, *_numbers("--bending", text, 3))


def closed_loop_from_args(args) -> ClosedLoop:
    """The :class:`ClosedLoop` of :func:`add_controller_options`' options (ValueError: one line)."""
    return ClosedLoop(kp=args.kp, kd=args.kd, mu=args.mu, sample_rate=args.controller_rate,
                      compensator=compensator_from_args(args), bending=bending_from_args(args))


def print_json(obj):
    """``obj`` on stdout as strict JSON (non-finite numbers as null), keys sorted."""
    print(json.dumps(jsonable(obj), indent=2, sort_keys=True, allow_nan=False))


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
