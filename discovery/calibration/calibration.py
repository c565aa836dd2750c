"""``Calibration``: the Bayesian calibration of a hypothesis on recordings.

sklearn-style: ``__init__`` only stores its arguments; :meth:`Calibration.fit` validates them,
builds the likelihood terms and the log posterior, runs (or resumes) the ensemble and returns
``self``; what it learns ends in ``_`` (``posterior_``, ``report_``, ``sampler_``, ...).

Here: the estimator's parameters, its set-up (validation, the terms, the log posterior), the
records that enter through their features instead of their waveform, the step check and the
transients chosen per record, and the run with its checkpoint and resume. Where the chain starts
(the maximum a posteriori, the discrepancy factors there, the walkers) is
:class:`.start.StartSearch`; the Laplace move's adaptation over the run is
:class:`.moves.LaplaceAdaptation`; the importance sampling that can stand in for the chain is
:class:`.importance_stage.ImportanceStage`; all three are parts of :class:`Calibration`.
"""
from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np

from tvcid.models.hypotheses import ActuatorParams
from tvcid.models.hypotheses import hypothesis as get_hypothesis
from tvcid.models.recording import load_recordings

from ..threads import one_blas_thread
from .backend import H5_GROUP, CheckpointBackend, store_weighted_posterior
from .importance import ImportanceReport
from .importance_stage import IMPORTANCE_ROUNDS, IMPORTANCE_TARGET_ESS, ImportanceStage
from .likelihood.features import DEFAULT_FEATURES
from .likelihood.registry import LIKELIHOODS, make_term
from .likelihood.waveform import IllPosedLikelihoodWarning, WaveformTerm
from .log_posterior import LogPosterior, check_parameter_names
from .moves import LaplaceAdaptation
from .nested import NestedReport
from .nested_stage import NESTED_TARGET_ESS, NestedStage
from .posterior import Posterior
from .priors import SIGMA, Prior, default_prior, ridge_coordinates, step_under_delay
from .record_choices import RecordChoices, record_likelihoods
from .resume import StartRestore
from .runner import run_ensemble
from .start import POLISH_RESTARTS, START_OPTIMIZERS, StartSearch

__all__ = ["Calibration", "truths_from_recordings"]


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


#: Default RK4 step per likelihood (s), with the friction offset's jump located inside the step
#: (``tvcid.models.nonlinearities.sign_switch_average``); records that need a finer step get
#: one (:meth:`.likelihood.solver._WaveformSolverError._refine_step`). The features' first-order
#: error is corrected instead.
DEFAULT_DT = {"waveform": 5e-4, "features": 5e-4}


