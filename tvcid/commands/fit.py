"""``tvcid fit``: Bayesian calibration of a hypothesis on recordings (emcee, resumable)."""
from __future__ import annotations

import contextlib
import sys
import warnings
from pathlib import Path

from tvcid.models.hypotheses import HYPOTHESES
from tvcid.models.strict_json import write_json

from ._common import parse_assignments


def register(sub):
    p = sub.add_parser(
        "fit",
        help="calibrate a hypothesis on recordings with MCMC (posterior, convergence, corner plot)",
        description="Sample the posterior of chosen parameters of a hypothesis given one or more "
        "recordings (closed loop at any controller setting, open-loop tests) with emcee. Writes "
        "DIR/chain.h5 (checkpointed every step), DIR/summary.json, DIR/corner.png, "
        "DIR/traces.png, DIR/predictive.png, DIR/check.json (posterior predictive check per "
        "recording) and DIR/posterior.nc (ArviZ InferenceData). "
        "Running it again on the same DIR resumes the chain (raise --max-steps to continue a "
        "run that stopped at the cap).",
    )
    p.add_argument("files", nargs="+", metavar="FILE.csv", help="recordings (CSV + JSON sidecar)")
    p.add_argument("--hypothesis", required=True, metavar="NAME",
                   help=f"hypothesis: {', '.join(HYPOTHESES)} (case-insensitive)")
    p.add_argument("--params", required=True, metavar="a,b,c",
                   help="comma-separated parameters to sample: fields of the hypothesis (e.g. "
                   "backlash,dead_zone,delay) and/or sigma (sensor-noise sd)")
    p.add_argument("--likelihood", choices=("waveform", "features"), default="waveform",
                   help="phase-aligned output error (a record whose simulated cycle is not "
                   "periodic or still settling enters through its features instead), or "
                   "limit-cycle features as a Gaussian")
    p.add_argument("--features", default="frequency,H1,H3,H5,H7",
                   help="features of the features likelihood (frequency, amplitude, Hk)")
    p.add_argument("--prior", action="append", default=[], metavar="NAME=LOW:HIGH[:log]",
                   help="declare a prior (repeatable); default log-uniform x/5..5x for widths, "
                   "uniform otherwise")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="fix a non-sampled parameter (repeatable; sigma=VALUE fixes the noise)")
    p.add_argument("--walkers", type=int, default=16, help="ensemble size")
    p.add_argument("--max-steps", type=int, default=4000, help="step cap of the whole chain")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    p.add_argument("--window", type=float, default=10.0, help="seconds of each closed-loop record used (its end)")
    p.add_argument("--transient", type=float, default=6.0,
                   help="seconds simulated before the window (waveform likelihood: a shorter one is "
                        "used where its log-likelihood at the walkers agrees with a 12 s one within "
                        "0.5 nats; --keep-transient to always use this one)")
    p.add_argument("--keep-transient", action="store_true",
                   help="simulate --transient seconds before the window, never a shorter transient")
    p.add_argument("--dt", type=float, default=None,
                   help="RK4 step of the likelihood simulations, s (default 5e-4, halved until one step, the "
                        "kernel's shortest delay, fits under the delay prior's floor; a record whose solver "
                        "error the data would see halves it)")
    p.add_argument("--processes", type=int, default=0,
                   help="map walker batches over a multiprocessing pool of this size (0: none; "
                   "the batch kernel already uses every core)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(func=run)


def run(args) -> int:
    from tvcid.discovery.calibration import Calibration, ConvergenceWarning, parse_prior
    from tvcid.discovery.parallel import map_pool

    from ..figures import write_posterior_figures

    names = [n.strip() for n in args.params.split(",") if n.strip()]
    priors = dict(parse_prior(text) for text in args.prior)
    fixed = parse_assignments(args.set)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        # its workers end with this process, however it ends
        pool = stack.enter_context(map_pool(args.processes)) if args.processes > 0 else None
        cal = Calibration(
            hypothesis=args.hypothesis, params=names, priors=priors, fixed=fixed,
            likelihood=args.likelihood,
            features=tuple(f.strip() for f in args.features.split(",") if f.strip()),
            window=args.window, transient=args.transient, choose_transient=not args.keep_transient,
            dt=args.dt, n_walkers=args.walkers, max_steps=args.max_steps, seed=args.seed,
            backend=out / "chain.h5",
            progress=not args.no_progress, pool=pool,
        )
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ConvergenceWarning)
            cal.fit(args.files)
    post = cal.posterior_
    post.to_json(out / "summary.json")
    from tvcid.discovery.calibration import predictive_check

    check = predictive_check(cal, seed=args.seed)
    write_json(out / "check.json", check.to_dict())
    write_posterior_figures(post, out, seed=args.seed)
    try:  # ArviZ InferenceData (walkers as chains, natural units)
        post.to_inference_data().to_netcdf(str(out / "posterior.nc"), engine="h5netcdf")
    except Exception as exc:  # noqa: BLE001 - an optional export must not lose the run
        print(f"note: posterior.nc not written ({exc})", file=sys.stderr)
    rep = cal.report_
    summary = post.summary()
    print(f"{rep.iterations} steps ({rep.new_steps} new), tau max {max(rep.tau):.1f}, "
          f"N/tau {rep.n_over_tau:.1f}, acceptance {rep.acceptance:.2f}")
    errors = getattr(cal, "transient_errors_", {})  # absent when a resumed run restored them
    for name, seconds in (getattr(cal, "transients_", None) or {}).items():
        how = ""
        if name in errors and seconds in errors[name]:
            how = f" (log-likelihood within {errors[name][seconds]:.2g} nats of a long one)"
        elif name in errors:
            how = " (no shorter one as accurate: the reference)"
        print(f"  transient {name}: {seconds:g} s{how}")
    for name, reason in (getattr(cal, "fallbacks_", None) or {}).items():
        print(f"  likelihood {name}: its limit-cycle features, not the waveform "
              f"({reason.split(': ', 1)[-1]})")
    for n, s in summary["parameters"].items():
        truth = "" if s["truth"] is None else f"  truth {s['truth']:.5g}"
        print(f"  {n:<12s} {s['q50']:.5g}  90 % [{s['q05']:.5g}, {s['q95']:.5g}]{truth}")
    for row, factor in zip(check.recordings, cal.inflation_):
        verdict = "passes" if row.passes else "FAILS: the data do not look like draws from the model"
        inflated = "" if factor == 1.0 else f", likelihood inflated x{factor:.3g} for model discrepancy"
        print(f"  check {row.name}: p = {row.p_value:.3g}, {verdict}{inflated}")
    if post.at_prior_bound():
        print(f"WARNING: at a prior bound: {', '.join(post.at_prior_bound())}", file=sys.stderr)
    if not rep.converged:
        for w in caught:
            if issubclass(w.category, ConvergenceWarning):
                print(f"WARNING: {w.message}", file=sys.stderr)
    print(f"wrote {out / 'chain.h5'}, {out / 'summary.json'}, {out / 'corner.png'}")
    return 0
