"""``tvcid sindy``: weak-SINDy structure discovery on recordings, proposals ranked by simulation."""
from __future__ import annotations

import math

from tvcid.discovery.sindy import DEFAULT_FORMS, FORMS, discover_structure

from ._common import print_json


def register(sub):
    p = sub.add_parser(
        "sindy",
        help="propose the actuator structure by weak-form SINDy and rank it by simulation",
        description="Fit the structure forms (dead zone on the error as in paper 002; dead zone "
        "and friction on the velocity as in paper 001, with or without the band-pass loop) to "
        "one or more recordings by weak-form sparse regression with a threshold and delay scan, "
        "then simulate every proposal as a full model and rank them.",
    )
    p.add_argument("files", nargs="+", metavar="FILE.csv", help="recordings (CSV + JSON sidecar)")
    p.add_argument("--noise", type=float, default=None, metavar="SIGMA",
                   help="sensor noise rms of delta, rad (bias-compensated normal equations)")
    p.add_argument("--form", action="append", choices=sorted(FORMS), default=None,
                   help=f"structure form to fit (repeatable; default {', '.join(DEFAULT_FORMS)})")
    p.add_argument("--bootstrap", type=int, default=30, help="bootstrap resamples for inclusion")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap generator")
    p.add_argument("--no-rank", action="store_true", help="skip the ranking by simulation")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    est = discover_structure(
        args.files, noise=args.noise, forms=tuple(args.form or DEFAULT_FORMS), seed=args.seed,
        rank=not args.no_rank, n_bootstrap=args.bootstrap,
    )
    candidates = [c.to_dict() for c in est.candidates_]
    if args.json:
        print_json({
            "candidates": candidates,
            "n_weak_equations": est.n_rows_,
            "fit_time": est.fit_time_,
            "skipped_forms": dict(est.skipped_),
            "files": list(args.files),
        })
        return 0
    for name, why in est.skipped_.items():
        print(f"skipped {name}: {why}")
    for rank, cand in enumerate(est.candidates_, start=1):
        score = "n/a" if cand.score is None else f"{cand.score:.4g}"
        print(f"#{rank} {cand.form}  score {score}  criterion {cand.criterion:.1f}")
        for name, coef in cand.terms.items():
            print(f"    {name:34s} {coef: .6g}   inclusion {cand.inclusion.get(name, math.nan):.2f}")
        for name, value in cand.thresholds.items():
            extra = cand.inclusion.get(name)
            incl = f"   inclusion {extra:.2f}" if extra is not None else ""
            print(f"    {name:34s} {value: .6g}{incl}")
    return 0
