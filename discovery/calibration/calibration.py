"""``Calibration``: the Bayesian calibration of a hypothesis on recordings (issue 5).

sklearn-style: ``__init__`` only stores its arguments; :meth:`Calibration.fit` validates them,
builds the likelihood terms and the log posterior, runs (or resumes) the ensemble and returns
``self``; what it learns ends in ``_`` (``posterior_``, ``report_``, ``sampler_``, ...).
"""
from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np

from models.hypotheses import ActuatorParams
from models.hypotheses import hypothesis as get_hypothesis
from models.recording import load_recordings

from ..threads import one_blas_thread
from .backend import CheckpointBackend
from .likelihood import (
    DEFAULT_FEATURES,
    LIKELIHOODS,
    SETTLING_PERTURBATION,
    FeatureTerm,
    IllPosedLikelihoodWarning,
    WaveformTerm,
    make_term,
)
from .log_posterior import LogPosterior, check_parameter_names
from .posterior import Posterior
from .priors import SIGMA, Prior, default_prior, ridge_coordinates
from .runner import run_ensemble

__all__ = ["Calibration", "truths_from_recordings"]

_H5_GROUP = "tvcid"


def truths_from_recordings(recordings, names, hypothesis_name):
    """Parameter values a simulated recording was made with (``None`` where unknown)."""
    truths = {}
    for rec in recordings:
        meta = rec.meta
        if meta.get("source") != "simulated":
            continue
        params = meta.get("parameters") or {}
        same = str(meta.get("hypothesis", "")).lower() == str(hypothesis_name).lower()
        for n in names:
            if n == SIGMA and "sensor_noise_sd" in meta:
                truths.setdefault(n, float(meta["sensor_noise_sd"]))
            elif same and n in params:
                truths.setdefault(n, float(params[n]))
    return {n: truths.get(n) for n in names}


#: Default RK4 step per likelihood (s). The waveform's was 2.5e-4 s while RK4 sampled the friction
#: offset's jump at its stages: the ridge case's cycle then locked its period to the 5e-4 s grid
#: (1574 steps for delays within +-2 %) and every posterior sample beat the truth. With the jump
#: located inside the step (``models.nonlinearities.sign_switch_average``) the same case at 5e-4 s
#: converged in 260 steps (27 s) with all four truths inside (HPD rank 0.30), against 970 steps
#: (159 s) at 2.5e-4 s; records that need a finer step still get one (``_refine_step``). The
#: features' first-order error is corrected instead.
DEFAULT_DT = {"waveform": 5e-4, "features": 5e-4}
#: Transients (s) tried below the given one, the reference they are checked against (at least
#: twice the given one) and the largest log-likelihood error (nats) a chosen one may make
#: (:meth:`Calibration._choose_transients`).
TRANSIENT_CANDIDATES = (2.0, 3.0, 4.0)
TRANSIENT_REFERENCE = 12.0
TRANSIENT_TOLERANCE = 0.5
#: Nats (at the noise) a waveform record's simulated cycle, started larger than the record's,
#: may still move between transients of ``max(TRANSIENT_REFERENCE, 2 transient)`` and twice that
#: at the maximum a posteriori before the record enters through its features
#: (:meth:`Calibration._fall_back_slow`).
SETTLING_LOAD_LIMIT = 2.0
#: Transient (s) of a record that fell back to its features (at least the given one): the
#: coverage benchmark's, whose calibration the features' table measures; a slowly attracting
#: cycle needs it (coverage draw 0 at 12 s: dead zone and friction offset outside at rank 1.00).
FALLBACK_TRANSIENT = 20.0


