"""The simulator's own error in a calibrated answer: how far it moves when the step is halved.

A calibration's posterior is the answer of a fixed-step RK4 model. Near switching events (dead
zone, backlash, square edges, a held controller) RK4 converges at first order, and where the
recordings pin a quantity tightly its 90 % interval can be narrower than the step resolves: M000's
open-loop square recorded with 2e-7 rad of noise pins the feedback gain to 1.2e-6 (90 %), and
halving the step (6.25e-5 s, the step refinement's cap) moves it by 4.9e-6
(``tests/test_step_error.py``). This module measures that move for a fitted member;
:mod:`.widening` widens the intervals it makes meaningless.

The measurement (:func:`measure_step_error`). Every likelihood term of the calibration is built
again at half the step it simulates at, as its own set-up builds it (:func:`halved_log_posterior`:
an open-loop record's edges placed again, each term's solver error measured again at the point the
calibration measured it at, the discrepancy factors kept). The half-step log posterior is evaluated
at a seeded subsample of the posterior's draws; its difference from the stored full-step one,
``D(z) = log p_half(z) - log p_full(z)``, is regressed linearly on the sampling coordinates ``z``:
``D ~ a + g . z``. Tilting a Gaussian posterior of covariance ``C`` by ``exp(g . z)`` moves it by
``C g`` and changes nothing else, whatever the size of the move; a half-step likelihood that is the
full-step one translated by ``m`` gives exactly ``g = C^-1 m``. So the posterior at half the step
is read as the draws translated by ``s = C g`` (``C`` from all the draws), and every quantity's
move is the change of its median over the translated draws: the sampled parameters', and the
combined ones' (:func:`tvcid.models.quantities.member_quantities`: DC gain, bandwidth,
threshold). On M000's bundled open-loop square the moves of the feedback gain and the delay are
within 8 % and 18 % of the moves of the maximum a posteriori; on the quiet square above, where the
move is four widths, the feedback gain's within 1.5 times; on the bundled sine, chains at 5e-4 and
2.5e-4 s (2000 draws each) move the feedback gain's and the delay's medians by 3.9e-6 and
-1.32e-5 (Monte Carlo error about 2.5e-6), read here from three subsamples as 4.3-5.8e-6 and
-1.29 to -1.54e-5.

Why not the alternatives. Importance weights ``exp(D)`` on the draws need the move to be well
under the posterior's width, and the case that matters is the one where it is not: their effective
sample size collapses exactly where the step error exceeds the width (3 % of the points on the
quiet square), leaving only "at least the width" (:attr:`StepError.ess` reports it as a
diagnostic). A local re-optimisation at both steps needs hundreds of simulations per optimum in
9-13 dimensions, and an optimiser's stopping tolerance on a likelihood that is rough at the step's
scale (switching events move by a step) is of the size of what is measured; the regression
averages that roughness over the posterior's extent, and its standard error says how much of it
is left.

The step error ``e`` of a quantity is ``SOLVER_ERROR_FACTOR`` (2) times its move plus the move's
standard error: at first order the answer at step ``dt`` is off from the converged one by twice
the change that halving shows (Richardson), the convention of :mod:`.likelihood.solver`; a move
the subsample cannot tell from its noise counts up to that noise. On M000's member (ten
parameters, four records) the delay's and the backlash's moves halve with the step (2.4 and 2.1
times smaller from ``dt / 2`` to ``dt / 4``), the linear block's fall faster (11-60 times), and
the band-pass loop's do not fall (its unlocked 9-10 Hz oscillation is resolved by no step), so
that for it the halving's move is a floor. :func:`.widening.widen_interval` widens a 90 % interval
narrower than ``2 e`` to at least ``q50 +- e``.

The same points give the member's log evidence at half the step
(:func:`log_evidence_ratio`: ``Z_half / Z_full = E_post[exp(D)]``), which the set's weights take
(:mod:`tvcid.discovery.members.set_weights`): structures whose switching events converge
differently can differ in evidence by what the step leaves unresolved.

Cost: on that member (converged after 430 steps, 8.8e5 simulated seconds with its start), the
default 80 points (8 per parameter) and the set-up cost 5,664 simulated seconds, 0.6 % of the
chain's (1.5 % of its RK4 steps: a halved step costs twice per simulated second), and 5-7 s.
"""
from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass, field

