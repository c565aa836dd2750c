"""``tvcid df``: describing-function analysis (paper 002): predict cycles, draw the inverse family."""
from __future__ import annotations

import numpy as np

from tvcid.discovery.describing import (
    FAMILY_BACKLASH_HALF_WIDTHS,
    NoHarmonicBalanceSolution,
    compare_with_simulation,
    paper002_family,
    predict_limit_cycles,
    solve_backlash_and_dead_zone,
)
from tvcid.models.experiments import CONTROLLER_A, ClosedLoop
from tvcid.models.hypotheses import HYPOTHESES, hypothesis

from ._common import (
    add_compensator_options,
    closed_loop_from_args,
    parse_assignments,
    print_json,
)


def _controller_arguments(p):
    a = CONTROLLER_A
    p.add_argument("--kp", type=float, default=a.kp, help=f"proportional gain (default: controller A, {a.kp:g})")
    p.add_argument("--kd", type=float, default=a.kd, help=f"derivative time, s (default {a.kd:g})")
    p.add_argument("--mu", type=float, default=a.mu, help=f"vehicle effectiveness, 1/s^2 (default {a.mu:g})")


def register(sub):
    p = sub.add_parser(
        "df",
        help="describing-function analysis: predicted limit cycles, paper 002's inverse family",
        description="First-harmonic (describing-function) analysis of papers 002 and 001: harmonic "
        "balance with the exact delay, and paper 002's (backlash, dead zone) family.",
    )
    dsub = p.add_subparsers(dest="df_command", metavar="ACTION")
    dsub.required = True

    pr = dsub.add_parser(
        "predict",
        help="limit cycles of a hypothesis by harmonic balance (Loeb's criterion for stability)",
        description="Every limit cycle harmonic balance predicts for a hypothesis in the HWIL loop. "
        "Amplitudes are first-harmonic amplitudes of delta (rad). The DF is an approximation: for "
        "M002 at controller A it predicts 8.88 rad/s where the simulator gives 8.60.",
    )
    pr.add_argument("name", metavar="NAME", help=f"hypothesis: {', '.join(HYPOTHESES)} (case-insensitive)")
    _controller_arguments(pr)
    pr.add_argument("--controller-rate", type=float, default=None, metavar="HZ",
                    help="controller held at this rate (the hold as its first harmonic: half a "
                    "sample of delay and a sinc attenuation)")
    add_compensator_options(pr)
    pr.add_argument("--set", action="append", metavar="KEY=VALUE", default=[], help="override a parameter (repeatable)")
    pr.add_argument("--amplitude-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                    help="search range of the amplitude (of delta, rad; of the dead zone's input with a band-pass loop)")
    pr.add_argument("--frequency-range", type=float, nargs=2, default=(0.1, 300.0), metavar=("LOW", "HIGH"),
                    help="search range of the frequency, rad/s")
    pr.add_argument("--compare", action="store_true", help="also simulate 40 s and report the differences")
    pr.add_argument("--plot", metavar="FILE.png", help="save the harmonic-balance plot")
    pr.add_argument("--json", action="store_true", help="print JSON")
    pr.set_defaults(func=run_predict)

    fa = dsub.add_parser(
        "family",
        help="paper 002's family of (backlash, dead zone) pairs from a measured cycle",
        description="Paper 002 eqs. 13-18 (corrected, or as printed) from a measured amplitude and "
        "frequency, and the exact harmonic-balance solve (which may have no solution).",
    )
    fa.add_argument("--amplitude", type=float, required=True, help="measured cycle amplitude at the output, rad")
    fa.add_argument("--frequency", type=float, required=True, help="measured cycle frequency, rad/s")
    _controller_arguments(fa)
    fa.add_argument("--delay", type=float, default=None, help="output delay Td, s (default: the hypothesis's, 0.007 for M002)")
    fa.add_argument("--hypothesis", default="M002", help="structure and linear part (default M002)")
    fa.add_argument("--variant", choices=("corrected", "printed"), default="corrected", help="paper 002's algebra")
    fa.add_argument("--backlash", type=float, nargs="+", default=list(FAMILY_BACKLASH_HALF_WIDTHS),
                    metavar="R", help="backlash half widths, rad")
    fa.add_argument("--plot", metavar="FILE.png", help="save the family plot")
    fa.add_argument("--json", action="store_true", help="print JSON")
    fa.set_defaults(func=run_family)


def _save(result, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax = result.plot()
    ax.figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(ax.figure)


def run_predict(args) -> int:
    params = hypothesis(args.name, **parse_assignments(args.set))
    controller = closed_loop_from_args(args)
    ranges = {"frequency_range": tuple(args.frequency_range)}
    if args.amplitude_range is not None:
        ranges["amplitude_range"] = tuple(args.amplitude_range)
    result = predict_limit_cycles(params, controller, **ranges)
    out = {"hypothesis": params.name, "controller": controller.to_dict()}
    out.update(result.to_dict())
    if args.compare:
        try:
            out["comparison"] = compare_with_simulation(params, controller, **ranges).to_dict()
        except NoHarmonicBalanceSolution as exc:
            out["comparison"] = {"error": str(exc)}
    if args.plot:
        _save(result, args.plot)
    if args.json:
        print_json(out)
        return 0
    print(result.label)
    if not result.limit_cycles:
        print("no limit cycle predicted")
    for c in result.limit_cycles:
        print(f"  {'stable  ' if c.stable else 'unstable'} amplitude {c.amplitude:.4g} rad  "
              f"frequency {c.frequency:.4g} rad/s ({c.frequency_hz:.4g} Hz)")
    if "comparison" in out and "error" not in out["comparison"]:
        cmp = out["comparison"]
        print(f"  simulated: first harmonic {cmp['simulated_first_harmonic']:.4g} rad at "
              f"{cmp['simulated_frequency']:.4g} rad/s (DF {cmp['amplitude_error']:+.1%}, {cmp['frequency_error']:+.1%})")
    print(f"note: {result.caveat}")
    return 0


def run_family(args) -> int:
    params = hypothesis(args.hypothesis)
    controller = ClosedLoop(kp=args.kp, kd=args.kd, mu=args.mu)
    family = paper002_family(args.amplitude, args.frequency, controller, params, delay=args.delay,
                             backlash_half_widths=args.backlash, variant=args.variant)
    exact_params = params if args.delay is None else params.replace(delay=args.delay)
    try:
        pairs = solve_backlash_and_dead_zone(args.amplitude, args.frequency, controller, exact_params)
        exact = {"solutions": [p.to_dict() for p in pairs], "message": None}
    except NoHarmonicBalanceSolution as exc:
        exact = {"solutions": [], "message": str(exc)}
    out = family.to_dict()
    out["exact"] = exact
    out["controller"] = {"kp": args.kp, "kd": args.kd, "mu": args.mu}
    out["hypothesis"] = params.name
    if args.plot:
        _save(family, args.plot)
    if args.json:
        print_json(out)
        return 0
    print(f"paper 002 family ({family.variant}) for {args.amplitude:g} rad at {args.frequency:g} rad/s, Td {family.delay:g} s")
    for f, z in zip(family.backlash_half_width, family.dead_zone):
        print(f"  backlash half width {f:.4g}  dead zone {'-' if np.isnan(z) else format(z, '.4g')}")
    if exact["solutions"]:
        for s in exact["solutions"]:
            print(f"exact: backlash half width {s['backlash_half_width']:.4g}, dead zone {s['dead_zone']:.4g}")
    else:
        print(f"exact: {exact['message']}")
    return 0
