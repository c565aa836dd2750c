"""The set's members calibrated as independent tasks of an executor (:mod:`discovery.executors`).

:func:`calibrate_member_task` does all of one member's own work: its chain
(:func:`tvcid.pipeline._calibrate_member`, checkpointed in ``chain-<tag>.h5`` of the output
directory), its summary, its step error and its pointwise log-likelihood for the weights. It
gets everything as arguments and hands back a :class:`MemberRun`, both of which pickle, so it
runs the same in this process (the default) or on a Dask worker; :func:`tvcid.pipeline._calibrate`
combines the runs in the members' order.
"""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["MemberRun", "calibrate_member_task"]


@dataclass
class MemberRun:
    """One member's calibration, or why it has none.

    Attributes
    ----------
    structure : str
    failed : str or None
        Why its chain could not start (:class:`discovery.calibration.start.NoFiniteStartError`);
        the other fields are then empty.
    posterior : discovery.calibration.Posterior or None
    kept : dict
        Its row of ``set_posterior.members`` (the posterior's summary, step error, chain file).
    quantities, prior_quantities : dict
        Combined quantity -> draws, of the posterior and of the priors alone.
    step_error : dict
        Combined quantity -> its step error.
    pointwise : discovery.structure.set_weights.MemberPointwise or None
        For the weights (only when the set has several members).
    simulated_seconds : float
        Seconds simulated: the chain (start included), the step error, the pointwise draws.
    start_seconds : float
        Of which the chain's start.
    """

    structure: str
    failed: str | None = None
    posterior: object = None
    kept: dict = field(default_factory=dict)
    quantities: dict = field(default_factory=dict)
    prior_quantities: dict = field(default_factory=dict)
    step_error: dict = field(default_factory=dict)
    pointwise: object = None
    simulated_seconds: float = 0.0
    start_seconds: float = 0.0


def calibrate_member_task(row, recs, offsets, fixed, seed, quick, max_steps, progress, out,
                          weigh):
    """One member's calibration and what the set needs of it.

    Parameters
    ----------
    row : dict
        The member's row of the ranking.
    recs : list of models.recording.Recording
    offsets : dict
        Sensor offset per recording (rad), removed before the calibration.
    fixed : dict or None
    seed : int
    quick : bool
    max_steps : int or None
    progress : bool
    out : pathlib.Path
        Where the chain is checkpointed (created if missing).
    weigh : bool
        Evaluate the pointwise log-likelihood for the members' weights.

    Returns
    -------
    MemberRun
    """
    from discovery.calibration.start import NoFiniteStartError
    from discovery.calibration.step_error import measure_step_error, widen_quantiles
    from discovery.structure.set_posterior import member_quantities, not_pinned, prior_quantities
    from discovery.structure.set_weights import member_pointwise

    from .pipeline import WEIGHT_DRAWS, _calibrate_member

    out.mkdir(parents=True, exist_ok=True)  # a worker's own disk may not hold it yet
    try:
        post, priors, seconds, chain = _calibrate_member(row, recs, offsets, fixed, seed,
                                                         quick, max_steps, progress, out)
    except NoFiniteStartError as exc:
        return MemberRun(row["structure"], failed=str(exc))
    simulated = seconds["start"] + seconds["sampling"]
    s = post.summary()
    kept = {k: s[k] for k in ("parameters", "converged", "tau", "correlation", "iterations",
                              "acceptance", "n_over_tau", "at_prior_bound", "laplace_move",
                              "interval_drift")}
    kept["not_pinned"] = not_pinned(post, priors)
    step = measure_step_error(post, seed=seed, params=row["params"])
    simulated += step.simulated_seconds
    kept["step_error"] = step.to_dict()
    kept["parameters"] = widen_quantiles(kept["parameters"],
                                         {n: v["error"] for n, v in step.parameters.items()},
                                         {n: (p.low, p.high) for n, p in priors.items()})
    kept["structure"], kept["chain"] = row["structure"], chain
    kept["merged_into"] = row["merged_into"]
    draws = {n: post.samples[:, j] for j, n in enumerate(post.names)}
    pointwise = None
    if weigh:
        before = post.calibration.log_posterior_.simulated_seconds
        pointwise = member_pointwise(post, n_draws=WEIGHT_DRAWS, seed=seed)
        simulated += post.calibration.log_posterior_.simulated_seconds - before
    return MemberRun(
        row["structure"], posterior=post, kept=kept,
        quantities=member_quantities(row["params"], draws),
        prior_quantities=prior_quantities(row["params"], priors, seed=seed),
        step_error={n: v["error"] for n, v in step.quantities.items()}, pointwise=pointwise,
        simulated_seconds=simulated, start_seconds=seconds["start"])