import numpy as np

from ..threads import one_blas_thread
from .likelihood.features import FeatureTerm
from .likelihood.open_loop import EDGE_CHECK_REFINEMENT, OpenLoopTerm
from .likelihood.solver import SOLVER_ERROR_FACTOR
from .likelihood.waveform import WaveformTerm
from .log_posterior import LogPosterior
from .priors import SIGMA

__all__ = [
    "StepError",
    "halved_log_posterior",
    "log_evidence_ratio",
    "measure_step_error",
    "tilt_shift",
    "STEP_ERROR_POINTS_PER_PARAMETER",
    "STEP_ERROR_MIN_POINTS",
]

#: Posterior draws at which the half-step log posterior is evaluated: this many per sampled
#: parameter ...
STEP_ERROR_POINTS_PER_PARAMETER = 8
#: ... and at least this many (the regression has ``n + 1`` coefficients).
STEP_ERROR_MIN_POINTS = 32
#: Seconds of the reference run a closed-loop warm start simulates
#: (:func:`tvcid.models.batch.warm_start_state`'s ``t_ref``), counted in the set-up's cost.
_WARM_START_SECONDS = 20.0
#: Draws the standard errors of the quantities' shifts are propagated with (a seeded normal
#: sample of the translation ``s``) ...
_SE_DRAWS = 32
#: ... over at most this many of the posterior's draws.
_SE_SUBSAMPLE = 1000


# -- the likelihood at half the step ------------------------------------------------------------
def _halve(term, start_params, at, warm, around=()):
    """A copy of ``term`` simulating at half its step, built as its own set-up builds it, its
    solver error measured at ``at`` (an ``ActuatorParams``; a features record's over ``at`` and
    ``around`` too, as its start measured it); ``(copy, runs)`` where ``runs`` lists the set-up's
    simulations as ``(seconds, step)``."""
    half = copy.copy(term)  # the original's arrays are shared, never written: every change rebinds
    h = float(term.simulator.dt) / 2.0
    runs = []
    if isinstance(term, OpenLoopTerm):
        half._build_for(at)  # its build closure bound to the copy
        half._build(h)
        end = float(term.tau[-1])
        if half.timing is not None:  # the edge check (:meth:`OpenLoopTerm.edge_loads`)
            runs += [(end, h)] * 3 + [(end, h / EDGE_CHECK_REFINEMENT)] * 2
            if not half.edges_on_grid:  # recentred, two passes
                runs += [(end, h)] * 2
        half.solver_var = None
        half.solver_var = half.waveform_solver_variance(at)
        runs += [(end, h), (end, h / 2)]
    elif isinstance(term, (FeatureTerm, WaveformTerm)):
        half.continuation = None  # a continuation's states are the full step's runs
        if isinstance(term, FeatureTerm):  # a settling record's start is sized again, from scratch
            half._start_rms, half._piece_simulator = None, None
        half._build_simulator(start_params, warm, h)
        end = float(half.simulator.t_end)
        piece = [] if getattr(term, "record_start", None) is None else [term.record_start[2]]
        if half.warm_start is not None:
            # the warm start, and a settling record's start sized twice (FeatureTerm), at h; the
            # step doubling's own warm start at h / 2
            runs += [(_WARM_START_SECONDS, h)] * (1 + 2 * len(piece)) + [(p, h) for p in piece] * 2
            runs += [(_WARM_START_SECONDS, h / 2)]
        points = 1
        if isinstance(term, FeatureTerm):  # the features' Richardson correction and its variance
            points = 1 + len(around)
            half.correct_over([at, *around], half.warm_start is not None)
        else:
            half.solver_var = None
            half.solver_var = half.waveform_solver_variance(at, warm)
        runs += ([(end, h), (end, h / 2)] + [(p, h) for p in piece] + [(p, h / 2) for p in piece]) * points
    else:
        raise TypeError(f"{type(term).__name__}: no half-step build for this likelihood term")
    return half, runs