class Calibration:
    """Posterior over chosen parameters of a hypothesis, given one or more recordings.

    Parameters
    ----------
    hypothesis : str or ActuatorParams
        A hypothesis name (``models.hypothesis``) or a parameter object; every parameter not
        sampled keeps its value (after ``fixed``).
    params : sequence of str
        Sampled parameters: fields of the hypothesis and/or ``"sigma"`` (sensor-noise sd, rad).
    priors : dict name -> Prior, optional
        Declared priors; the rest get :func:`.priors.default_prior` around their start value.
    fixed : dict, optional
        Overrides of non-sampled fields (and ``"sigma"`` when it is not sampled; default: the
        noise level estimated from the recordings).
    start : dict, optional
        Starting values (default: the hypothesis' values, the estimated noise for sigma).
    likelihood : {"waveform", "features"}
        How closed-loop records enter: their phase-aligned output error (a record where it is
        ill-posed falls back to its features, ``features_fallback``), or their limit-cycle
        features as a Gaussian. Open-loop records always enter through their output error.
    features : sequence of str
        Features of the features likelihood (``frequency``, ``amplitude``, ``Hk``).
    window : float or None
        Seconds of each closed-loop recording used (its end); ``None`` for all of it.
    transient : float
        Seconds simulated before the compared window (after the warm start).
    features_fallback : bool
        With the waveform likelihood, a closed-loop record whose phase-aligned waveform is
        ill-posed enters through its limit-cycle features instead (said in an
        :class:`.likelihood.IllPosedLikelihoodWarning`): a simulated cycle that is not periodic
        (the band-pass loop's; decided at the start), or one that attracts so slowly that its
        recording may still be settling (decided at the maximum a posteriori, which is then
        searched again with the features; :meth:`_fall_back_slow`). The features measure a
        record's settling and a run's start imprint; the waveform reads both as parameters.
        Learned attributes ``likelihoods_`` (record -> ``"waveform"``, ``"features"`` or
        ``"open"``) and ``fallbacks_`` (record -> reason), kept in the checkpoint. ``False``
        keeps the waveform everywhere (and only warns of a cycle that is not periodic).
    choose_transient : bool
        Waveform records: once the walkers are placed, simulate before each record's window the
        shortest of ``TRANSIENT_CANDIDATES`` below ``transient`` whose log-likelihood stays within
        ``TRANSIENT_TOLERANCE`` nats of a ``TRANSIENT_REFERENCE`` one at the walkers and at as many
        points twice as far out; ``transient`` itself if none does; the reference if not even
        ``transient`` does (:meth:`_choose_transients`). Learned attributes ``transients_``
        (record -> seconds) and ``transient_errors_`` (record -> {seconds: largest error}).
    continuation : bool
        Start each closed-loop run from the end state of the stored run nearest its parameters
        (within ``CONTINUATION_RADIUS``; :meth:`.likelihood._ClosedLoopTerm.continue_runs`), so
        that a proposal continues its walker's cycle. Off by default: on M002's record it cuts
        the worst log-likelihood error of proposals 0.3 % from their walkers (walkers 0.5-2 % off
        the truth, against a 12 s transient) from 121 to 8 nats at a 3 s transient and from 9.9
        to 0.9 at 6 s, but not the median (0.40 and 0.22 nats shared, 0.59 and 0.10 continued:
        a nearby cycle is approached slowly). Over the calibration benchmark's seven M002 seeds
        (``studies.benchmarks.calibration --continuation``; 99.6 % of the runs continued) the
        posteriors sit within 0.10 half-widths of a 12 s transient's at 6 s and at 3 s (0.15 and
        0.08 without it) and the cost to convergence does not drop (median simulated seconds
        35,729 at 6 s against 38,740 without; 35,794 at 3 s against 24,359 without, chains of
        140-280 steps); a resumed chain, whose stored states are not checkpointed, would not
        repeat the uninterrupted one.
    dt : float or None
        RK4 step of the simulations (each output-error record may halve it further,
        :meth:`.likelihood._WaveformSolverError._refine_step`). Default ``DEFAULT_DT``: 5e-4 s.
        Learned attribute ``dt_``: the step used.
    n_walkers, max_steps, tau_factor
        Ensemble size, step cap, ``N > tau_factor * tau``.
    moves : emcee moves, optional
        Default: DEMove/DESnookerMove mix.
    pool : object with ``.map``, optional
        Walker batches are mapped over it (multiprocessing, MPI, Dask executors).
    backend : str, Path or None
        HDF5 file (emcee ``HDFBackend``) to checkpoint to and resume from.
    seed : int
    progress : bool
    warm_start : bool
        Start closed-loop runs on a scaled reference cycle.
    optimize_start : bool
        Find the maximum a posteriori (Nelder-Mead) before placing the walkers around it.
    stop_when_converged : bool
        False runs every chain to ``max_steps`` (e.g. to map a ridge).
    discrepancy : bool
        Inflate each recording's likelihood for model discrepancy, set once at the maximum a
        posteriori (:func:`.likelihood.waveform_inflation`, :func:`.likelihood.features_inflation`):
        a wrong or slightly wrong model then gets intervals as wide as its misfit warrants instead
        of needles; a right model keeps factor 1. Stored in the checkpoint so a resumed chain uses
        the same factors. Learned attribute ``inflation_`` (one factor per recording).
    spread : {"axes", "hessian"}
        Initial walkers around the maximum a posteriori: a ball with each axis' own sd, or along
        the principal axes of the Hessian there, spread over the prior along ridges the data do not
        constrain (:func:`_principal_axes`).
    laplace_move : bool
        When the posterior at the maximum a posteriori is close enough to its Laplace
        approximation (:func:`laplace_covariance`), nine steps in ten are independence proposals
        from a widened t around it (:class:`.moves.LaplaceIndependenceMove`), refitted once to
        the chain after ``LAPLACE_ADAPT_STEPS``; the rest are DE moves (unless ``moves`` is
        given). Otherwise the move waits idle (share 0) for that refit, which tries it on the
        chain's mean and covariance and keeps it only if it would be accepted often enough.
        Learned attribute ``laplace_`` (mean, covariance in sampling coordinates and the move's
        share), kept in the checkpoint for a resumed chain.
    global_search : bool
        Where the local optimum leaves a discrepancy, look for a better one over the whole prior
        box (differential evolution) and with a short ensemble run (:meth:`_scout`) before the
        inflation is set. ``False`` when the start already is a global search's optimum on the
        same recordings (``tvcid discover``'s winner): a misfit left there is the model's, and
        both searches only repeat that search (M000's four records: 37 s and 20 s of the stage's
        123 s, the same optimum).
    check_every : int
        Steps between convergence checks (``N > tau_factor * tau``; an autocorrelation estimate
        costs far less than a step's simulations, so the chain stops within 10 steps of where
        it could).
    """

    def __init__(self, hypothesis, params=("backlash", "dead_zone", "delay", SIGMA),
                 priors=None, fixed=None, start=None, likelihood="waveform",
                 features=DEFAULT_FEATURES, window=10.0, transient=6.0, features_fallback=True,
                 choose_transient=True, continuation=False,
                 dt=None, n_walkers=16,
                 max_steps=4000, check_every=10, tau_factor=50.0, moves=None, pool=None,
                 backend=None, seed=0, progress=False, warm_start=True, optimize_start=True,
                 stop_when_converged=True, spread="axes", discrepancy=True, laplace_move=True,
                 global_search=True):
        self.hypothesis = hypothesis
        self.params = params
        self.priors = priors
        self.fixed = fixed
        self.start = start
        self.likelihood = likelihood
        self.features = features
        self.window = window
        self.transient = transient
        self.features_fallback = features_fallback
        self.choose_transient = choose_transient
        self.continuation = continuation
        self.dt = dt
        self.n_walkers = n_walkers
        self.max_steps = max_steps
        self.check_every = check_every
        self.tau_factor = tau_factor
        self.moves = moves
        self.pool = pool
        self.backend = backend
        self.seed = seed
        self.progress = progress
        self.warm_start = warm_start
        self.optimize_start = optimize_start
        self.stop_when_converged = stop_when_converged
        self.spread = spread
        self.discrepancy = discrepancy
        self.laplace_move = laplace_move
        self.global_search = global_search

    # -- set-up ---------------------------------------------------------------------------------
    def _base(self):
        h = self.hypothesis
        if isinstance(h, ActuatorParams):
            base = h
        else:
            base = get_hypothesis(h)
        fixed = dict(self.fixed or {})
        fixed.pop(SIGMA, None)
        return base.replace(**fixed) if fixed else base

    def _config(self):
        return {
            "hypothesis": self.base_.name,
            "base": self.base_.to_dict(),
            "params": list(self.names_),
            "priors": {n: p.describe() for n, p in self.priors_.items()},
            "likelihood": self.likelihood,
            "features": list(self.features),
            "window": self.window,
            "transient": self.transient,
            "dt": self.dt_,
            "n_walkers": self.n_walkers,
            "recordings": [t.describe()["name"] for t in self.terms_],
            "discrepancy": bool(self.discrepancy),
            # only when on: checkpoints written before the option existed still resume
            **({"continuation": True} if self.continuation else {}),
            **({"choose_transient": True} if self._chooses_transient() else {}),
            # only when a record fell back: older checkpoints still resume
            **({"fallbacks": sorted(self.fallbacks_)} if getattr(self, "fallbacks_", None) else {}),
        }

    def setup(self, recordings):
        """Validate and build everything :meth:`fit` needs, without sampling; returns ``self``."""
        if self.likelihood not in LIKELIHOODS:
            raise ValueError(
                f"unknown likelihood {self.likelihood!r}; choose one of {', '.join(LIKELIHOODS)}"
            )
        for name in ("n_walkers", "max_steps"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be a positive integer (got {v!r})")
        dt = DEFAULT_DT[self.likelihood] if self.dt is None else self.dt
        if not (isinstance(dt, (int, float)) and dt > 0):
            raise ValueError(f"dt must be > 0 (got {dt!r})")
        self.dt_ = float(dt)
        if self.spread not in ("axes", "hessian"):
            raise ValueError(f"spread must be 'axes' or 'hessian' (got {self.spread!r})")
        if self.transient < 0:
            raise ValueError(f"transient must be >= 0 (got {self.transient})")
        base = self._base()
        names = check_parameter_names(self.params, base)
        priors = dict(self.priors or {})
        unknown = sorted(set(priors) - set(names))
        if unknown:
            raise ValueError(f"priors given for parameters that are not sampled: {', '.join(unknown)}")
        for n, p in priors.items():
            if not isinstance(p, Prior):
                raise TypeError(f"prior of {n!r} must be a Prior (Uniform/LogUniform), got {p!r}")
        start = dict(self.start or {})
        bad = sorted(set(start) - set(names))
        if bad:
            raise ValueError(f"start values given for parameters that are not sampled: {', '.join(bad)}")
        if 2 * len(names) > self.n_walkers:
            raise ValueError(
                f"n_walkers ({self.n_walkers}) must be at least twice the number of sampled "
                f"parameters ({len(names)})"
            )
        self.recordings_ = load_recordings(recordings)
        rng = np.random.default_rng(self.seed)
        self.terms_ = []
        for i, rec in enumerate(self.recordings_):
            name = rec.path.stem if rec.path is not None else f"recording{i}"
            self.terms_.append(make_term(rec, self.likelihood, self.window, self.transient,
                                         self.dt_, name=name, features=self.features, rng=rng))
        self.sigma_hat_ = float(np.sqrt(np.mean([t.sigma_hat**2 for t in self.terms_])))
        sigma_fixed = float((self.fixed or {}).get(SIGMA, self.sigma_hat_))
        start_values = {}
        for n in names:
            if n in start:
                start_values[n] = float(start[n])
            elif n == SIGMA:
                start_values[n] = self.sigma_hat_
            else:
                start_values[n] = float(getattr(base, n))
            if n not in priors:
                priors[n] = default_prior(n, start_values[n], dt=self.dt_)
            p = priors[n]
            if not p.low <= start_values[n] <= p.high:
                raise ValueError(
                    f"start value of {n} ({start_values[n]:g}) lies outside its prior "
                    f"[{p.low:g}, {p.high:g}]"
                )
        self.base_ = base
        self.names_ = names
        self.priors_ = ridge_coordinates(priors, names, base)
        self.start_ = start_values
        start_params = base.replace(**{n: v for n, v in start_values.items() if n != SIGMA})
        self.fallbacks_ = {}
        self.transients_, self.transient_errors_ = {}, {}  # set once the walkers are placed
        not_periodic = []
        for i, term in enumerate(self.terms_):
            if isinstance(term, WaveformTerm) and self.features_fallback:
                with warnings.catch_warnings():  # said in _fall_back, with what is done
                    warnings.simplefilter("ignore", IllPosedLikelihoodWarning)
                    term.setup(start_params, warm_start=self.warm_start)
                if not term.periodic:
                    not_periodic.append((i, term.not_periodic()))
            else:
                term.setup(start_params, warm_start=self.warm_start)
        self.log_posterior_ = LogPosterior(base, names, self.priors_, self.terms_, sigma_fixed)
        for i, reason in not_periodic:
            self._fall_back(i, reason)
        for term in self.terms_:
            if self.continuation and hasattr(term, "continue_runs"):
                term.continue_runs()
        self.inflation_ = [t.inflation for t in self.terms_]
        self.likelihoods_ = _likelihoods(self.terms_)
        self.truths_ = truths_from_recordings(self.recordings_, names, base.name)
        return self

    def _fall_back(self, i, reason, save=False):
        """Record ``i`` enters through its limit-cycle features from now on (its waveform is
        ill-posed: ``reason``), said in an :class:`.likelihood.IllPosedLikelihoodWarning`; kept
        in the checkpoint when ``save``."""
        old = self.terms_[i]
        warnings.warn(IllPosedLikelihoodWarning(
            f"{reason}; this record enters through its limit-cycle features"), stacklevel=3)
        start = self.base_.replace(**{n: v for n, v in self.start_.items() if n != SIGMA})
        term = FeatureTerm(old.recording, self.window,
                           max(float(self.transient), FALLBACK_TRANSIENT), self.dt_,
                           name=old.name, features=self.features,
                           rng=np.random.default_rng([int(self.seed), i]))
        term.noise_from_sigma = False  # the record's own noise estimate, not the sampled sd
        term.setup(start, warm_start=self.warm_start)
        term.inflation = old.inflation
        self.terms_[i] = term
        self.log_posterior_.terms[i] = term
        self.fallbacks_[term.name] = reason
        self.likelihoods_ = _likelihoods(self.terms_)
        if save and self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(_H5_GROUP).attrs["fallbacks"] = json.dumps(self.fallbacks_)

    def _fall_back_slow(self, lp, z0) -> bool:
        """Waveform records whose cycle attracts slowly at ``z0`` (the maximum a posteriori) fall
        back to their features; True if any did.

        Slowly: a run of ``z0`` started ``SETTLING_PERTURBATION`` larger than the record's cycle
        still moves by over ``SETTLING_LOAD_LIMIT`` nats between transients of
        ``max(TRANSIENT_REFERENCE, 2 transient)`` s and twice that
        (:meth:`.likelihood.WaveformTerm.settling_load`). Measured at the maximum, whose own
        cycle has the record's size, so that a start far off does not count its own distance
        (coverage draw 22 at its truth: 990 nats; M002 and the ridge case: 0.0-0.11).
        """
        params = lp.params_for(lp.natural(z0)[0])
        if params is None:
            return False
        short = max(TRANSIENT_REFERENCE, 2.0 * float(self.transient))
        fell = False
        for i, term in enumerate(self.terms_):
            if not isinstance(term, WaveformTerm):
                continue
            load = term.settling_load(params, short, 2.0 * short)
            lp.account_seconds(term.settling_seconds(2.0 * short), term.simulator.dt)
            if load > SETTLING_LOAD_LIMIT:
                self._fall_back(i, (
                    f"{term.name}: its simulated cycle attracts slowly (at the maximum a posteriori, "
                    f"started {SETTLING_PERTURBATION:.0%} larger, it still moves by {load:.3g} "
                    f"nats at the noise between transients of {short:g} and {2 * short:g} s), so "
                    "the recording may still be settling and runs carry their start, both of "
                    "which a waveform comparison would read as parameters"), save=True)
                fell = True
        return fell

    # -- initial positions ----------------------------------------------------------------------
    def _initial(self, rng):
        lp = self.log_posterior_
        z0 = lp.internal(np.array([[self.start_[n] for n in self.names_]]))[0]
        if self.optimize_start:
            z0 = self._maximum(lp, z0, rng)
        if self.features_fallback and self._fall_back_slow(lp, z0) and self.optimize_start:
            z0 = self._maximum(lp, z0, rng)  # the features' own maximum, from the waveform's
        self.map_start_ = dict(zip(self.names_, lp.natural(z0)[0].tolist()))
        self._refine_steps_at(self.map_start_)
        if self.discrepancy:
            self._set_inflation(lp, z0)
            for _ in range(SCOUT_ROUNDS if self.global_search else 0):
                # each round from the last one's better point
                better = self._scout(lp, z0, rng) if max(self.inflation_) > 1.0 else None
                if better is None:
                    break
                z0 = better
                self.map_start_ = dict(zip(self.names_, lp.natural(z0)[0].tolist()))
                self._refine_steps_at(self.map_start_)
                self._set_inflation(lp, z0)
        scale = _axis_scales(lp, z0)
        axes = np.diag(0.5 * scale)
        hess = _hessian(lp, z0, scale) if (self.spread == "hessian" or self.laplace_move) else None
        if self.spread == "hessian":
            axes = _principal_axes(lp, z0, scale, hess)
        self.laplace_ = None
        if self.laplace_move:
            self._start_laplace(lp, z0, hess, axes)
        self.initial_axes_ = axes
        out = self._walkers_around(lp, z0, axes, rng)
        if out is None:
            raise RuntimeError("could not place the walkers where the posterior is finite")
        if self._chooses_transient():
            self._choose_transients(lp, z0, axes, out, rng)
        if self._set_transient_variance(lp, out) and self.discrepancy:
            self._set_inflation(lp, z0)  # measured against the widened covariance
        return out

    def _start_laplace(self, lp, z0, hess, axes):
        """``laplace_`` at the start: the Laplace approximation at ``z0`` where it can serve as a
        proposal (:func:`laplace_covariance`), else the move idle (share 0) until its first refit
        to the chain (:meth:`_adapt_laplace`), which keeps it only if it would be accepted often
        enough. Idle covers a curvature not resolved at an optimum not quite reached (M002, 2
        noise seeds of 7: an eigenvalue of -164 beside 2e4-2e11; without the move the chains
        took 710-750 steps instead of 90-130) and a maximum on a prior bound or on a ridge the
        prior cuts, where the Hessian cannot be had (coverage draw 20: its optimum at friction
        offset 0; with the DE moves alone 1500 steps, tau 26-81, not converged; idle, then on
        from its third retry at step 400: converged in 680 steps, tau 5-7, the same
        intervals)."""
        cov = laplace_covariance(lp, z0, hess)
        if cov is not None:
            self.laplace_ = {"mean": z0.tolist(), "cov": cov.tolist()}
        else:
            self.laplace_ = {"mean": z0.tolist(), "cov": (axes @ axes.T).tolist(), "share": 0.0}

    def _maximum(self, lp, z0, rng):
        """The maximum a posteriori from ``z0`` (internal coordinates): Nelder-Mead, then, where
        a recording still shows a misfit, the global search and restarts (:meth:`_polish`)."""
        from scipy.optimize import minimize

        z0 = _profile_sigma(lp, z0, self.names_)
        res = minimize(_cost(lp), z0,
                       method="Nelder-Mead",
                       options={"maxfev": 150 * len(z0), "xatol": 1e-6, "fatol": 0.05,
                                "initial_simplex": _simplex(z0, lp)})
        if np.isfinite(lp(res.x)):
            z0 = _profile_sigma(lp, res.x, self.names_)
        searched = (self.discrepancy and self.global_search
                    and self._suspect_optimum(lp, z0))
        if searched:
            z0 = _global_start(lp, z0, int(rng.integers(2**31)), self.names_)
        if self.discrepancy:
            z0, factors = self._polish(lp, z0)
            if self.global_search and not searched and max(factors) > 1.0:
                # still a misfit: a local optimum (the ridge case: 448 nats under the
                # truth) or a wrong model; the global search tells them apart
                z0, _ = self._polish(lp, _global_start(lp, z0, int(rng.integers(2**31)),
                                                       self.names_))
        return z0

    def _walkers_around(self, lp, z0, axes, rng):
        """``n_walkers`` points ``z0 + axes @ N(0, 1)`` where the posterior is finite (the first
        ones drawn, in at most 100 batches), or None."""
        found = []
        for _ in range(100):
            trial = z0 + rng.standard_normal((self.n_walkers, len(z0))) @ axes.T
            found.extend(trial[np.isfinite(lp(trial))])
            if len(found) >= self.n_walkers:
                return np.asarray(found[: self.n_walkers])
        return None

    def _refine_steps_at(self, point, save=True):
        """Each output-error term's simulation step checked again at ``point`` (natural
        coordinates; the maximum a posteriori), never coarser than set up
        (:meth:`.likelihood._WaveformSolverError.refine_at`); ``point`` is kept in the
        checkpoint so that a resumed run rebuilds the same likelihood."""
        params = self.log_posterior_.params_for(np.array([point[n] for n in self.names_]))
        if params is None:
            return
        for term in self.terms_:
            if hasattr(term, "refine_at"):
                term.refine_at(params)
        if save and self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(_H5_GROUP).attrs["step_check_at"] = json.dumps(point)

    def _transient_terms(self):
        """The closed-loop waveform terms (open-loop records have no transient)."""
        return [t for t in getattr(self, "terms_", [])
                if getattr(t, "kind", "") == "waveform" and hasattr(t, "set_transient")]

    def _chooses_transient(self) -> bool:
        return bool(self.choose_transient) and bool(self._transient_terms())

    def _choose_transients(self, lp, z0, axes, walkers, rng):
        """Each waveform record's transient, chosen by the accuracy it gives (issue 12, item 4).

        Check points: the walkers and as many points ``z0 + 2 axes N(0, 1)`` (where a chain
        goes). The log-likelihood at each candidate transient is compared with the reference's
        (``max(TRANSIENT_REFERENCE, 2 * transient)``); the shortest candidate whose largest error
        is within ``TRANSIENT_TOLERANCE`` nats is kept. On M002's 10 s record (seeds 1-4) the
        errors at the walkers and twice as far were at most 1.04 nats at 2 s, 0.22 at 3 s, 0.11
        at 4 s and 0.28 at 6 s; 0.5-2 % off the truth, outside the posterior, 3 s is 121 nats
        off, which no chain visits. Kept in the checkpoint.
        """
        wide = z0 + 2.0 * rng.standard_normal((len(walkers), len(z0))) @ axes.T
        points = np.vstack([walkers, wide])
        _, x, sets = lp._prepare(points)
        keep = [i for i, p in enumerate(sets) if p is not None]
        sets = [sets[i] for i in keep]
        sigma = lp.sigmas(x[keep])
        given = float(self.transient)
        reference = max(TRANSIENT_REFERENCE, 2.0 * given)
        self.transients_, self.transient_errors_ = {}, {}
        for term in self._transient_terms() if sets else []:
            term.set_transient(reference)
            ref = term.loglike(sets, sigma)
            lp.account(len(sets), [term])  # the check's runs count in the cost
            errors, chosen = {}, reference
            for t in sorted({c for c in TRANSIENT_CANDIDATES if c < given} | {given}):
                term.set_transient(t)
                ll = term.loglike(sets, sigma)
                lp.account(len(sets), [term])
                # a run that fails at both lengths agrees; one that fails at one only does not
                both_failed = ~np.isfinite(ll) & ~np.isfinite(ref)
                d = np.where(both_failed, 0.0, np.abs(ll - ref))
                errors[t] = float(np.max(np.where(np.isfinite(d), d, np.inf)))
                if errors[t] <= TRANSIENT_TOLERANCE:
                    chosen = t
                    break
            term.set_transient(chosen)
            self.transients_[term.name] = chosen
            self.transient_errors_[term.name] = errors
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(_H5_GROUP).attrs["transients"] = json.dumps(self.transients_)

    def _set_transient_variance(self, lp, z) -> bool:
        """Each features term's start imprint (:meth:`.likelihood.FeatureTerm.transient_variance`)
        over the walkers' starting points ``z``, kept in the checkpoint; True if any is nonzero.

        The waveform term has none: its imprint is correlated over the window (draw 20's truth:
        0.18 noise sd per sample, 249 nats over 10,000 samples), which a per-sample variance
        would not cover."""
        terms = [t for t in self.terms_ if hasattr(t, "transient_variance")]
        if not terms:
            return False
        x = lp.natural(z)
        sets = [p for p in (lp.params_for(row) for row in x) if p is not None]
        for term in terms:
            term.set_transient_variance(term.transient_variance(sets))
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                g = f.require_group(_H5_GROUP).require_group("transient_var")
                for term in terms:
                    if term.name in g:
                        del g[term.name]
                    g.create_dataset(term.name, data=term.transient_var)
        return any(np.any(t.transient_var > 0) for t in terms)

    def _polish(self, lp, z0):
        """Nelder-Mead restarted along the principal axes at its optimum while that optimum
        leaves some recording a discrepancy factor over 1 and the restart gains over
        ``POLISH_GAIN`` nats (at most ``POLISH_RESTARTS`` times); ``(z0, factors there)``.

        The factor is measured where the search stopped; on a ridge an axis-aligned simplex stops
        short of the maximum, and the misfit there reads as model discrepancy (the ridge case:
        factors 1.6 and 2.9 for the right model, 1.0 at the truth), widening a right model's
        intervals by up to 70 %. A right model at its maximum keeps 1, so a restart is owed
        only while the factor is over 1.
        """
        from scipy.optimize import minimize

        ndim = len(z0)
        factors = self._inflations_at(lp, z0)
        for _ in range(POLISH_RESTARTS):
            if max(factors) <= 1.0:
                break
            scale = _axis_scales(lp, z0)
            axes = _principal_axes(lp, z0, scale, _hessian(lp, z0, scale))
            simplex = np.vstack([z0, z0[None, :] + axes.T])
            res = minimize(_cost(lp), z0, method="Nelder-Mead",
                           options={"maxfev": 100 * ndim, "xatol": 1e-6, "fatol": 0.05,
                                    "initial_simplex": simplex})
            before = float(np.ravel(lp(z0))[0])
            if not float(np.ravel(lp(res.x))[0]) > before + POLISH_GAIN:
                break
            z0 = _profile_sigma(lp, res.x, self.names_)
            factors = self._inflations_at(lp, z0)
        return z0, factors

    def _scout(self, lp, z0, rng):
        """A better maximum than ``z0`` found by a short ensemble run, or None.

        A discrepancy factor over 1 is measured at the optimum the searches returned; when they
        stopped short of the maximum, a right model reads as a wrong one (coverage draw 23, one
        limit cycle: factor 30 at that point, 1.0 at the truth, intervals widened to 108-400 %).
        ``SCOUT_STEPS`` steps of DE moves under the inflated likelihood (wide, so the walkers
        roam) from around ``z0``; their best points are compared with ``z0`` without the
        inflation, and the best, polished, is returned if it gains over ``POLISH_GAIN`` nats.
        """
        import emcee

        ndim = len(z0)
        scale = _axis_scales(lp, z0)
        start = self._walkers_around(lp, z0, _principal_axes(lp, z0, scale, _hessian(lp, z0, scale)),
                                     rng)
        if start is None:
            return None
        sampler = emcee.EnsembleSampler(self.n_walkers, ndim, lp, vectorize=True,
                                        moves=[(emcee.moves.DEMove(), 0.8),
                                               (emcee.moves.DESnookerMove(), 0.2)])
        sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
        sampler.run_mcmc(start, SCOUT_STEPS, progress=False)
        flat, logp = sampler.get_chain(flat=True), sampler.get_log_prob(flat=True)
        candidates = flat[np.argsort(logp)[::-1][:SCOUT_CANDIDATES]]
        kept = [t.inflation for t in self.terms_]
        for t in self.terms_:  # compared on the searches' own objective
            t.inflation = 1.0
        try:
            values = np.asarray(lp(candidates), dtype=float)
            before = float(np.ravel(lp(z0))[0])
            if not np.nanmax(values) > before + POLISH_GAIN:
                return None
            z = _nelder_mead_from(lp, candidates[int(np.nanargmax(values))])
            z, _ = self._polish(lp, _profile_sigma(lp, z, self.names_))
            return z if float(np.ravel(lp(z))[0]) > before + POLISH_GAIN else None
        finally:
            for t, v in zip(self.terms_, kept):
                t.inflation = v

    def _inflations_at(self, lp, z0) -> list:
        """Each term's discrepancy inflation at ``z0`` (inf everywhere if ``z0`` is invalid)."""
        x = lp.natural(z0)[0]
        params = lp.params_for(x)
        if params is None:
            return [math.inf] * len(self.terms_)
        sigma = float(lp.sigmas(x[None, :])[0])
        return [float(t.discrepancy(params, sigma)) for t in self.terms_]

    def _suspect_optimum(self, lp, z0) -> bool:
        """The local search's optimum misfits some recording by over ``SUSPECT_INFLATION`` times
        its noise: a local optimum (drawn truths: the start 30 % off, Nelder-Mead stopped at lp
        -1456 where the truth has +114) or a wrong model; either way a global search is owed
        before the discrepancy inflation is measured there."""
        return max(self._inflations_at(lp, z0)) > SUSPECT_INFLATION

    def _set_inflation(self, lp, z0):
        """Each term's discrepancy inflation at ``z0`` (the MAP), kept in the checkpoint."""
        self.inflation_ = [v if math.isfinite(v) else 1.0 for v in self._inflations_at(lp, z0)]
        for term, value in zip(self.terms_, self.inflation_):
            term.inflation = value
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(_H5_GROUP).attrs["inflation"] = json.dumps(self.inflation_)

    def _moves(self):
        """The user's moves; else DE moves, nine in ten of them replaced by independence proposals
        from the Laplace approximation when it is usable (``laplace_``)."""
        self._laplace_move = None
        if self.moves is not None or self.laplace_ is None:
            return self.moves
        import emcee

        from .moves import LaplaceIndependenceMove

        self._laplace_move = LaplaceIndependenceMove(self.laplace_["mean"], self.laplace_["cov"])
        share = float(self.laplace_.get("share", 1.0 - LAPLACE_SHARE_OTHER))
        moves = (emcee.moves.DEMove(), emcee.moves.DESnookerMove(), self._laplace_move)
        return list(zip(moves, _move_weights(share)))

    def _adapt_laplace(self, sampler):
        """At the first chunk end past ``LAPLACE_ADAPT_STEPS``, the independence proposal is
        refitted to the chain (:meth:`_refit_laplace`); after that, every
        ``LAPLACE_CHECK_STEPS``, the walkers' realised acceptance over those steps is read off the
        chain (so a resumed run decides as the uninterrupted one), and under
        ``LAPLACE_MIN_REALISED`` the proposal is refitted again (at most
        ``LAPLACE_MAX_REFITS`` times, then the move is switched off). The trial's importance
        weights only see where the proposal reaches: refitted while the walkers were still
        spreading along a ridge, a proposal accepted at 0.23 over its first 50 steps fell to an
        overall 0.06 (the ridge case: tau 150-220, not converged in 4000 steps). Each refit is
        kept in the checkpoint; the posterior's burn-in covers the last one."""
        move, info = self._laplace_move, self.laplace_
        if move is None:
            return
        it = int(sampler.iteration)
        if info.get("adapted_at") is None:
            if it >= LAPLACE_ADAPT_STEPS:
                self._refit_laplace(sampler, it)
            return
        last = int(info.get("checked_at", info["adapted_at"]))
        if info.get("share", 0.0) <= 0.0:
            # switched off while the walkers were still spreading along a ridge: tried again once
            # the chain has doubled (the ridge case: 0.15 expected at step 200)
            retries = int(info.get("retries", 0))
            if retries < LAPLACE_MAX_RETRIES and it >= 2 * int(info["adapted_at"]):
                info["retries"] = retries + 1
                self._refit_laplace(sampler, it)
            return
        if it < last + LAPLACE_CHECK_STEPS:
            return
        chain = sampler.get_chain(discard=it - LAPLACE_CHECK_STEPS - 1)
        realised = float(np.mean(np.any(np.diff(chain, axis=0) != 0, axis=2)))
        info.update(checked_at=it, realised_acceptance=realised)
        refits = int(info.get("refits", 0))
        mediocre = (min(realised, info.get("expected_acceptance", 1.0)) < LAPLACE_GOOD_ACCEPTANCE
                    and it >= 2 * int(info["adapted_at"]))
        if realised >= LAPLACE_MIN_REALISED and not (mediocre and refits < LAPLACE_MAX_REFITS):
            self._save_laplace()
        elif refits < LAPLACE_MAX_REFITS:
            info["refits"] = int(info.get("refits", 0)) + 1
            self._refit_laplace(sampler, it)
        else:
            info["share"] = 0.0
            sampler._weights = _move_weights(0.0)
            self._save_laplace()

    def _refit_laplace(self, sampler, it):
        """The independence proposal recentred on the chain's second half (its mean and
        covariance), which the curvature at the optimum only approximates (M002 on one record:
        tau 5.4 without the refit, 2.3 with it), then tried: ``2 n_walkers`` proposals (a seeded
        draw, one batch of simulations) give its expected acceptance at equilibrium; under
        ``LAPLACE_MIN_ACCEPTANCE`` the move is switched off and the DE moves take every step
        (drawn truths whose posterior is far from Gaussian: acceptance 0.05-0.08, tau 80-95 with
        the move kept)."""
        move, info = self._laplace_move, self.laplace_
        z = sampler.get_chain(discard=it // 2, flat=True)
        cov = np.cov(z, rowvar=False)
        try:
            move.set_proposal(z.mean(axis=0), cov)
        except np.linalg.LinAlgError:
            info["share"] = 0.0
            sampler._weights = _move_weights(0.0)
            self._save_laplace()
            return
        trial = move.draw(np.random.default_rng([int(self.seed), it]), 2 * self.n_walkers)
        acceptance = move.expected_acceptance(trial, self.log_posterior_(trial))
        share = (1.0 - LAPLACE_SHARE_OTHER) if acceptance >= LAPLACE_MIN_ACCEPTANCE else 0.0
        sampler._weights = _move_weights(share)  # emcee's move weights, in _moves' order
        info.update(mean=z.mean(axis=0).tolist(), cov=np.atleast_2d(cov).tolist(), adapted_at=it,
                    checked_at=it, expected_acceptance=acceptance, share=share)
        self._save_laplace()

    def _save_laplace(self):
        if self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(_H5_GROUP).attrs["laplace"] = json.dumps(self.laplace_)

    # -- fit ------------------------------------------------------------------------------------
    def fit(self, recordings):
        """Sample (or resume) the posterior; returns ``self``.

        Learned attributes: ``posterior_`` (:class:`.results.Posterior`), ``report_``
        (:class:`.runner.ConvergenceReport`), ``sampler_``, ``log_posterior_``, ``terms_``,
        ``priors_``, ``truths_``, ``sigma_hat_``.
        """
        with one_blas_thread():  # the kernels own the cores (:mod:`discovery.threads`)
            return self._fit(recordings)

    def _fit(self, recordings):
        self.setup(recordings)
        backend = None
        if self.backend is not None:
            path = Path(self.backend)
            path.parent.mkdir(parents=True, exist_ok=True)
            config = json.dumps(self._config(), sort_keys=True)
            backend = CheckpointBackend(str(path), name="mcmc")
            if path.exists():
                with backend.open("r") as f:
                    old = f[_H5_GROUP].attrs.get("config") if _H5_GROUP in f else None
                    stored = f[_H5_GROUP].attrs.get("inflation") if _H5_GROUP in f else None
                    transient = ({k: v[()] for k, v in f[_H5_GROUP]["transient_var"].items()}
                                 if _H5_GROUP in f and "transient_var" in f[_H5_GROUP] else None)
                    step_check = f[_H5_GROUP].attrs.get("step_check_at") if _H5_GROUP in f else None
                    chosen = f[_H5_GROUP].attrs.get("transients") if _H5_GROUP in f else None
                    fallbacks = f[_H5_GROUP].attrs.get("fallbacks") if _H5_GROUP in f else None
                if fallbacks is not None and old == config:  # resuming: the records that fell back
                    names = [t.name for t in self.terms_]
                    for name, reason in json.loads(fallbacks).items():
                        if name not in self.fallbacks_:
                            self._fall_back(names.index(name), reason)
                if step_check is not None and old == config:  # resuming: the steps of the start
                    self._refine_steps_at(json.loads(step_check), save=False)
                if chosen is not None and old == config:  # resuming: the transients chosen
                    self.transients_ = json.loads(chosen)
                    for term in self.terms_:
                        if term.name in self.transients_:
                            term.set_transient(self.transients_[term.name])
                if transient is not None and old == config:  # resuming: the start's imprint
                    for term in self.terms_:
                        if term.name in transient:
                            term.set_transient_variance(transient[term.name])
                if stored is not None and old == config:  # resuming: the factors of the start
                    self.inflation_ = [float(v) for v in json.loads(stored)]
                    for term, value in zip(self.terms_, self.inflation_):
                        term.inflation = value
                if old is not None and old != config:
                    was, now = json.loads(old), json.loads(config)
                    changed = sorted(k for k in set(was) | set(now) if was.get(k) != now.get(k))
                    diff = "; ".join(f"{k}: {was.get(k)!r} -> {now.get(k)!r}" for k in changed)
                    raise ValueError(
                        f"{path} holds a run with a different set-up ({diff}); it is kept: choose "
                        "another output directory, or delete it to start again")
            with backend.open("a") as f:
                g = f.require_group(_H5_GROUP)
                g.attrs["config"] = config
                # the noise sd used when sigma is not sampled (predictions and designs need it)
                g.attrs["sigma"] = float(self.log_posterior_.sigma)
        initial = self._initial
        self.laplace_ = None
        if backend is not None and _iteration(backend) > 0:  # resuming: the start's proposal
            with backend.open("r") as f:
                stored = f[_H5_GROUP].attrs.get("laplace") if _H5_GROUP in f else None
            self.laplace_ = json.loads(stored) if stored else None
        else:
            initial = self._initial(np.random.default_rng(self.seed))
            if backend is not None and self.laplace_ is not None:
                with backend.open("a") as f:
                    f.require_group(_H5_GROUP).attrs["laplace"] = json.dumps(self.laplace_)
        # what finding the start cost (optimisation, curvature), beside the sampling
        self.start_simulated_seconds_ = float(self.log_posterior_.simulated_seconds)
        self.sampler_, self.report_ = run_ensemble(
            self.log_posterior_, initial, self.n_walkers, len(self.names_),
            self.max_steps, seed=self.seed, backend=backend, moves=self._moves(), pool=self.pool,
            vectorize=True, check_every=self.check_every, tau_factor=self.tau_factor,
            progress=self.progress, stop_when_converged=self.stop_when_converged,
            after_chunk=self._adapt_laplace,
        )
        self.posterior_ = Posterior.from_sampler(
            self, self.sampler_, self.report_,
            min_burn=int((self.laplace_ or {}).get("adapted_at") or 0))
        return self


def _likelihoods(terms) -> dict:
    """Record -> how it enters: ``"waveform"`` or ``"features"`` (closed loop), ``"open"``."""
    return {t.name: "open" if t.recording.kind == "open" else t.kind for t in terms}


def _move_weights(share):
    """Weights of (DEMove, DESnookerMove, Laplace move) when the last takes ``share`` of the
    steps: the DE moves split the rest 80/20 as in :func:`.runner.default_moves`."""
    return np.array([0.8 * (1.0 - share), 0.2 * (1.0 - share), share])


def _iteration(backend) -> int:
    """Steps held by an HDF backend (0 for a new file or one without a chain yet)."""
    try:
        return int(backend.iteration)
    except (OSError, KeyError):
        return 0


#: Restarts of the local search while its optimum leaves a discrepancy (:meth:`Calibration._polish`)
POLISH_RESTARTS = 3
#: ... each kept only if it gains more than this (nats).
POLISH_GAIN = 0.1
#: Steps of the short ensemble run that looks for a better maximum where the one found leaves a
#: discrepancy factor over 1 (:meth:`Calibration._scout`) ...
SCOUT_STEPS = 60
#: ... and how many of its most probable points are compared with that maximum; at most
#: ``SCOUT_ROUNDS`` runs, each from the last one's better point (draw 23: one round took the
#: factor from 30 to 3.2).
SCOUT_CANDIDATES = 24
SCOUT_ROUNDS = 3
#: Misfit (as a discrepancy inflation) beyond which the local optimum is checked globally.
SUSPECT_INFLATION = 10.0
#: Steps between checks of the move's realised acceptance ...
LAPLACE_CHECK_STEPS = 50
#: ... and under which (the fraction of walker-steps that moved) it is switched off.
LAPLACE_MIN_REALISED = 0.15
#: Refits of the proposal after its first when its realised acceptance falls short.
LAPLACE_MAX_REFITS = 3
#: Largest principal sd of a usable Laplace approximation, as a fraction of the prior's extent.
LAPLACE_MAX_FRACTION = 0.25
#: Share of the DE moves when the Laplace independence move is on.
LAPLACE_SHARE_OTHER = 0.1
#: Steps after which the independence proposal is refitted to the chain, once.
LAPLACE_ADAPT_STEPS = 50
#: Expected acceptance of the refitted proposal under which it is switched off.
LAPLACE_MIN_ACCEPTANCE = 0.25
#: Times a switched-off proposal is refitted again (each when the chain has doubled).
LAPLACE_MAX_RETRIES = 3
#: Acceptance (expected, or realised over the last check) under which a proposal in use is
#: refitted when the chain has doubled since its fit (its first fit rests on 25 steps: M002's noise
#: seed 5 expected 0.52 and took 470 steps, tau 10).
LAPLACE_GOOD_ACCEPTANCE = 0.6


def _global_start(lp, z0, seed, names):
    """The better of ``z0`` and a differential evolution over the prior box (vectorised: each
    generation one batch of simulations), refined by Nelder-Mead."""
    from scipy.optimize import differential_evolution

    bounds = [p.internal_bounds for p in lp.priors]

    def cost(z):  # (ndim, S) -> (S,)
        f = np.asarray(lp(np.atleast_2d(z.T)), dtype=float)
        return np.where(np.isfinite(f), -f, 1e30)  # finite: DE squares the spread of costs

    res = differential_evolution(cost, bounds, vectorized=True, popsize=12, maxiter=40, tol=1e-3,
                                 seed=seed, polish=False, init="sobol", updating="deferred")
    z = _profile_sigma(lp, _nelder_mead_from(lp, res.x), names)
    return z if lp(z) > lp(z0) else z0


def _nelder_mead_from(lp, z):
    """Nelder-Mead from ``z`` (100 evaluations per coordinate); its end if more probable than ``z``."""
    from scipy.optimize import minimize

    ref = minimize(_cost(lp), z, method="Nelder-Mead",
                   options={"maxfev": 100 * len(z), "xatol": 1e-6, "fatol": 0.05,
                            "initial_simplex": _simplex(z, lp)})
    if np.isfinite(lp(ref.x)) and lp(ref.x) > lp(z):
        return ref.x
    return z


def _profile_sigma(lp, z0, names):
    """``z0`` with the noise sd at its conditional maximum given the other parameters.

    The noise estimate from the record's floor is far below the misfit of a misspecified model
    (a SINDy proposal): started there, the posterior is so sharp that the walkers' ball collapses
    and the chain crawls for hundreds of steps (seen in the ``discover`` study).
    """
    if SIGMA not in names:
        return z0
    from scipy.optimize import minimize_scalar

    j = list(names).index(SIGMA)
    lo, hi = lp.priors[j].internal_bounds
    full_cost = _cost(lp)

    def cost(v):
        z = z0.copy()
        z[j] = v
        return full_cost(z)

    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4 * (hi - lo)})
    if res.fun < cost(z0[j]):
        z0 = z0.copy()
        z0[j] = res.x
    return z0


