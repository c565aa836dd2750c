"""The posterior over the set of structures the recordings cannot tell apart.

Each distinct member of the indistinguishable set (:mod:`discovery.structure.indistinguishable`)
is calibrated on its own, every parameter the recordings inform sampled, the linear block
included. :func:`combine` then mixes the members' draws into one posterior of the physical
quantities they share:

* ``dead_zone`` (rad on the error, rad/s on the velocity signal: members with the dead zone in
  different places are combined per place, ``dead_zone[error]`` and ``dead_zone[velocity]``);
* ``threshold``: the velocity form's ``z - off``, which motion pins (docs/models.md#what-a-recording-pins);
* ``backlash``, ``friction_offset`` (0 in a member without them) and ``delay``;
* the linear block's ``dc_gain`` (``1/K``, rad per rad of command) and ``bandwidth`` (rad/s, the
  -3 dB frequency of ``K1/(s^3 + K2 s^2 + K3 s + K K1)``, the position loop without its delay and
  nonlinearities).

The weights are equal within the set. The set holds the structures whose held-out scores differ
from the best by less than the margin the two folds' disagreement allows: the data do not rank
them, so any weight that favours one (stacking of the held-out predictive, or Bayes factors of
fits whose differences lie inside that noise) would rank them on noise. :class:`SetPosterior`
records each member's score difference over the margin, the assumption's check: every ratio is
at most 1 by the set's construction.

A quantity *depends on the structure* when the spread of the members' medians exceeds half the
median width of their own 90 % intervals: then the combined interval is wide because the members
disagree, not because each is uncertain.

Beside its interval, each quantity has the range the recordings *allow* (:func:`allowed_range`):
where its profile log posterior stays within 1.92 nats of the best, the members' ranges joined.
The priors are flat in the sampling coordinates, so this is a profile-likelihood range, which
does not depend on how a prior spreads its mass: on a quantity the recordings do not pin, the 90 %
interval is mostly the prior's, the allowed range says where the recordings bound it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["MemberPosterior", "SetPosterior", "allowed_range", "calibrate_member", "combine",
           "linear_block_dc_gain_and_bandwidth", "member_priors", "member_quantities",
           "member_walkers", "not_pinned", "QUANTITY_UNITS"]

#: Unit of each combined quantity (the dead zone's depends on its place).
QUANTITY_UNITS = {
    "dead_zone[error]": "rad", "dead_zone[velocity]": "rad/s", "threshold": "rad/s",
    "backlash": "rad", "friction_offset": "rad/s", "delay": "s", "dc_gain": "rad/rad",
    "bandwidth": "rad/s",
}
#: A quantity depends on the structure when the members' medians spread by more than this
#: fraction of the median width of their 90 % intervals.
STRUCTURE_DEPENDENCE = 0.5
#: Drop of the log posterior (nats) that bounds the values the recordings allow
#: (:func:`allowed_range`): a profile likelihood's 95 % point for one quantity (3.84 / 2).
ALLOWED_DROP = 1.92
#: Bins of a quantity's range over which its profile is read.
ALLOWED_BINS = 40
#: Frequencies (rad/s) on which the linear block's -3 dB point is found.
_OMEGA = np.logspace(-1, 4.5, 1200)


def linear_block_dc_gain_and_bandwidth(gain, damping, stiffness, feedback_gain):
    """DC gain (``1/K``) and -3 dB bandwidth (rad/s) of the actuator's linear position loop
    ``K1 / (s^3 + K2 s^2 + K3 s + K K1)`` (docs/models.md#the-linear-block-and-the-papers-a-b-c),
    for arrays of parameters; the bandwidth is ``nan`` where the response never falls 3 dB below
    its DC value within 10^4.5 rad/s."""
    k1, k2, k3, k = (np.atleast_1d(np.asarray(v, dtype=float)) for v in
                     (gain, damping, stiffness, feedback_gain))
    s = 1j * _OMEGA[None, :]
    h = k1[:, None] / (s ** 3 + k2[:, None] * s ** 2 + k3[:, None] * s + (k * k1)[:, None])
    ratio = np.abs(h) * k[:, None]  # |H| / DC gain
    below = ratio < 1 / np.sqrt(2)
    bandwidth = np.full(k1.shape, np.nan)
    for i in np.flatnonzero(below.any(axis=1)):
        j = int(np.argmax(below[i]))
        if j == 0:
            bandwidth[i] = _OMEGA[0]
            continue
        # interpolate the crossing in log frequency
        r0, r1 = ratio[i, j - 1], ratio[i, j]
        f = (r0 - 1 / np.sqrt(2)) / (r0 - r1)
        bandwidth[i] = float(np.exp(np.log(_OMEGA[j - 1]) + f * np.log(_OMEGA[j] / _OMEGA[j - 1])))
    return 1.0 / k, bandwidth


def allowed_range(values, log_prob, drop=ALLOWED_DROP, bins=ALLOWED_BINS):
    """The values of one quantity the recordings allow, read off a member's draws.

    The draws' range is cut into ``bins`` bins (in log where the values are positive and span
    over a decade); a bin's profile is the largest log posterior of its draws, and the range
    runs from the first to the last bin whose profile is within ``drop`` nats of the largest of
    all, its ends read at the outermost draws of those two bins that are within ``drop`` too.
    With priors flat in the sampling coordinates (log-uniform and uniform), the log posterior is
    the log likelihood plus a constant, so this is a profile-likelihood range: unlike the 90 %
    interval, it does not follow where the prior puts its mass. Sparse draws at an edge read the
    profile low there, so the range errs narrow. Returns ``(low, high)``, or ``None`` under
    ``2 bins`` finite draws."""
    v = np.asarray(values, dtype=float)
    lp = np.broadcast_to(np.asarray(log_prob, dtype=float), v.shape)
    ok = np.isfinite(v) & np.isfinite(lp)
    v, lp = v[ok], lp[ok]
    if v.size < 2 * bins:
        return None
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        return lo, hi
    log = lo > 0 and hi > 10 * lo
    x = np.log(v) if log else v
    edges = np.linspace(x.min(), x.max(), bins + 1)
    index = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    profile = np.full(bins, -np.inf)
    np.maximum.at(profile, index, lp)
    within = lp >= lp.max() - drop
    kept = np.flatnonzero(profile >= lp.max() - drop)
    return (float(v[within & (index == kept[0])].min()),
            float(v[within & (index == kept[-1])].max()))


def member_quantities(params: dict, draws: dict) -> dict:
    """The combined quantities of one member: its fitted ``params`` (a dict of
    :class:`models.ActuatorParams` fields) with the sampled fields replaced by ``draws`` (name ->
    array, natural units); every array the same length."""
    n = len(next(iter(draws.values()))) if draws else 1
    value = {name: np.broadcast_to(np.asarray(draws.get(name, params[name]), dtype=float), (n,))
             for name in ("gain", "damping", "stiffness", "feedback_gain", "dead_zone",
                          "friction_offset", "backlash", "delay")}
    position = str(params.get("dead_zone_position", "error"))
    out = {f"dead_zone[{position}]": value["dead_zone"], "backlash": value["backlash"],
           "delay": value["delay"]}
    if position == "velocity":
        out["threshold"] = value["dead_zone"] - value["friction_offset"]
        out["friction_offset"] = value["friction_offset"]
    dc, bw = linear_block_dc_gain_and_bandwidth(value["gain"], value["damping"],
                                                value["stiffness"], value["feedback_gain"])
    out["dc_gain"], out["bandwidth"] = dc, bw
    return {k: np.array(v, dtype=float) for k, v in out.items()}


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


def not_pinned(post, priors, fraction=0.5) -> list:
    """Sampled parameters whose 90 % interval spans more than ``fraction`` of their prior (in
    the prior's own coordinate): the recordings do not pin them."""
    out = []
    for j, name in enumerate(post.names):
        prior = priors.get(name)
        if prior is None:
            continue
        lo, hi = prior.internal_bounds
        q05, q95 = np.quantile(post.internal[:, j], (0.05, 0.95))
        if q95 - q05 > fraction * (hi - lo):
            out.append(name)
    return out


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


@dataclass
class MemberPosterior:
    """One member of the set, calibrated.

    Attributes
    ----------
    structure : str
        Its name (:meth:`models.structures.Structure.parse` reads it).
    quantities : dict
        Combined quantity -> draws (:func:`member_quantities`).
    summary : dict
        Its calibration's summary (:meth:`discovery.calibration.Posterior.summary`): every
        sampled parameter's quantiles, convergence, ``at_prior_bound``.
    score_over_margin : float
        ``(score - best score) / margin``: at most 1 for a member of the set.
    log_prob : ndarray, optional
        The log posterior of each draw (for :func:`allowed_range`).
    """

    structure: str
    quantities: dict
    summary: dict = field(default_factory=dict)
    score_over_margin: float = 0.0
    log_prob: np.ndarray | None = None

    @property
    def converged(self) -> bool:
        return bool(self.summary.get("converged", False))


@dataclass
class SetPosterior:
    """The members' posteriors and their equal-weight mixture (:func:`combine`)."""

    members: list
    quantities: dict
    criterion: str

    def interval(self, name, level=0.90):
        """The combined ``level`` interval of quantity ``name``."""
        q = self.quantities[name]
        return q["q05"], q["q95"]

    def to_dict(self) -> dict:
        return {
            "criterion": self.criterion,
            "quantities": self.quantities,
            "members": [{"structure": m.structure, "weight": 1.0 / len(self.members),
                         "score_over_margin": m.score_over_margin, "converged": m.converged,
                         "quantities": {k: _quantiles(v) for k, v in m.quantities.items()},
                         "posterior": m.summary} for m in self.members],
        }

    def plot(self, ax=None, names=("backlash", "delay", "threshold")):
        """Each member's 90 % interval and median (lines) beside the combined one (thick), for the
        quantities ``names`` the set has; returns the axes (one per quantity)."""
        import matplotlib.pyplot as plt

        names = [n for n in names if n in self.quantities]
        if ax is None:
            ax = plt.subplots(1, len(names), figsize=(3.2 * len(names), 2.8), squeeze=False)[1][0]
        for a, name in zip(np.atleast_1d(ax), names):
            rows = [(m.structure, _quantiles(m.quantities[name])) for m in self.members
                    if name in m.quantities]
            for i, (_, q) in enumerate(rows):
                a.plot([q["q05"], q["q95"]], [i, i], color="C0", lw=1.5)
                a.plot(q["q50"], i, "o", color="C0", ms=3)
            c = self.quantities[name]
            a.plot([c["q05"], c["q95"]], [-1, -1], color="C3", lw=4)
            a.plot(c["q50"], -1, "o", color="C3")
            a.set_yticks(range(-1, len(rows)), ["combined"] + [f"member {i + 1}" for i in range(len(rows))],
                         fontsize=7)
            a.set_xlabel(f"{name} ({QUANTITY_UNITS.get(name, '')})")
        return ax


def _quantiles(values) -> dict:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"q05": None, "q50": None, "q95": None}
    q05, q50, q95 = np.quantile(v, (0.05, 0.5, 0.95))
    return {"q05": float(q05), "q50": float(q50), "q95": float(q95)}