def _step_check_point(calibration, posterior=None) -> dict:
    """Where the calibration measured its terms' solver error (natural coordinates): the start's
    maximum a posteriori, or on a resumed run the point its checkpoint kept; else the
    posterior's maximum."""
    point = getattr(calibration, "map_start_", None)
    if point is None and getattr(calibration, "backend", None) is not None:
        from .backend import H5_GROUP, CheckpointBackend

        with CheckpointBackend(str(calibration.backend), name="mcmc").open("r") as f:
            stored = f[H5_GROUP].attrs.get("step_check_at") if H5_GROUP in f else None
        point = json.loads(stored) if stored is not None else None
    if point is None and posterior is not None:
        point = posterior.map
    if point is None:
        raise ValueError("the calibration has no point its step was checked at: fit it first")
    return point


def _solver_check_points(calibration) -> list:
    """Where the calibration's start measured its features' solver correction (natural
    coordinates; the maximum a posteriori first); empty for a run whose checkpoint has none."""
    points = getattr(calibration, "solver_check_points_", None)
    return list(points) if points else []


def halved_log_posterior(calibration, at=None):
    """The calibration's log posterior with every term simulating at half its step.

    Each term is copied and rebuilt as its own set-up builds it at that step: a closed-loop
    record's warm start from the calibration's start values, an open-loop record's edges placed
    again (on the grid or where they are, :meth:`.likelihood.open_loop.OpenLoopTerm.edge_loads`),
    and each term's solver error (features: the Richardson correction; waveforms: the variance)
    measured at ``at`` against a quarter step (features: over the points the start measured its
    correction at, when ``at`` is left to its default). The discrepancy factors, the transients, a
    features record's start imprint, the priors and the noise sd are the calibration's: only the
    step differs. The calibration itself is left as it is.

    Parameters
    ----------
    calibration : Calibration
        A fitted (or set-up) calibration (``posterior.calibration``).
    at : dict, optional
        Natural coordinates of the sampled parameters where the solver error is measured;
        default the point the calibration measured its own at (the start's maximum a posteriori).

    Returns
    -------
    LogPosterior
        Over the halved terms; its ``simulated_seconds`` and ``simulated_steps`` start at the
        set-up's runs.
    """
    cal = calibration
    around = []
    if at is None:
        at = _step_check_point(cal, getattr(cal, "posterior_", None))
        around = _solver_check_points(cal)[1:]
    lp0 = cal.log_posterior_
    point = lp0.params_for(np.array([float(at[n]) for n in cal.names_]))
    if point is None:
        raise ValueError(f"no valid parameter set at {at}")
    others = [p for p in (lp0.params_for(np.array([float(x[n]) for n in cal.names_]))
                          for x in around) if p is not None]
    start = cal.base_.replace(**{n: v for n, v in cal.start_.items() if n != SIGMA})
    terms, runs = [], []
    for term in lp0.terms:
        half, r = _halve(term, start, point, bool(cal.warm_start), others)
        terms.append(half)
        runs += r
    lp = LogPosterior(lp0.base, lp0.names, dict(zip(lp0.names, lp0.priors)), terms, lp0.sigma)
    for seconds, dt in runs:
        lp.account_seconds(seconds, dt)
    return lp


# -- the posterior's move under a tilt ---------------------------------------------------------
def tilt_shift(draws, points, delta):
    """How far a posterior moves when its log density changes by ``delta`` at ``points``.

    ``delta`` is regressed on ``points`` (least squares, ``delta ~ a + g . z``); a Gaussian of
    the draws' covariance ``C`` tilted by ``exp(g . z)`` is the same Gaussian moved by ``C g``.

    Parameters
    ----------
    draws : ndarray (n, d)
        The posterior's draws (sampling coordinates), for ``C``.
    points : ndarray (m, d)
        Where ``delta`` was evaluated (``m > d + 1``).
    delta : ndarray (m,)
        The change of the log density there.

    Returns
    -------
    shift : ndarray (d,)
    cov : ndarray (d, d)
        The covariance of ``shift`` from the regression's residuals.
    residual_sd : float
        The residuals' sd (nats): what of ``delta`` is not a linear trend.
    """
    draws = np.atleast_2d(np.asarray(draws, dtype=float))
    z = np.atleast_2d(np.asarray(points, dtype=float))
    y = np.asarray(delta, dtype=float)
    m, d = z.shape
    if m <= d + 1:
        raise ValueError(f"tilt_shift: {m} points cannot fit {d + 1} coefficients with a residual")
    c = np.atleast_2d(np.cov(draws, rowvar=False))
    x = np.column_stack([np.ones(m), z - z.mean(axis=0)])
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    residual = y - x @ coef
    s2 = float(residual @ residual) / (m - d - 1)
    cov_g = s2 * np.linalg.pinv(x.T @ x)[1:, 1:]
    g = coef[1:]
    return c @ g, c @ cov_g @ c, math.sqrt(s2)