def _cost(lp):
    """``-lp(z)`` for the optimisers, one evaluation per call; a huge finite value where ``lp``
    is ``-inf`` (Nelder-Mead and the bounded scalar search need finite costs)."""

    def cost(z):
        f = lp(z)
        return -f if np.isfinite(f) else 1e300

    return cost


def _simplex(z0, lp):
    scale = _axis_scales(lp, z0)
    simplex = [z0]
    for j in range(len(z0)):
        z = z0.copy()
        z[j] += scale[j]
        simplex.append(z)
    return np.array(simplex)


def _hessian(lp, z0, scale):
    """Hessian of ``lp`` at ``z0`` (internal coordinates) by central differences with steps
    ``scale`` (the per-axis sds, so each probe moves ``lp`` by ~0.5), all probes in one
    vectorised call; ``None`` when a probe fails."""
    ndim = len(z0)
    h = np.asarray(scale, dtype=float)
    pts = [z0]
    for i in range(ndim):
        for si in (1, -1):
            z = z0.copy()
            z[i] += si * h[i]
            pts.append(z)
    for i in range(ndim):
        for j in range(i + 1, ndim):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                z = z0.copy()
                z[i] += si * h[i]
                z[j] += sj * h[j]
                pts.append(z)
    f = np.asarray(lp(np.array(pts)), dtype=float)
    if not np.all(np.isfinite(f)):
        return None
    f0, k = f[0], 1
    hess = np.empty((ndim, ndim))
    for i in range(ndim):
        hess[i, i] = (f[k] - 2 * f0 + f[k + 1]) / h[i] ** 2
        k += 2
    for i in range(ndim):
        for j in range(i + 1, ndim):
            fpp, fpm, fmp, fmm = f[k:k + 4]
            hess[i, j] = hess[j, i] = (fpp - fpm - fmp + fmm) / (4 * h[i] * h[j])
            k += 4
    return hess


