"""How each record enters a calibration, chosen at its start: a waveform record whose cycle
attracts slowly falls back to its limit-cycle features, each output-error term's simulation step
is checked again at the maximum a posteriori, and each closed-loop waveform record's transient is
the shortest that keeps its log-likelihood accurate.

A part of :class:`tvcid.discovery.calibration.calibration.Calibration` (as
:class:`.start.StartSearch` is): it reads ``terms_``, ``log_posterior_``, ``base_``, ``start_``,
``names_``, ``window``, ``transient``, ``features``, ``warm_start``, ``choose_transient``,
``seed`` and ``backend``, and sets ``fallbacks_``, ``likelihoods_``, ``transients_`` and
``transient_errors_``; every choice is kept in the checkpoint, so that a resumed run rebuilds the
same likelihood.
"""
from __future__ import annotations

import json
import warnings

import numpy as np

from .backend import H5_GROUP, CheckpointBackend
from .likelihood.features import FeatureTerm
from .likelihood.waveform import SETTLING_PERTURBATION, IllPosedLikelihoodWarning, WaveformTerm
from .priors import SIGMA

__all__ = ["RecordChoices", "record_likelihoods", "FALLBACK_TRANSIENT", "SETTLING_LOAD_LIMIT",
           "TRANSIENT_CANDIDATES", "TRANSIENT_REFERENCE", "TRANSIENT_TOLERANCE"]

#: Transients (s) tried below the given one, the reference they are checked against (at least
#: twice the given one) and the largest log-likelihood error (nats) a chosen one may make
#: (:meth:`RecordChoices._choose_transients`).
TRANSIENT_CANDIDATES = (2.0, 3.0, 4.0)
TRANSIENT_REFERENCE = 12.0
TRANSIENT_TOLERANCE = 0.5
#: Nats (at the noise) a waveform record's simulated cycle, started larger than the record's,
#: may still move between transients of ``max(TRANSIENT_REFERENCE, 2 transient)`` and twice that
#: at the maximum a posteriori before the record enters through its features
#: (:meth:`RecordChoices._fall_back_slow`).
SETTLING_LOAD_LIMIT = 2.0
#: Transient (s) of a record that fell back to its features (at least the given one): the
#: coverage benchmark's, whose calibration the features' table measures; a slowly attracting
#: cycle needs it.
FALLBACK_TRANSIENT = 20.0


def record_likelihoods(terms) -> dict:
    """Record -> how it enters: ``"waveform"`` or ``"features"`` (closed loop), ``"open"``."""
    return {t.name: "open" if t.recording.kind == "open" else t.kind for t in terms}


class RecordChoices:
    """The start's choices of how each record enters the likelihood (the module's)."""

    def _fall_back(self, i, reason, save=False):
        """Record ``i`` enters through its limit-cycle features from now on (its waveform is
        ill-posed: ``reason``), said in an
        :class:`.likelihood.waveform.IllPosedLikelihoodWarning`; kept in the checkpoint when
        ``save``."""
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
        self.likelihoods_ = record_likelihoods(self.terms_)
        if save and self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(H5_GROUP).attrs["fallbacks"] = json.dumps(self.fallbacks_)

    def _fall_back_slow(self, lp, z0) -> bool:
        """Waveform records whose cycle attracts slowly at ``z0`` (the maximum a posteriori) fall
        back to their features; True if any did.

        Slowly: a run of ``z0`` started ``SETTLING_PERTURBATION`` larger than the record's cycle
        still moves by over ``SETTLING_LOAD_LIMIT`` nats between transients of
        ``max(TRANSIENT_REFERENCE, 2 transient)`` s and twice that
        (:meth:`.likelihood.waveform.WaveformTerm.settling_load`). Measured at the maximum, whose
        own cycle has the record's size, so that a start far off does not count its own distance.
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

    def _refine_steps_at(self, point, save=True):
        """Each output-error term's simulation step checked again at ``point`` (natural
        coordinates; the maximum a posteriori), never coarser than set up
        (:meth:`.likelihood.solver._WaveformSolverError.refine_at`); ``point`` is kept in the
        checkpoint so that a resumed run rebuilds the same likelihood."""
        params = self.log_posterior_.params_for(np.array([point[n] for n in self.names_]))
        if params is None:
            return
        for term in self.terms_:
            if hasattr(term, "refine_at"):
                term.refine_at(params)
        if save and self.backend is not None:
            with CheckpointBackend(str(self.backend), name="mcmc").open("a") as f:
                f.require_group(H5_GROUP).attrs["step_check_at"] = json.dumps(point)

    def _transient_terms(self):
        """The closed-loop waveform terms (open-loop records have no transient)."""
        return [t for t in getattr(self, "terms_", [])
                if getattr(t, "kind", "") == "waveform" and hasattr(t, "set_transient")]

    def _chooses_transient(self) -> bool:
        return bool(self.choose_transient) and bool(self._transient_terms())

    def _choose_transients(self, lp, z0, axes, walkers, rng):
        """Each waveform record's transient, chosen by the accuracy it gives.

        Check points: the walkers and as many points ``z0 + 2 axes N(0, 1)`` (where a chain
        goes). The log-likelihood at each candidate transient is compared with the reference's
        (``max(TRANSIENT_REFERENCE, 2 * transient)``); the shortest candidate whose largest error
        is within ``TRANSIENT_TOLERANCE`` nats is kept. Kept in the checkpoint.
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
                f.require_group(H5_GROUP).attrs["transients"] = json.dumps(self.transients_)