# -- the measurement -----------------------------------------------------------------------------
@dataclass
class StepError:
    """How far a calibrated member's answer moves when its simulation step is halved.

    Attributes
    ----------
    parameters : dict
        Sampled parameter -> ``shift`` (of the median, natural units, half step minus full), ``se``
        (its standard error from the regression's residuals) and ``error``
        (``SOLVER_ERROR_FACTOR * (|shift| + se)``, the step error
        :func:`.widening.widen_interval` takes).
    quantities : dict
        The same for the member's combined quantities
        (:func:`tvcid.models.quantities.member_quantities`); empty when not asked for.
    steps : dict
        Record -> ``[step, half step]`` (s).
    n_points : int
        Draws the half-step log posterior was evaluated at and finite at both steps ...
    n_failed : int
        ... and those where it was not (a run that fails, diverges or stops oscillating at one
        step only).
    residual_sd : float
        Nats of the log posterior's change that are not a linear trend over the draws (the
        likelihood's roughness at the step's scale).
    ess : float
        Effective sample size of the importance weights ``exp(D)`` over the points, as a fraction
        of them: near 1 the move is well under the posterior's width; near ``1 / n_points`` it is
        beyond it (the tilt still measures it).
    log_evidence_shift : float
        How far the member's log evidence moves when the step is halved (nats):
        ``log mean exp(D)`` over the points, the ratio of the two steps' evidences read from the
        posterior's draws (``Z_half / Z_full = E_post[exp(D)]``); ``log_evidence_shift_se`` its
        standard error. Two members whose evidences differ by less than their shifts' difference
        differ by what their step resolves, not by what the recordings tell.
    log_prob_sd : float
        The sd of the chain's log posterior over its draws (nats): how much the posterior's own
        draws differ in density. Where ``residual_sd`` exceeds it beyond its own noise, halving
        the step reorders the draws by more than they differ (:attr:`resolved`).
    simulated_seconds, simulated_steps : float
        The measurement's cost (set-up and evaluations); a halved step costs twice the RK4 steps
        per simulated second.
    """

    parameters: dict
    quantities: dict = field(default_factory=dict)
    steps: dict = field(default_factory=dict)
    n_points: int = 0
    n_failed: int = 0
    residual_sd: float = math.nan
    ess: float = math.nan
    log_evidence_shift: float = math.nan
    log_evidence_shift_se: float = math.nan
    log_prob_sd: float = math.nan
    simulated_seconds: float = 0.0
    simulated_steps: float = 0.0

    @property
    def resolved(self) -> bool:
        """Whether the step resolves the member: the half step's change of the log posterior,
        beyond a tilt, is not larger than the spread of the posterior's own log density by
        more than twice the residual sd's own relative error, ``1 / sqrt(2 dof)`` with ``dof``
        the regression's residual degrees of freedom. Where it is larger, the half-step
        posterior is not this one moved, and the errors are the regression's noise. Such a
        member: a features solver correction that does not hold at the posterior's draws (taken
        where halving the step moves the cycle's fundamental by several data sd, applied at draws
        where it moves it by a fraction of one,
        :meth:`.likelihood.features.FeatureTerm.solver_correction`); at half the step the
        correction nearly vanishes, and the draws reorder."""
        if not (math.isfinite(self.residual_sd) and math.isfinite(self.log_prob_sd)):
            return True
        dof = max(self.n_points - len(self.parameters) - 1, 1)
        return self.residual_sd <= self.log_prob_sd * (1.0 + 2.0 / math.sqrt(2.0 * dof))

    def error(self, name) -> float:
        """The step error of a combined quantity or, failing that, of a sampled parameter."""
        if name in self.quantities:
            return self.quantities[name]["error"]
        return self.parameters[name]["error"]

    @property
    def errors(self) -> dict:
        """Name -> step error, the combined quantities over the sampled parameters of the same
        name."""
        return {**{n: v["error"] for n, v in self.parameters.items()},
                **{n: v["error"] for n, v in self.quantities.items()}}

    def to_dict(self) -> dict:
        return {"parameters": self.parameters, "quantities": self.quantities,
                "steps": self.steps, "n_points": self.n_points, "n_failed": self.n_failed,
                "residual_sd": self.residual_sd, "log_prob_sd": self.log_prob_sd,
                "resolved": self.resolved, "ess": self.ess,
                "log_evidence_shift": self.log_evidence_shift,
                "log_evidence_shift_se": self.log_evidence_shift_se,
                "simulated_seconds": self.simulated_seconds, "simulated_steps": self.simulated_steps,
                "rule": f"step error = {SOLVER_ERROR_FACTOR:g} x (the median's move when the step "
                        "is halved + its standard error)"}


