"""``tvcid predict``: the limit cycle of a calibrated actuator under a controller, with its band."""
from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

from ._common import (
    add_compensator_options,
    add_controller_arguments,
    bending_from_args,
)


def register(sub):
    p = sub.add_parser(
        "predict",
        help="limit cycle under a controller (or over a grid) from a posterior, with its 90 %% band",
        description="Simulate posterior draws of a calibrated actuator (the --out directory of "
        "tvcid fit or tvcid discover) in closed loop with the given controller, u = -Kp (1 + Kd s) "
        "F(s) theta_m, and report the limit cycle's amplitude ((max-min)/2 of delta, rad) and "
        "frequency (rad/s): median and 90 % band over the draws, the fractions of draws that "
        "oscillate and that diverge, and the describing-function cycle of the median model. "
        "With --grid (once or twice) it maps them over controller values and writes "
        "MAP_DIR/map.json, map.csv and map.png (medians, band width, stability boundary). On a "
        "discover directory whose set holds several structures, every member predicts with its "
        "own posterior; the band mixes the members' oscillating draws, each member's carrying its "
        "weight (the set posterior's, equal where the run stores none) times the fraction of its "
        "draws that oscillate; and the output says whether the members agree at that controller "
        "(their medians differ by no more than two independent measurements would) or the choice "
        "of structure changes the answer (with --grid: MAP_DIR/disagreement.png, where they "
        "disagree).",
    )
    p.add_argument("directory", metavar="DIR", help="output directory of tvcid fit or tvcid discover")
    add_controller_arguments(p)
    add_compensator_options(p)
    p.add_argument("--grid", action="append", default=[], metavar="KEY=LO:HI:N",
                   help="vary a controller value over N points (repeatable, at most twice): kp, kd, "
                   "mu, lead_zero, lead_pole (need --lead), notch_frequency, notch_damping, "
                   "notch_depth (need --notch)")
    p.add_argument("--draws", type=int, default=200, help="posterior draws simulated (default 200)")
    p.add_argument("--transient", type=float, default=3.0,
                   help="seconds each draw runs from the median model's cycle before the window")
    p.add_argument("--window", type=float, default=4.0, help="seconds measured")
    p.add_argument("--pilot", type=float, default=20.0,
                   help="seconds of the median model's run that finds its cycle at each setting "
                   "(0: start every draw near rest; then raise --transient)")
    p.add_argument("--no-df", action="store_true", help="skip the describing-function prediction")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of every random draw: the posterior draws' selection, the in-loop "
                   "noise of each draw, the recordings' resolution")
    p.add_argument("--json", action="store_true", help="print the one-setting result as JSON")
    p.add_argument("--out", metavar="MAP_DIR", help="output directory of a --grid map (required with --grid)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def setting_from_args(args):
    """The :class:`ControllerSetting` of the options; one --lead and one --notch stay named so
    that a grid can vary them."""
    from tvcid.discovery.prediction import ControllerSetting

    from ._common import _numbers, compensator_from_args

    named = {}
    leads, notches = list(args.lead), list(args.notch)
    if leads:
        named["lead_zero"], named["lead_pole"] = _numbers("--lead", leads.pop(0), 2)
    if notches:
        f, z, d = _numbers("--notch", notches.pop(0), 3)
        named.update(notch_frequency=f, notch_damping=z, notch_depth=d)
    rest = SimpleNamespace(lead=leads, notch=notches, controller_tf=list(args.controller_tf))
    try:
        return ControllerSetting(kp=args.kp, kd=args.kd, mu=args.mu,
                                 sample_rate=args.controller_rate, bending=bending_from_args(args),
                                 compensator=compensator_from_args(rest), **named)
    except ValueError as exc:
        raise ValueError(f"controller: {exc}") from None


def run(args) -> int:
    from tvcid.discovery.prediction import (
        PredictionConfig,
        cycle_map,
        load_set_draws,
        parse_grid,
        predict_cycle,
    )
    from tvcid.models import strict_json
    from tvcid.models.strict_json import write_json

    grid = dict(parse_grid(g) for g in args.grid)
    if len(grid) != len(args.grid):
        raise ValueError("--grid names the same key twice")
    if len(grid) > 2:
        raise ValueError(f"--grid given {len(grid)} times: a map varies at most two values")
    if grid and not args.out:
        raise ValueError("--grid writes a map: give --out MAP_DIR")
    if args.draws < 1:
        raise ValueError(f"--draws must be >= 1 (got {args.draws})")
    setting = setting_from_args(args)
    for key, values in grid.items():  # every grid point must be a valid controller
        for v in (values[0], values[-1]):
            try:
                setting.replace(**{key: float(v)})
            except ValueError as exc:
                raise ValueError(f"--grid {key}: {exc}") from None
    config = PredictionConfig(transient=args.transient, window=args.window, pilot=args.pilot,
                              seed=args.seed)
    members = load_set_draws(args.directory, n_draws=args.draws, seed=args.seed)
    if len(members) > 1:
        return _run_over_set(args, members, setting, grid, config)
    draws = next(iter(members.values()))
    if not grid:
        pred = predict_cycle(draws, setting, config, describing=not args.no_df)
        result = pred.to_dict()
        if args.json:
            print(strict_json.dumps(result))
            return 0
        print(f"{len(draws)} posterior draws of {draws.base.name} ({draws.source})")
        for name, unit, scale in (("amplitude", "mrad", 1e3), ("frequency", "rad/s", 1.0)):
            q = result[name]
            if q["q50"] is None:
                print(f"  {name:<10s} no draw oscillates")
            else:
                print(f"  {name:<10s} {q['q50'] * scale:.4g} {unit}  90 % "
                      f"[{q['q05'] * scale:.4g}, {q['q95'] * scale:.4g}]")
        print(f"  oscillating {result['fraction_oscillating']:.0%}, diverging "
              f"{result['fraction_diverging']:.0%}, at rest {result['fraction_at_rest']:.0%}")
        if result["fraction_not_settled"] > 0:
            print(f"  {result['fraction_not_settled']:.0%} of the draws still grow or decay slowly "
                  "over the window (near the stability boundary): their amplitude is not a cycle's")
        df = result["describing_function"]
        if df and df.get("amplitude") is not None:
            print(f"  describing function (median model): first harmonic "
                  f"{df['amplitude'] * 1e3:.4g} mrad at {df['frequency']:.4g} rad/s")
        elif df:
            print(f"  describing function: {df.get('note')}")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cmap = cycle_map(draws, setting, grid, config, describing=not args.no_df,
                     progress=not args.no_progress)
    write_json(out / "map.json", cmap.to_dict(), indent=1)
    cmap.to_csv(out / "map.csv")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes = cmap.plot()
    fig = axes[0].figure
    fig.savefig(out / "map.png", dpi=110)
    plt.close(fig)
    print(f"wrote {out / 'map.json'}, {out / 'map.csv'}, {out / 'map.png'}", file=sys.stderr)
    return 0


def _band(q, scale, unit) -> str:
    if q["q50"] is None:
        return "no draw oscillates"
    return f"{q['q50'] * scale:.4g} {unit}  90 % [{q['q05'] * scale:.4g}, {q['q95'] * scale:.4g}]"


def _run_over_set(args, members, setting, grid, config) -> int:
    """Every member of a discover directory's set predicts; the mixture's band, and whether the
    members agree (:mod:`tvcid.discovery.prediction.set_prediction`)."""
    from tvcid.discovery.prediction.draws import load_set_weights, load_unsure_members
    from tvcid.discovery.prediction.set_prediction import (
        MIXTURE_RULE,
        cycle_map_over_set,
        predict_cycle_over_set,
        run_resolution,
    )
    from tvcid.models import strict_json
    from tvcid.models.strict_json import write_json

    weights = load_set_weights(args.directory)
    unsure = load_unsure_members(args.directory)
    resolution = run_resolution(args.directory, seed=args.seed)
    if not grid:
        result = predict_cycle_over_set(members, setting, config, describing=not args.no_df,
                                        resolution=resolution, weights=weights,
                                        unsure=unsure).to_dict()
        if args.json:
            print(strict_json.dumps(result))
            return 0
        n = len(next(iter(members.values())))
        source = ("weights of the set's posterior" if weights is not None
                  else "equal weights (the run stores none)")
        print(f"the set's {len(members)} structures, {n} posterior draws each, {source} "
              f"({args.directory})")
        print(f"  amplitude  {_band(result['amplitude'], 1e3, 'mrad')}")
        print(f"  frequency  {_band(result['frequency'], 1.0, 'rad/s')}")
        print(f"  oscillating {result['fraction_oscillating']:.0%} (the members' fractions, "
              f"weighted); in the band {MIXTURE_RULE}")
        within = ("" if resolution is None else
                  f", each with what a recording resolves: amplitude "
                  f"{100 * resolution['amplitude']:.2g} %, frequency "
                  f"{100 * resolution['frequency']:.2g} % sd")
        if result["members_agree"]:
            print(f"  the members agree at this controller (their medians differ by no more than "
                  f"two independent measurements would{within}): the choice of structure does "
                  "not change the answer here")
        else:
            why = "; ".join(f"{d['members'][0]} / {d['members'][1]}: {d['why']}"
                            for d in result["disagreeing"])
            print(f"  the choice of structure changes the answer here ({why})")
        for name, b in result["members"].items():
            final = " (not final)" if name in result["unsure"] else ""
            print(f"  {name}: weight {b['weight']:.3g}{final}, oscillating "
                  f"{b['fraction_oscillating']:.0%} ({b['share_of_band']:.0%} of the band); amplitude "
                  f"{_band(b['amplitude'], 1e3, 'mrad')}; frequency "
                  f"{_band(b['frequency'], 1.0, 'rad/s')}")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    smap = cycle_map_over_set(members, setting, grid, config, describing=not args.no_df,
                              progress=not args.no_progress, resolution=resolution,
                              weights=weights, unsure=unsure)
    write_json(out / "map.json", smap.to_dict(), indent=1)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax = smap.plot()
    ax.figure.tight_layout()
    ax.figure.savefig(out / "disagreement.png", dpi=110)
    plt.close(ax.figure)
    dis = smap.disagreement()
    print(f"the members disagree at {int(dis.sum())} of {dis.size} grid points; wrote "
          f"{out / 'map.json'}, {out / 'disagreement.png'}", file=sys.stderr)
    return 0