def combine(members, n_draws=4000, seed=0) -> SetPosterior:
    """Mix the members' draws with equal weights into one posterior per shared quantity.

    Each member contributes ``n_draws / len(members)`` draws (resampled with a seeded
    ``numpy.random.Generator``); a quantity only some members have (the dead zone at one place,
    the velocity form's threshold) is mixed over those members.

    Returns
    -------
    SetPosterior
        ``quantities``: name -> ``q05``, ``q50``, ``q95``, ``unit``, ``members`` (how many have
        it), ``depends_on_structure`` and ``spread_over_width`` (the rule of the module's
        docstring), and ``allowed``: ``[low, high]``, the members' :func:`allowed_range` joined
        (``None`` where no member has its draws' log posterior).
    """
    if not members:
        raise ValueError("combine: no member to combine")
    rng = np.random.default_rng(seed)
    per = max(1, n_draws // len(members))
    present = {n for m in members for n in m.quantities}
    names = [n for n in QUANTITY_UNITS if n in present] + sorted(present - set(QUANTITY_UNITS))
    quantities = {}
    for name in names:
        having = [m for m in members if name in m.quantities]
        mixed = np.concatenate([rng.choice(m.quantities[name], size=per, replace=True)
                                for m in having])
        q = _quantiles(mixed)
        own = [_quantiles(m.quantities[name]) for m in having]
        medians = [o["q50"] for o in own if o["q50"] is not None]
        widths = [o["q95"] - o["q05"] for o in own if o["q50"] is not None]
        spread = (max(medians) - min(medians)) if medians else 0.0
        width = float(np.median(widths)) if widths else 0.0
        ratio = spread / width if width > 0 else (0.0 if spread == 0 else float("inf"))
        ranges = [allowed_range(m.quantities[name], m.log_prob) for m in having
                  if m.log_prob is not None]
        ranges = [r for r in ranges if r is not None]
        allowed = [min(r[0] for r in ranges), max(r[1] for r in ranges)] if ranges else None
        quantities[name] = {**q, "unit": QUANTITY_UNITS.get(name, ""), "members": len(having),
                            "spread_over_width": ratio,
                            "depends_on_structure": bool(len(having) > 1 and ratio > STRUCTURE_DEPENDENCE),
                            "allowed": allowed}
    criterion = ("equal weights: the members' held-out scores differ from the best by less than "
                 "the margin the folds' disagreement allows (largest difference "
                 f"{max(m.score_over_margin for m in members):.2f} margins)")
    return SetPosterior(list(members), quantities, criterion)