def log_evidence_ratio(delta) -> tuple:
    """``log(Z_half / Z_full)`` and its standard error from the change ``delta`` of the log
    posterior (half step minus full) at draws of the full-step posterior.

    ``Z_half / Z_full = E_post[exp(delta)]``: the half-step posterior's normalising constant over
    the full-step one's is the mean of the likelihoods' ratio under the full-step posterior,
    whatever the size of the change (importance sampling with the posterior as proposal). The
    standard error is the mean's, carried to its log (delta method).
    """
    delta = np.asarray(delta, dtype=float)
    if delta.size < 2 or not np.all(np.isfinite(delta)):
        raise ValueError(f"log_evidence_ratio needs at least 2 finite changes, not {delta.size}")
    w = np.exp(delta - delta.max())
    return (float(delta.max() + math.log(w.mean())),
            float(np.std(w, ddof=1) / (w.mean() * math.sqrt(w.size))))


def _median_shifts(values_at, z, shift, cov, rng):
    """Name -> ``(shift, se)`` of each quantity's median when the draws ``z`` move by ``shift``;
    ``values_at(z)`` gives name -> values. The standard error propagates ``cov`` by a seeded
    normal sample of the move over a subsample of the draws."""
    base = values_at(z)
    moved = values_at(z + shift)
    out = {n: float(np.nanmedian(moved[n]) - np.nanmedian(base[n])) for n in base}
    sub = z[rng.choice(len(z), size=min(len(z), _SE_SUBSAMPLE), replace=False)]
    sub_base = values_at(sub)
    centre = {n: np.nanmedian(v) for n, v in sub_base.items()}
    samples = {n: [] for n in base}
    for s in rng.multivariate_normal(shift, cov, size=_SE_DRAWS, method="eigh"):
        v = values_at(sub + s)
        for n in base:
            samples[n].append(float(np.nanmedian(v[n]) - centre[n]))
    return {n: (out[n], float(np.std(samples[n], ddof=1))) for n in base}


def _finite_sd(values) -> float:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.std(v)) if v.size > 1 else math.nan


def _entry(shift, se):
    # a move the subsample cannot tell from its noise still counts up to its standard error
    return {"shift": shift, "se": se, "error": SOLVER_ERROR_FACTOR * (abs(shift) + se)}