def _principal_axes(lp, z0, scale, hess):
    """Columns: the posterior's principal axes at ``z0``, each as long as its sd.

    From the Hessian ``hess`` (:func:`_hessian`). Along a direction the data barely constrain (a
    ridge: an eigenvalue near zero or positive), the sd is a quarter of the prior box's extent
    through ``z0`` in that direction, so the walkers start spread along the ridge instead of in a
    ball that must crawl along it. Falls back to the axis sds when the probes failed.
    """
    ndim = len(z0)
    h = np.asarray(scale, dtype=float)
    if hess is None:
        return np.diag(0.5 * h)
    # in units of the axis sds, so that eigenvalues compare across parameters
    precision = -hess * np.outer(h, h)
    vals, vecs = np.linalg.eigh(precision)
    lows, highs = _box(lp)
    axes = np.empty((ndim, ndim))
    for m in range(ndim):
        v = vecs[:, m] * h  # direction in internal coordinates, one unit = one eigen-sd at 1
        extent = _box_extent(z0, v, lows, highs)
        sd = 1.0 / math.sqrt(vals[m]) if vals[m] > 0 else math.inf
        axes[:, m] = v * min(sd, 0.25 * extent)
    return axes


def _box(lp):
    lows = np.array([p.internal_bounds[0] for p in lp.priors])
    highs = np.array([p.internal_bounds[1] for p in lp.priors])
    return lows, highs


