"""One member of the set, calibrated: its priors, its ensemble and its MCMC.

Each distinct member of the indistinguishable set (:mod:`tvcid.discovery.structure.indistinguishable`)
is calibrated on its own (:func:`calibrate_member`), every parameter its structure has sampled, the
linear block included, within the structure search's box widened to hold the member's fit
(:func:`member_priors`); :mod:`tvcid.discovery.members.set_posterior` then mixes the members.
"""
from __future__ import annotations

import math

from tvcid.discovery.calibration.importance_stage import IMPORTANCE_ROUNDS
from tvcid.discovery.calibration.start import POLISH_RESTARTS

__all__ = ["MEMBER_DELAY_FLOOR", "MEMBER_IMPORTANCE_ROUND", "calibrate_member",
           "member_delay_floor", "member_priors", "member_walkers"]

#: The floor (s) of a member's delay prior: one step of the calibration's default 5e-4 s, the
#: kernel's shortest delay (:func:`tvcid.discovery.calibration.priors.step_under_delay`), under the
#: shortest delay a rig has (0.8 ms, the benchmark generator's ``RANGES['wide']``).
MEMBER_DELAY_FLOOR = 5e-4


def member_delay_floor(delay) -> float:
    """The floor (s) of the delay prior of a member whose fit has ``delay`` (s):
    ``min(MEMBER_DELAY_FLOOR, delay / 2)``.

    The calibration's step follows the floor, halved until one step fits under it
    (:func:`tvcid.discovery.calibration.priors.step_under_delay`), so only a member fitted under
    1 ms runs at a finer step (2.5e-4 s for a fit down to the structure search's one step of
    5e-4 s, twice the cost of every simulation); the others keep the default step and a prior
    that reaches 0.5 ms.
    """
    delay = float(delay)
    if not (math.isfinite(delay) and delay > 0.0):
        raise ValueError(f"a member's delay must be a finite number > 0 (got {delay!r})")
    return min(MEMBER_DELAY_FLOOR, 0.5 * delay)


def member_priors(params, structure, names, delay_floor=None):
    """Priors of one member's sampled parameters: the structure search's box
    (:data:`tvcid.discovery.structure.coordinates.BOUNDS`) in natural units, each widened to hold the
    member's fit; the delay's from ``delay_floor`` (default :func:`member_delay_floor` of the
    fit's delay, lowered to 0.9 times the fit where that is lower)."""
    from tvcid.discovery.calibration.priors import LogUniform, Uniform
    from tvcid.discovery.structure.coordinates import BOUNDS

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
            if delay_floor is None:
                delay_floor = member_delay_floor(value)
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


#: Points per round of a member's importance stage
#: (:mod:`tvcid.discovery.calibration.importance_stage`): where its ratios are reliable the
#: member's posterior costs a few rounds of these instead of a chain.
MEMBER_IMPORTANCE_ROUND = 400


def calibrate_member(params, structure, recordings, fixed=None, seed=0, max_steps=2000,
                     backend=None, progress=False, polish_restarts=POLISH_RESTARTS,
                     importance_rounds=IMPORTANCE_ROUNDS, importance_only=False, nested=0,
                     stop_when_converged=True):
    """MCMC of one member of the set on ``recordings`` (features likelihood, 10 s windows):
    every parameter of ``structure`` but the ``fixed`` ones, the linear block included, within
    :func:`member_priors`; starts at ``params`` (the member's fit, with the cycle's initial
    state). The step is the calibration's default 5e-4 s, halved until one step fits under the
    delay prior's floor (:func:`member_delay_floor`: a fit under 1 ms halves it). The sensor
    noise sd stays at the records' estimate: sampled, it mixes several times slower than the
    physical parameters, and a misfit beyond the noise is the discrepancy factor's business.
    The maximum a posteriori is found by quasi-Newton steps from the fit (batched simulations;
    :func:`tvcid.discovery.calibration.optimum._quasi_newton`). Rounds of importance sampling
    from the start's Laplace approximation come first
    (``MEMBER_IMPORTANCE_ROUND`` points each); where their ratios are reliable they are the
    posterior, else the chain starts from their points. ``polish_restarts``,
    ``importance_rounds`` and ``importance_only`` limit the start's restarts, the rounds and the
    chain after them; ``nested`` (live points) puts nested sampling between the rounds and the
    chain; ``stop_when_converged=False`` runs the chain to ``max_steps`` (a long reference)
    (:class:`tvcid.discovery.calibration.Calibration`'s). Returns
    ``(posterior, priors, simulated seconds)``: the last a dict, ``start`` (the set-up and the
    start's searches) and ``sampling`` (this call's steps; a resumed chain's earlier steps are not
    counted again)."""
    import warnings

    from tvcid.discovery.calibration import Calibration
    from tvcid.discovery.calibration.runner import ConvergenceWarning

    fixed = fixed or {}
    names = [n for n in structure.parameter_names() if n not in fixed
             and not (n == "bandpass_saturation" and not math.isfinite(params.bandpass_saturation))]
    priors = member_priors(params, structure, names)
    start = {n: min(max(getattr(params, n), priors[n].low * 1.001), priors[n].high * 0.999)
             for n in names}
    sampled = tuple(names) or ("sigma",)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        cal = Calibration(params, params=sampled, priors=priors, start=start,
                          likelihood="features", window=10.0, n_walkers=member_walkers(len(names)),
                          max_steps=max_steps, seed=seed, backend=backend, progress=progress,
                          global_search=False, importance=MEMBER_IMPORTANCE_ROUND,
                          start_optimizer="quasi-newton", polish_restarts=polish_restarts,
                          importance_rounds=importance_rounds,
                          importance_only=importance_only, nested=nested,
                          stop_when_converged=stop_when_converged).fit(recordings)
    start = cal.start_simulated_seconds_
    return cal.posterior_, priors, {"start": start,
                                    "sampling": cal.log_posterior_.simulated_seconds - start,
                                    "start_steps": cal.start_simulated_steps_}
