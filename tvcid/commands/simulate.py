"""``tvcid simulate``: run a hypothesis closed or open loop and write a recording."""
from __future__ import annotations

import numpy as np

from tvcid.models.experiments import OpenLoop
from tvcid.models.hypotheses import HYPOTHESES, hypothesis
from tvcid.models.recording import MAX_ANGLE, recording_from_trajectory, save_recording
from tvcid.models.simulate import DEFAULT_DT, DEFAULT_RATE, simulate

from ._common import add_controller_options, closed_loop_from_args, parse_assignments


def register(sub):
    p = sub.add_parser(
        "simulate",
        help="simulate a hypothesis and write a recording (CSV + JSON sidecar)",
        description="Simulate one of the papers' hypotheses in the HWIL closed loop (vehicle "
        "mu/s^2, PD controller, null reference) or open loop, and write a recording.",
    )
    p.add_argument("name", metavar="NAME", help=f"hypothesis: {', '.join(HYPOTHESES)} (case-insensitive)")
    add_controller_options(p)
    p.add_argument("--open-loop", choices=("step", "square", "sine"), help="open-loop command instead of the closed loop")
    p.add_argument("--amplitude", type=float, default=0.01, help="open-loop command amplitude, rad")
    p.add_argument("--frequency", type=float, default=1.0, help="open-loop square/sine frequency, Hz")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[], help="override a parameter (repeatable)")
    p.add_argument("--t-end", type=float, default=20.0, help="duration, s")
    p.add_argument("--dt", type=float, default=None,
                   help=f"RK4 step, s (default: the longest up to {DEFAULT_DT:g} s that --rate and a "
                   "held controller's rate divide)")
    p.add_argument("--rate", type=float, default=DEFAULT_RATE, help="output sample rate, Hz")
    p.add_argument("--seed", type=int, default=None, help="seed of the output noise (sets noise_seed)")
    p.add_argument("--out", required=True, metavar="FILE.csv", help="output recording")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.open_loop and (args.lead or args.notch or args.controller_tf or args.bending):
        raise ValueError("--lead, --notch, --controller-tf and --bending act in the closed loop; "
                         "drop them or --open-loop")
    if not args.open_loop:  # options checked before any simulation
        experiment = closed_loop_from_args(args)
    overrides = parse_assignments(args.set)
    if args.seed is not None:
        overrides["noise_seed"] = args.seed
    params = hypothesis(args.name, **overrides)
    if args.open_loop == "step":
        experiment = OpenLoop.step(args.amplitude)
    elif args.open_loop == "square":
        experiment = OpenLoop.square(args.amplitude, args.frequency)
    elif args.open_loop == "sine":
        experiment = OpenLoop.sine(args.amplitude, args.frequency)
    trajectory = simulate(params, experiment, args.t_end, dt=args.dt, rate=args.rate)
    peak = float(np.max(np.abs(trajectory.delta)))
    if peak > MAX_ANGLE:  # a recording tvcid would refuse to read back (degrees suspected)
        raise ValueError(f"{params.name}: the output reaches {peak:.3g} rad, beyond the {MAX_ANGLE} rad "
                         "an actuator record may hold (the loop is unstable or nearly so with these "
                         "parameters and controller settings)")
    columns, meta = recording_from_trajectory(trajectory)
    path = save_recording(args.out, columns, meta)
    print(f"wrote {path} ({trajectory.t.size} samples)")
    return 0