class Calibration(StartSearch, LaplaceAdaptation, ImportanceStage, NestedStage, StartRestore,
                  RecordChoices):
    """Posterior over chosen parameters of a hypothesis, given one or more recordings.

    Parameters
    ----------
    hypothesis : str or ActuatorParams
        A hypothesis name (``tvcid.models.hypothesis``) or a parameter object; every parameter not
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
        :class:`.likelihood.waveform.IllPosedLikelihoodWarning`): a simulated cycle that is not
        periodic (the band-pass loop's; decided at the start), or one that attracts so slowly that
        its recording may still be settling (decided at the maximum a posteriori, which is then
        searched again with the features; :meth:`_fall_back_slow`). The features measure a record's
        settling and a run's start imprint; the waveform reads both as parameters. Learned
        attributes ``likelihoods_`` (record -> ``"waveform"``, ``"features"`` or ``"open"``) and
        ``fallbacks_`` (record -> reason), kept in the checkpoint. ``False`` keeps the waveform
        everywhere (and only warns of a cycle that is not periodic).
    choose_transient : bool
        Waveform records: once the walkers are placed, simulate before each record's window the
        shortest of ``TRANSIENT_CANDIDATES`` below ``transient`` whose log-likelihood stays within
        ``TRANSIENT_TOLERANCE`` nats of a ``TRANSIENT_REFERENCE`` one at the walkers and at as many
        points twice as far out; ``transient`` itself if none does; the reference if not even
        ``transient`` does (:meth:`_choose_transients`, :mod:`.record_choices`). Learned
        attributes ``transients_`` (record -> seconds) and ``transient_errors_`` (record ->
        {seconds: largest error}).
    continuation : bool
        Start each closed-loop run from the end state of the stored run nearest its parameters
        (within ``CONTINUATION_RADIUS``;
        :meth:`.likelihood.closed_loop._ClosedLoopTerm.continue_runs`), so that a proposal
        continues its walker's cycle. Off by default: it cuts the worst transient error but not
        the median one nor the cost to convergence, and a resumed chain, whose stored states are
        not checkpointed, would not repeat the uninterrupted one.
    dt : float or None
        RK4 step of the simulations (each output-error record may halve it further,
        :meth:`.likelihood.solver._WaveformSolverError._refine_step`). Default ``DEFAULT_DT``,
        5e-4 s, halved until one step, the kernel's shortest delay, fits under the floor of a
        sampled delay's prior, declared or default (:func:`.priors.step_under_delay`).
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
        Find the maximum a posteriori before placing the walkers around it.
    start_optimizer : {"nelder-mead", "quasi-newton"}
        How the maximum is found from the start: Nelder-Mead (one point at a time), or
        quasi-Newton steps on gradients and a Hessian by central differences over each axis' sd,
        their points in batches (:func:`.optimum._quasi_newton`: a fraction of the simulations
        where the start is near the maximum, as a structure search's fit is).
    polish_restarts : int
        Restarts of the local search along the principal axes while its optimum leaves some
        recording a discrepancy factor over 1 (:meth:`.start.StartSearch._polish`); 0 keeps the
        local search's optimum.
    stop_when_converged : bool
        False runs every chain to ``max_steps`` (e.g. to map a ridge).
    discrepancy : bool
        Inflate each recording's likelihood for model discrepancy, set once at the maximum a
        posteriori (:func:`.likelihood.base.waveform_inflation`,
        :func:`.likelihood.base.features_inflation`): a wrong or slightly wrong model then gets
        intervals as wide as its misfit warrants instead of needles; a right model keeps factor 1.
        Stored in the checkpoint so a resumed chain uses the same factors. Learned attribute
        ``inflation_`` (one factor per recording).
    spread : {"axes", "hessian"}
        Initial walkers around the maximum a posteriori: a ball with each axis' own sd, or along
        the principal axes of the Hessian there, spread over the prior along ridges the data do not
        constrain (:func:`.optimum._principal_axes`).
    laplace_move : bool
        When the posterior at the maximum a posteriori is close enough to its Laplace approximation
        (:func:`.optimum.laplace_covariance`), nine steps in ten are independence proposals from a
        widened t around it (:class:`.moves.LaplaceIndependenceMove`), refitted once to the chain
        after ``LAPLACE_ADAPT_STEPS`` (:class:`.moves.LaplaceAdaptation`); the rest are DE moves
        (unless ``moves`` is given). Otherwise the move waits idle (share 0) for that refit, which
        tries it on the chain's mean and covariance and keeps it only if it would be accepted often
        enough. Learned attribute ``laplace_`` (mean, covariance in sampling coordinates and the
        move's share), kept in the checkpoint for a resumed chain.
    global_search : bool
        Where the local optimum misfits a recording by over ``SUSPECT_INFLATION`` times its noise
        or leaves it without a cycle, look for a better one over the whole prior box (differential
        evolution), with or without the discrepancy term; with the term, also where the factors
        stay over 1, and with a short ensemble run (:meth:`.start.StartSearch._scout`) before the
        inflation is set. ``False`` when the start
        already is a global search's optimum on the same recordings (``tvcid discover``'s winner):
        a misfit left there is the model's, and both searches only repeat that search.
    importance : int
        Points per round of the importance stage (:mod:`.importance_stage`); 0 (default) goes
        straight to the chain. When on and the start's Laplace approximation is usable, rounds
        of adaptive importance sampling from it come first; where their ratios are reliable
        (Pareto ``k`` < 0.7 and ``IMPORTANCE_TARGET_ESS`` effective points) they are the
        posterior (``posterior_.importance``, ``report_`` an
        :class:`.importance.ImportanceReport`, ``sampler_`` None), else the chain starts from
        their points. Learned attribute ``importance_`` (the run, or None).
    importance_rounds : int
        Rounds of the importance stage at most (default ``IMPORTANCE_ROUNDS``); a later fit on
        the same checkpoint with more continues from the stored rounds, drawing the points a
        single run would have.
    importance_only : bool
        Where the importance stage runs, its run is the posterior even if its ratios are not yet
        reliable (``report_.converged`` False): no chain follows. A screening's choice, which a
        later fit on the same checkpoint without it continues.
    nested : int
        Live points of the nested-sampling stage (:mod:`.nested_stage`); 0 (default) switches
        it off. When on, where the importance stage's ratios are not reliable (or there is no
        importance stage), nested sampling over the start's proposal, widened (its Laplace
        approximation, else the curvature held to the walkers' starting ball, else the ball;
        :mod:`.nested_stage`), comes before any chain; where the run
        is reliable (finished, Pareto ``k`` < 0.7, ``NESTED_TARGET_ESS`` effective points) it is
        the posterior (``posterior_.importance`` the run, ``report_`` a
        :class:`.nested.NestedReport` with the evidence), else the chain starts from its
        points. Learned attribute ``nested_`` (the run, or None).
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
                 global_search=True, importance=0, start_optimizer="nelder-mead",
                 polish_restarts=POLISH_RESTARTS, importance_rounds=IMPORTANCE_ROUNDS,
                 importance_only=False, nested=0):
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
        self.importance = importance
        self.start_optimizer = start_optimizer
        self.polish_restarts = polish_restarts
        self.importance_rounds = importance_rounds
        self.importance_only = importance_only
        self.nested = nested

    # -- set-up ---------------------------------------------------------------------------------
    def _default_dt(self, base, names, priors, start):
        """``DEFAULT_DT``, halved until one step fits under the floor of a sampled delay's prior
        (:func:`.priors.step_under_delay`): the declared prior's, or the default prior's, half the
        delay's start (:func:`.priors.default_prior`). A delay not sampled keeps ``DEFAULT_DT``."""
        dt = DEFAULT_DT[self.likelihood]
        if "delay" not in names:
            return dt
        if "delay" in priors:
            floor = priors["delay"].low
        else:
            floor = 0.5 * float(start.get("delay", getattr(base, "delay")))
            if floor == 0.0:  # default_prior names the problem: no prior centred on 0
                return dt
        return step_under_delay(floor, dt)

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
            # only when on, so that a checkpoint without the option resumes
            **({"continuation": True} if self.continuation else {}),
            **({"importance": int(self.importance)} if self.importance else {}),
            **({"nested": int(self.nested)} if self.nested else {}),
            **({"choose_transient": True} if self._chooses_transient() else {}),
            # only when a record fell back, so that a checkpoint without fallbacks resumes
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
        if self.dt is not None and not (isinstance(self.dt, (int, float)) and self.dt > 0):
            raise ValueError(f"dt must be > 0 (got {self.dt!r})")
        if self.spread not in ("axes", "hessian"):
            raise ValueError(f"spread must be 'axes' or 'hessian' (got {self.spread!r})")
        if self.start_optimizer not in START_OPTIMIZERS:
            raise ValueError(f"start_optimizer must be one of {', '.join(START_OPTIMIZERS)} "
                             f"(got {self.start_optimizer!r})")
        if self.transient < 0:
            raise ValueError(f"transient must be >= 0 (got {self.transient})")
        if not isinstance(self.polish_restarts, (int, np.integer)) or self.polish_restarts < 0:
            raise ValueError(f"polish_restarts must be an integer >= 0 (got "
                             f"{self.polish_restarts!r})")
        if not isinstance(self.importance_rounds, (int, np.integer)) or self.importance_rounds < 1:
            raise ValueError(f"importance_rounds must be an integer >= 1 (got "
                             f"{self.importance_rounds!r})")
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
        self.dt_ = (float(self.dt) if self.dt is not None
                    else self._default_dt(base, names, priors, start))
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
        self.solver_check_points_ = None  # likewise (StartSearch._set_solver_correction)
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
        self.likelihoods_ = record_likelihoods(self.terms_)
        self.truths_ = truths_from_recordings(self.recordings_, names, base.name)
        return self

    # -- fit ------------------------------------------------------------------------------------
    def _store_laplace(self, backend):
        """The Laplace proposal kept in the checkpoint (a resumed run proposes the same)."""
        if backend is not None and self.laplace_ is not None:
            with backend.open("a") as f:
                f.require_group(H5_GROUP).attrs["laplace"] = json.dumps(self.laplace_)

    def _adopt(self, run, report, backend):
        """A run of weighted points (importance or nested) as the posterior, no chain after it;
        its points kept in the checkpoint where a chain would be. Returns ``self``."""
        self.sampler_, self.report_ = None, report
        self.posterior_ = Posterior.from_importance(self, run, report, seed=self.seed)
        if backend is not None:
            store_weighted_posterior(backend, run.points, run.weights)
        return self

    def fit(self, recordings):
        """Sample (or resume) the posterior; returns ``self``.

        Learned attributes: ``posterior_`` (:class:`.posterior.Posterior`), ``report_``
        (:class:`.runner.ConvergenceReport`), ``sampler_``, ``log_posterior_``, ``terms_``,
        ``priors_``, ``truths_``, ``sigma_hat_``.
        """
        with one_blas_thread():  # the kernels own the cores (:mod:`tvcid.discovery.threads`)
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
                self._restore_start(backend, path, config)
            with backend.open("a") as f:
                g = f.require_group(H5_GROUP)
                g.attrs["config"] = config
                # the noise sd used when sigma is not sampled (predictions and designs need it)
                g.attrs["sigma"] = float(self.log_posterior_.sigma)
        initial = self._initial
        self.laplace_ = None
        self.importance_ = None
        self.nested_ = None
        chain_steps = _iteration(backend) if backend is not None else 0
        if chain_steps > 0 or self._has_importance() or self._has_nested():  # resuming
            with backend.open("r") as f:
                stored = f[H5_GROUP].attrs.get("laplace") if H5_GROUP in f else None
            self.laplace_ = json.loads(stored) if stored else None
        else:
            initial = self._initial(np.random.default_rng(self.seed))
            self._store_laplace(backend)
        # what finding the start cost (optimisation, curvature), beside the sampling
        self.start_simulated_seconds_ = float(self.log_posterior_.simulated_seconds)
        self.start_simulated_steps_ = float(self.log_posterior_.simulated_steps)
        if chain_steps == 0 and self._importance_usable():
            t0 = time.perf_counter()
            new = self._run_importance()
            report = ImportanceReport.of(self.importance_, IMPORTANCE_TARGET_ESS, new,
                                         time.perf_counter() - t0)
            if report.converged or self.importance_only:  # reliable, or all that is asked
                return self._adopt(self.importance_, report, backend)
            # the nested stage, when on, starts from the start's proposal, not the run's
            walkers = (None if self._nested_usable() else
                       self._walkers_from_importance(np.random.default_rng([int(self.seed), 17])))
            if walkers is not None:  # the chain starts from the run's points
                initial = walkers
                self._store_laplace(backend)
        if chain_steps == 0 and self._nested_usable():
            t0 = time.perf_counter()
            new = self._run_nested()
            report = NestedReport.of(self.nested_, NESTED_TARGET_ESS, new,
                                     time.perf_counter() - t0)
            if report.converged:
                return self._adopt(self.nested_, report, backend)
            walkers = self._walkers_from_nested(np.random.default_rng([int(self.seed), 23]))
            if walkers is not None:
                initial = walkers
                self._store_laplace(backend)
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


def _iteration(backend) -> int:
    """Steps held by an HDF backend (0 for a new file or one without a chain yet)."""
    try:
        return int(backend.iteration)
    except (OSError, KeyError):
        return 0