def laplace_covariance(lp, z0, hess, max_fraction=LAPLACE_MAX_FRACTION):
    """The Laplace covariance ``(-hess)^-1`` at ``z0`` when it can serve as a proposal, else
    ``None``: the negative Hessian must be positive definite and every principal sd under
    ``max_fraction`` of the prior box's extent along it (otherwise the posterior is a ridge the
    prior cuts, far from its Gaussian)."""
    eig = _curvature_without_ridge(lp, z0, hess, max_fraction)
    if eig is None or not np.all(eig[0] > 0):
        return None
    vals, vecs = eig
    return (vecs / vals) @ vecs.T


def _curvature_without_ridge(lp, z0, hess, max_fraction):
    """``(vals, vecs)`` of ``-hess`` when it is finite and no direction of positive curvature has
    a principal sd reaching ``max_fraction`` of the prior box's extent along it; else ``None``."""
    if hess is None or not np.all(np.isfinite(hess)):
        return None
    vals, vecs = np.linalg.eigh(-hess)
    lows, highs = _box(lp)
    for m, v in enumerate(vals):
        if v > 0 and 1.0 / math.sqrt(v) >= max_fraction * _box_extent(z0, vecs[:, m], lows, highs):
            return None
    return vals, vecs


def _box_extent(z0, v, lows, highs):
    """Length (in multiples of ``v``) of the line ``z0 + t v`` inside the box ``[lows, highs]``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lows - z0) / v, (highs - z0) / v
    lo = np.where(v != 0, np.minimum(a, b), -np.inf)
    hi = np.where(v != 0, np.maximum(a, b), np.inf)
    return float(np.min(hi) - np.max(lo))


def _axis_scales(lp, z0):
    """Posterior sd along each internal axis from the curvature at ``z0`` (bounded guesses)."""
    ndim = len(z0)
    widths = np.array([hi - lo for lo, hi in (p.internal_bounds for p in lp.priors)])
    scale = np.empty(ndim)
    f0 = lp(z0)
    for j in range(ndim):
        h = 1e-3 * widths[j]
        scale[j] = 1e-3 * widths[j]
        for _ in range(6):
            pts = np.array([z0, z0, z0])
            pts[1, j] -= h
            pts[2, j] += h
            f = lp(pts)
            if not np.all(np.isfinite(f)):
                h *= 0.3
                continue
            d2 = (f[1] - 2 * f0 + f[2]) / h**2
            if d2 < 0:
                s = 1.0 / math.sqrt(-d2)
                scale[j] = min(s, 0.1 * widths[j])
                if 0.1 * s < h < 10 * s:
                    break
                h = s
            else:
                h *= 3.0
    return scale