def measure_step_error(posterior, n_points=None, seed=0, quantities=True, params=None,
                       at=None):
    """Each sampled parameter's and combined quantity's step error in a calibrated member.

    The half-step log posterior (:func:`halved_log_posterior`) is evaluated at ``n_points``
    draws of the posterior (a seeded subsample); its difference from the chain's own log
    posterior there is regressed on the sampling coordinates and the posterior moved by the
    tilt that gives (:func:`tilt_shift`, the module's docstring). Cost: the set-up's runs and
    ``n_points`` evaluations at half the step, against the chain's ``n_walkers x steps``.

    Parameters
    ----------
    posterior : Posterior
        A calibration's posterior (``calibration.posterior_``; it holds its
        :class:`.calibration.Calibration` in ``posterior.calibration``).
    n_points : int, optional
        Default ``max(STEP_ERROR_MIN_POINTS, STEP_ERROR_POINTS_PER_PARAMETER * d)``.
    seed : int
        Seeds the subsample and the standard errors' draws.
    quantities : bool
        Also the combined quantities of
        :func:`tvcid.models.quantities.member_quantities`.
    params : dict, optional
        The fields not sampled, for those quantities (the member's fit, as its quantities are
        computed); default the calibration's base.
    at : dict, optional
        Where the half-step terms' solver error is measured (:func:`halved_log_posterior`).

    Returns
    -------
    StepError
    """
    cal = posterior.calibration
    if cal is None:
        raise ValueError("the posterior holds no calibration to build the half step from")
    rng = np.random.default_rng(seed)
    z_all = np.asarray(posterior.internal, dtype=float)
    n, d = z_all.shape
    m = int(n_points or max(STEP_ERROR_MIN_POINTS, STEP_ERROR_POINTS_PER_PARAMETER * d))
    if m > n:
        raise ValueError(f"{m} points asked of a posterior with {n} draws")
    idx = rng.choice(n, size=m, replace=False)
    points, full = z_all[idx], np.asarray(posterior.log_prob, dtype=float)[idx]
    lp0 = cal.log_posterior_
    # the chain's own log posterior, over the same terms, counting its runs apart from the chain's
    own = LogPosterior(lp0.base, lp0.names, dict(zip(lp0.names, lp0.priors)), lp0.terms, lp0.sigma)
    with one_blas_thread():  # the kernels own the cores (:mod:`tvcid.discovery.threads`)
        at = _step_check_point(cal, posterior) if at is None else at
        lp = halved_log_posterior(cal, at=at)
        half = np.asarray(lp(points), dtype=float)
        # the stored log posterior is the chain's; one point confirms that it is this likelihood
        again = float(np.ravel(own(points[:1]))[0])
        if not math.isclose(again, full[0], rel_tol=1e-9, abs_tol=1e-6):
            full = np.asarray(own(points), dtype=float)
    ok = np.isfinite(half) & np.isfinite(full)
    if ok.sum() <= d + 1:
        raise ValueError(f"the half-step log posterior is finite at {int(ok.sum())} of {m} draws: "
                         "too few to measure the step error")
    delta = half[ok] - full[ok]
    shift, cov, residual_sd = tilt_shift(z_all, points[ok], delta)
    w = np.exp(delta - delta.max())
    ess = float(w.sum() ** 2 / (w @ w)) / delta.size
    evidence_shift, evidence_shift_se = log_evidence_ratio(delta)

    names = list(posterior.names)
    priors = lp0.priors

    def natural(z):
        return {nm: p.to_natural(z[:, j]) for j, (nm, p) in enumerate(zip(names, priors))}

    sampled = _median_shifts(natural, z_all, shift, cov, rng)
    combined = {}
    if quantities:
        from tvcid.models.quantities import member_quantities

        fit = cal.base_.to_dict() if params is None else dict(params)

        def composite(z):
            x = natural(z)
            return member_quantities(fit, {k: v for k, v in x.items() if k != SIGMA})

        combined = _median_shifts(composite, z_all, shift, cov, rng)
    return StepError(
        parameters={k: _entry(*v) for k, v in sampled.items()},
        quantities={k: _entry(*v) for k, v in combined.items()},
        steps={t.name: [float(t0.simulator.dt), float(t.simulator.dt)]
               for t0, t in zip(lp0.terms, lp.terms)},
        n_points=int(ok.sum()), n_failed=int(m - ok.sum()), residual_sd=residual_sd, ess=ess,
        log_evidence_shift=evidence_shift, log_evidence_shift_se=evidence_shift_se,
        log_prob_sd=_finite_sd(posterior.log_prob),
        simulated_seconds=lp.simulated_seconds + own.simulated_seconds,
        simulated_steps=lp.simulated_steps + own.simulated_steps)
