"""One member of the set, calibrated: its priors, its ensemble and its MCMC.

Each distinct member of the indistinguishable set (:mod:`discovery.structure.indistinguishable`)
is calibrated on its own (:func:`calibrate_member`), every parameter its structure has sampled, the
linear block included, within the structure search's box widened to hold the member's fit
(:func:`member_priors`); :mod:`discovery.structure.set_posterior` then mixes the members.
"""
from __future__ import annotations

import math

__all__ = ["calibrate_member", "member_priors", "member_walkers"]


def member_priors(params, structure, names, delay_floor):
    """Priors of one member's sampled parameters: the structure search's box
    (:data:`discovery.structure.coordinates.BOUNDS`) in natural units, each widened to hold the
    member's fit."""
    from discovery.calibration.priors import LogUniform, Uniform
    from discovery.structure.coordinates import BOUNDS

    g0 = params.gain / params.stiffness  # the block's static gain, rad/s per rad of error
    velocity = structure.dead_zone_position.value == "velocity"
    log_box = {"gain": BOUNDS["log_K1"], "damping": BOUNDS["log_K2"],
               "stiffness": BOUNDS["log_K3"], "feedback_gain": BOUNDS["log_K"],
               "backlash": BOUNDS["log_r"], "bandpass_gain": BOUNDS["log_G"]}
    scale = {}
    if velocity:
        log_box["dead_zone"], scale["dead_zone"] = BOUNDS["log_c_e"], g0
    else:
        log_box["dead_zone"] = BOUNDS["log_z"]
    log_box["bandpass_saturation"], scale["bandpass_saturation"] = BOUNDS["log_s_e"], g0
    priors = {}
    for name in names:
        value = float(getattr(params, name))
        if name == "delay":
            priors[name] = Uniform(min(delay_floor, 0.9 * value), max(BOUNDS["delay"][1], 1.5 * value))
        elif name == "friction_offset":
            c = params.dead_zone - params.friction_offset
            priors[name] = Uniform(min(-1.5 * c, 1.5 * value), max(0.3 * c, 0.5 * value + 1e-12))
        else:
            lo, hi = (math.exp(b) * scale.get(name, 1.0) for b in log_box[name])
            priors[name] = LogUniform(min(lo, value / 1.5), max(hi, value * 1.5))
    return priors


def member_walkers(n_parameters) -> int:
    """Walkers of a member's ensemble: ``max(16, 2 n + 6)``. The chain's length to convergence
    is set by its autocorrelation time in steps, which the Laplace independence move keeps from
    growing as the ensemble shrinks, while every walker costs one simulation of every recording
    per step; twice the parameters (emcee's floor) and a margin keep the differential-evolution
    moves' pairs varied where that move does not serve."""
    return max(16, 2 * int(n_parameters) + 6)


def calibrate_member(params, structure, recordings, fixed=None, seed=0, max_steps=2000,
                     backend=None, progress=False):
    """MCMC of one member of the set on ``recordings`` (features likelihood, 10 s windows):
    every parameter of ``structure`` but the ``fixed`` ones, the linear block included, within
    :func:`member_priors`; starts at ``params`` (the member's fit, with the cycle's initial
    state). The sensor noise sd stays at the records' estimate: sampled, it mixes several times
    slower than the physical parameters, and a misfit beyond the noise is the discrepancy
    factor's business. Returns ``(posterior, priors, simulated seconds)``: the last a dict,
    ``start`` (the set-up and the start's searches) and ``sampling`` (this call's steps; a
    resumed chain's earlier steps are not counted again)."""
    import warnings

    from discovery.calibration import Calibration
    from discovery.calibration.runner import ConvergenceWarning

    fixed = fixed or {}
    names = [n for n in structure.parameter_names() if n not in fixed
             and not (n == "bandpass_saturation" and not math.isfinite(params.bandpass_saturation))]
    # the shortest delay the structure search's 5e-4 s step resolves well
    priors = member_priors(params, structure, names, 1.2e-3 if params.delay > 1.2e-3 else 6e-4)
    start = {n: min(max(getattr(params, n), priors[n].low * 1.001), priors[n].high * 0.999)
             for n in names}
    sampled = tuple(names) or ("sigma",)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        cal = Calibration(params, params=sampled, priors=priors, start=start,
                          likelihood="features", window=10.0, n_walkers=member_walkers(len(names)),
                          max_steps=max_steps, seed=seed, backend=backend, progress=progress,
                          global_search=False).fit(recordings)
    start = cal.start_simulated_seconds_
    return cal.posterior_, priors, {"start": start,
                                    "sampling": cal.log_posterior_.simulated_seconds - start}
