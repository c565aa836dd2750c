"""Result objects of a calibration: posterior summaries, plots, predictive checks, comparison.

Compute and plot are kept apart: every object here is computed once and has ``plot``-style
methods taking an optional axes or figure.
"""
from __future__ import annotations

import contextlib
import json
import math
from dataclasses import dataclass, field

import numpy as np

from .priors import SIGMA

__all__ = ["Posterior", "PosteriorPredictive", "ModelComparison", "compare"]


@dataclass(eq=False)
class Posterior:
    """Posterior samples of one calibration (burn-in discarded, thinned).

    Attributes
    ----------
    names : tuple of str
    samples : ndarray (n, ndim)
        Natural units.
    internal : ndarray (n, ndim)
        Sampling coordinates (log for log-uniform priors).
    log_prob : ndarray (n,)
    chain : ndarray (n_steps, n_walkers, ndim)
        The whole chain in natural units (for traces).
    log_scale : tuple of bool
        Which coordinates are sampled in log.
    truths : dict name -> float or None
    report : ConvergenceReport or ImportanceReport
    burn, thin : int
    importance : ImportanceRun, NestedRun or None
        The weighted points behind ``samples`` when they were drawn by importance or nested
        sampling (:meth:`from_importance`); ``chain`` is then the resampled draws as one walker.
    """

    names: tuple
    samples: np.ndarray
    internal: np.ndarray
    log_prob: np.ndarray
    chain: np.ndarray
    log_scale: tuple
    truths: dict
    report: object
    burn: int
    thin: int
    calibration: object = field(default=None, repr=False)
    importance: object = field(default=None, repr=False)

    #: Equally weighted draws resampled from an importance run (:meth:`from_importance`).
    RESAMPLED = 4000

    @classmethod
    def from_importance(cls, calibration, run, report, seed=0, n=None):
        """The posterior of an importance run (:mod:`.importance`): ``n`` draws resampled by
        the weights (systematic resampling, seeded), ``chain`` those draws as one walker."""
        lp = calibration.log_posterior_
        idx = run.resample(np.random.default_rng([int(seed), 11]), int(n or cls.RESAMPLED))
        z = run.points[idx]
        nat = lp.natural(z)
        return cls(
            names=tuple(calibration.names_), samples=nat, internal=z,
            log_prob=run.log_posterior[idx], chain=nat[:, None, :],
            log_scale=tuple(p.log for p in lp.priors), truths=dict(calibration.truths_),
            report=report, burn=0, thin=1, calibration=calibration, importance=run)

    @classmethod
    def from_sampler(cls, calibration, sampler, report, burn=None, thin=None, min_burn=0):
        """Samples after a burn-in of ``2 tau`` steps, and at least ``min_burn`` (the sampler's
        last adaptation), both capped at half the chain, or after the steps the convergence test
        left out (``report.burn``); thinned by half the shortest tau."""
        lp = calibration.log_posterior_
        it = sampler.iteration
        tau = np.asarray(report.tau, dtype=float)
        tmax = float(np.max(tau)) if np.all(np.isfinite(tau)) else it / 10.0
        if burn is None:
            burn = max(int(min(max(2 * tmax, min_burn, 0), it // 2)), int(getattr(report, "burn", 0)))
        if thin is None:
            tmin = float(np.min(tau)) if np.all(np.isfinite(tau)) else 1.0
            thin = max(1, int(0.5 * tmin))
        z = sampler.get_chain(discard=burn, thin=thin, flat=True)
        logp = sampler.get_log_prob(discard=burn, thin=thin, flat=True)
        full = sampler.get_chain()
        nat_full = lp.natural(full.reshape(-1, full.shape[-1])).reshape(full.shape)
        return cls(
            names=tuple(calibration.names_),
            samples=lp.natural(z),
            internal=z,
            log_prob=logp,
            chain=nat_full,
            log_scale=tuple(p.log for p in lp.priors),
            truths=dict(calibration.truths_),
            report=report,
            burn=burn,
            thin=thin,
            calibration=calibration,
        )

    # -- numbers --------------------------------------------------------------------------------
    def quantiles(self, q=(0.05, 0.5, 0.95)):
        return np.quantile(self.samples, q, axis=0)

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix in the sampling coordinates (``ln`` for log-uniform parameters)."""
        if self.internal.shape[0] < 3:
            return np.full((len(self.names),) * 2, np.nan)
        return np.atleast_2d(np.corrcoef(self.internal, rowvar=False))

    def interval(self, name, level=0.90):
        j = self.names.index(name)
        a = 0.5 * (1 - level)
        lo, hi = np.quantile(self.samples[:, j], [a, 1 - a])
        return float(lo), float(hi)

    def z_scores(self):
        """``(truth - mean)/sd`` per parameter whose truth is known."""
        out = {}
        for j, n in enumerate(self.names):
            t = self.truths.get(n)
            if t is not None:
                col = self.samples[:, j]
                out[n] = float((t - col.mean()) / col.std())
        return out

    @property
    def map(self) -> dict:
        """Highest-posterior sample of the whole chain, or of an importance run's points
        (natural units)."""
        if self.importance is not None:
            run = self.importance
            i = int(np.argmax(run.log_posterior))
            x = self.calibration.log_posterior_.natural(run.points[i:i + 1])[0]
            return dict(zip(self.names, x.tolist()))
        s = self.calibration.sampler_
        lp = s.get_log_prob()
        i, w = np.unravel_index(int(np.argmax(lp)), lp.shape)
        return dict(zip(self.names, self.chain[i, w].tolist()))

    def summary(self) -> dict:
        q05, q50, q95 = self.quantiles()
        params = {}
        for j, n in enumerate(self.names):
            col = self.samples[:, j]
            params[n] = {
                "mean": float(col.mean()), "sd": float(col.std()),
                "q05": float(q05[j]), "q50": float(q50[j]), "q95": float(q95[j]),
                "truth": self.truths.get(n),
            }
        rep = self.report
        corr = self.correlation
        method = getattr(rep, "method", "")
        extra = ({"sampler": "importance", "pareto_k": rep.pareto_k, "rounds": rep.rounds}
                 if method == "importance" else
                 {"sampler": "nested", "pareto_k": rep.pareto_k, "log_z": rep.log_z,
                  "log_z_se": rep.log_z_se, "likelihood_calls": rep.n_like}
                 if method == "nested" else {"sampler": "ensemble"})
        return {
            **extra,
            "parameters": params,
            "tau": dict(zip(self.names, [float(t) for t in rep.tau])),
            "converged": bool(rep.converged),
            "n_over_tau": rep.n_over_tau,
            "tau_factor": rep.tau_factor,
            "iterations": rep.iterations,
            "acceptance": rep.acceptance,
            "wall_time_this_call": rep.wall_time,
            "burn": self.burn,
            "thin": self.thin,
            "n_samples": int(self.samples.shape[0]),
            "correlation": {
                "names": list(self.names),
                "coordinates": ["log" if lg else "linear" for lg in self.log_scale],
                "matrix": [[float(v) for v in row] for row in corr],
            },
            "map": self.map,
            # per recording, in the order of the recordings (1: no model-discrepancy inflation)
            "inflation": list(getattr(self.calibration, "inflation_", None) or []),
            "at_prior_bound": self.at_prior_bound(),
            "laplace_move": self.laplace_move(),
            "interval_drift": self.interval_drift(),
        }

    def interval_drift(self) -> dict | None:
        """How far the 90 % intervals still move: the two halves of the kept chain (after the
        burn-in) each give an interval per parameter, and ``largest`` is the largest
        ``(|q05_a - q05_b| + |q95_a - q95_b|) / (q95 - q05)`` over the parameters (``parameter``
        names it), the whole kept chain's width in the denominator, in the sampling coordinates
        (log for log-uniform priors, as :func:`tvcid.discovery.members.set_posterior.not_pinned`
        judges widths). A converged chain's halves agree to a few per cent of the width; a chain
        still wandering differs by a large part of it. ``None`` for a chain under 20 kept
        steps. For an importance run the halves are its points of even and odd index
        (:meth:`.importance.ImportanceRun.interval_drift`)."""
        if self.importance is not None:
            d = self.importance.interval_drift()
            return {"largest": d["largest"], "parameter": self.names[d["index"]]}
        kept = self.chain[self.burn:]
        if kept.shape[0] < 20:
            return None
        logs = np.asarray(self.log_scale, dtype=bool)
        if logs.any():
            kept = kept.copy()
            kept[..., logs] = np.log(kept[..., logs])
        half = kept.shape[0] // 2
        a = kept[:half].reshape(-1, kept.shape[2])
        b = kept[half:].reshape(-1, kept.shape[2])
        qa, qb = np.quantile(a, (0.05, 0.95), axis=0), np.quantile(b, (0.05, 0.95), axis=0)
        q = np.quantile(kept.reshape(-1, kept.shape[2]), (0.05, 0.95), axis=0)
        width = q[1] - q[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            drift = np.where(width > 0, np.abs(qa - qb).sum(axis=0) / width, 0.0)
        j = int(np.argmax(drift))
        return {"largest": float(drift[j]), "parameter": self.names[j]}

    def laplace_move(self) -> dict | None:
        """How the Laplace independence move served the chain
        (:class:`.moves.LaplaceAdaptation`): ``share`` of the steps it took at the end (0:
        switched off, the differential-evolution and chord moves alone), its
        ``expected_acceptance`` at its last fit and the step of that fit (``adapted_at``);
        ``None`` where the run had no such move."""
        info = getattr(self.calibration, "laplace_", None)
        if not info:
            return None
        return {"share": float(info.get("share", 0.0)),
                "expected_acceptance": info.get("expected_acceptance"),
                "adapted_at": info.get("adapted_at")}

    def at_prior_bound(self, fraction=0.1) -> list:
        """Parameters stuck at a prior bound: the whole 90 % interval within ``fraction`` of the
        prior's width (internal coordinates) of one bound and pressed against it (nearer to it
        than the interval is wide), the data pushing them out of the prior. A wide posterior that
        merely reaches a bound is not stuck, nor a narrow one that lies near a bound of a wide
        prior but clear of it (M000's delay, 1.70-1.72 ms in a prior from 1.2 to 20 ms)."""
        lp = getattr(self.calibration, "log_posterior_", None)
        if lp is None:
            return []
        out = []
        q05, q95 = np.quantile(self.internal, [0.05, 0.95], axis=0)
        for j, (n, p) in enumerate(zip(self.names, lp.priors)):
            lo, hi = p.internal_bounds
            width = q95[j] - q05[j]
            low = q95[j] - lo < fraction * (hi - lo) and q05[j] - lo < width
            high = hi - q05[j] < fraction * (hi - lo) and hi - q95[j] < width
            if low or high:
                out.append(n)
        return out

    def to_json(self, path=None, **kwargs):
        text = json.dumps(self.summary(), indent=2, sort_keys=True, default=_jsonable)
        if path is not None:
            with open(path, "w") as fh:
                fh.write(text + "\n")
        return text

    # -- plots ----------------------------------------------------------------------------------
    def plot_corner(self, fig=None, truths=True, **kwargs):
        """Corner plot (``corner`` package) with the truths when known."""
        import corner

        tv = [self.truths.get(n) for n in self.names] if truths else None
        if tv is not None and all(t is None for t in tv):
            tv = None
        return corner.corner(
            self.samples, labels=list(self.names), truths=tv, fig=fig,
            quantiles=[0.05, 0.5, 0.95], show_titles=True, title_fmt=".3g", **kwargs,
        )

    def plot_traces(self, axes=None):
        """Every walker's trace per parameter, burn-in marked; for an importance run, its points
        in the order drawn, shaded by weight, the rounds marked."""
        import matplotlib.pyplot as plt

        ndim = len(self.names)
        if axes is None:
            _, axes = plt.subplots(ndim, 1, figsize=(8, 1.8 * ndim), sharex=True, squeeze=False)
            axes = axes[:, 0]
        if self.importance is not None:
            run = self.importance
            x = self.calibration.log_posterior_.natural(run.points)
            w = run.weights
            order = np.argsort(w)  # the heavy points drawn last, on top
            for j, ax in enumerate(axes):
                ax.scatter(order, x[order, j], c=w[order], s=3, cmap="viridis")
                for edge in np.cumsum(run.counts)[:-1]:
                    ax.axvline(edge, color="k", ls="--", lw=0.8)
                ax.set_ylabel(self.names[j])
            axes[-1].set_xlabel("point (rounds of importance sampling)")
            return axes
        for j, ax in enumerate(axes):
            ax.plot(self.chain[:, :, j], lw=0.4, alpha=0.5)
            ax.axvline(self.burn, color="k", ls="--", lw=0.8)
            t = self.truths.get(self.names[j])
            if t is not None:
                ax.axhline(t, color="C3", lw=1)
            ax.set_ylabel(self.names[j])
        axes[-1].set_xlabel("step")
        return axes

    # -- ArviZ ----------------------------------------------------------------------------------
    def to_inference_data(self, log_likelihood=False, n_draws=200, seed=0):
        """ArviZ ``InferenceData`` (walkers as chains, post burn-in, natural units).

        With ``log_likelihood=True`` the result is instead built on ``n_draws`` random posterior
        draws (one pseudo-chain): its ``posterior`` group holds those draws and its
        ``log_likelihood`` group (variable ``delta``) their pointwise log-likelihood over every
        recording's samples (or whitened features), for ``arviz.waic``/``arviz.loo``.
        """
        import arviz as az

        c = self.chain[self.burn:: self.thin]  # (draw, walker, ndim)
        posterior = {n: np.swapaxes(c[:, :, j], 0, 1) for j, n in enumerate(self.names)}
        idata = az.from_dict(posterior=posterior)
        if log_likelihood:
            ll = self.pointwise_log_likelihood(n_draws=n_draws, seed=seed)
            ll_idata = az.from_dict(
                posterior={n: self._draws[None, :, j] for j, n in enumerate(self.names)},
                log_likelihood={"delta": ll[None, :, :]},
            )
            return ll_idata
        return idata

    def draws(self, n_draws=100, seed=0):
        """``n_draws`` posterior samples (internal coordinates), drawn with a seeded Generator."""
        rng = np.random.default_rng(seed)
        n = self.internal.shape[0]
        idx = rng.choice(n, size=min(n_draws, n), replace=False)
        return self.internal[idx]

    def pointwise_log_likelihood(self, n_draws=200, seed=0):
        """``(n_draws, n_obs)`` pointwise log-likelihood over every recording."""
        z = self.draws(n_draws, seed)
        self._draws = self.calibration.log_posterior_.natural(z)
        return self.calibration.log_posterior_.pointwise(z)

    def predictive(self, n_draws=50, seed=0):
        """Posterior predictive limit cycles of every recording (:class:`PosteriorPredictive`)."""
        lp = self.calibration.log_posterior_
        z = self.draws(n_draws, seed)
        x = lp.natural(z)
        sets = [lp.params_for(row) for row in x]
        sets_ok = [s for s in sets if s is not None]
        curves = {}
        for term in lp.terms:
            if getattr(term, "kind", "") == "features":
                import warnings

                from .likelihood.waveform import IllPosedLikelihoodWarning, WaveformTerm

                wt = WaveformTerm(term.recording, term.window, term.transient, term.dt,
                                  name=term.name)
                with warnings.catch_warnings():  # only drawn here, not a likelihood
                    warnings.simplefilter("ignore", IllPosedLikelihoodWarning)
                    wt.setup(lp.base.replace(**{n: v for n, v in self.calibration.start_.items()
                                                if n != SIGMA}),
                             warm_start=term.warm_start is not None)
                pred = wt.predict(sets_ok)
            else:
                pred = term.predict(sets_ok)
            curves[term.name] = (term.tau, term.data, pred)
        return PosteriorPredictive(curves=curves, label=self.calibration.base_.name)


@dataclass(eq=False)
class PosteriorPredictive:
    """Simulated outputs of posterior draws against each recording.

    ``curves[name] = (t, data, predictions (n_draws, n_t))``; predictions of closed-loop
    recordings are phase-aligned to the data.
    """

    curves: dict
    label: str = "model"

    def band(self, name, level=0.90):
        t, data, pred = self.curves[name]
        a = 0.5 * (1 - level)
        good = np.all(np.isfinite(pred), axis=1)
        lo, med, hi = np.quantile(pred[good], [a, 0.5, 1 - a], axis=0)
        return t, lo, med, hi

    def rms_error(self, name):
        """RMS of data minus the predictive median."""
        t, data, _ = self.curves[name]
        _, _, med, _ = self.band(name)
        return float(np.sqrt(np.mean((data - med) ** 2)))

    def plot(self, name=None, ax=None, seconds=2.0, color="C0", level=0.90):
        """Data and the predictive band over the first ``seconds`` of one recording's window."""
        import matplotlib.pyplot as plt

        name = name or next(iter(self.curves))
        if ax is None:
            _, ax = plt.subplots(figsize=(8, 3))
        t, lo, med, hi = self.band(name, level)
        data = self.curves[name][1]
        sel = t <= t[0] + seconds
        ax.plot(t[sel], data[sel], "k.", ms=1.5, label="data")
        ax.fill_between(t[sel], lo[sel], hi[sel], color=color, alpha=0.35,
                        label=f"{self.label} {int(level * 100)} % band")
        ax.plot(t[sel], med[sel], color=color, lw=1)
        ax.set_xlabel("t in window (s)")
        ax.set_ylabel("delta (rad)")
        ax.set_title(name)
        ax.legend(fontsize=7, loc="upper right")
        return ax


@dataclass(eq=False)
class ModelComparison:
    """Information criteria of several calibrations on the same data.

    ``table`` rows: ``model``, ``k`` (sampled parameters), ``n`` (observations), ``max_loglike``
    (highest log-likelihood over the chain, the MAP under flat priors), ``bic``, ``waic``
    (ArviZ, deviance scale: lower is better), ``p_waic``, ``waic_se``.
    """

    table: list
    predictive: dict

    def best(self, criterion="waic"):
        return min(self.table, key=lambda r: r[criterion])["model"]

    def to_dict(self):
        return {"table": self.table, "best_waic": self.best("waic"), "best_bic": self.best("bic")}

    def plot(self, axes=None, seconds=2.0):
        """Posterior predictive bands of every model on the first recording, one panel each."""
        import matplotlib.pyplot as plt

        names = list(self.predictive)
        if axes is None:
            _, axes = plt.subplots(len(names), 1, figsize=(8, 2.6 * len(names)), squeeze=False)
            axes = axes[:, 0]
        for k, (ax, name) in enumerate(zip(axes, names)):
            self.predictive[name].plot(ax=ax, seconds=seconds, color=f"C{k}")
            row = next(r for r in self.table if r["model"] == name)
            ax.set_title(f"{name}: WAIC {row['waic']:.1f}, BIC {row['bic']:.1f}")
        return axes


@contextlib.contextmanager
def _uninflated(calibration):
    """The calibration's likelihood terms without their discrepancy inflation, for a while."""
    kept = [t.inflation for t in calibration.terms_]
    for t in calibration.terms_:
        t.inflation = 1.0
    try:
        yield
    finally:
        for t, value in zip(calibration.terms_, kept):
            t.inflation = value


def compare(calibrations, n_draws=200, seed=0) -> ModelComparison:
    """WAIC (ArviZ, pointwise log-likelihoods) and BIC at the MAP of fitted calibrations.

    ``calibrations`` is a dict label -> fitted :class:`Calibration` (or a list, labelled by the
    hypothesis name); all must have been fitted on the same recordings with the same likelihood.
    The criteria use each model's own likelihood, without the model-discrepancy inflation
    (tempered likelihoods of different models are not comparable); fit with
    ``discrepancy=False`` for posteriors of that same likelihood.
    """
    import warnings

    import arviz as az

    if not isinstance(calibrations, dict):
        calibrations = {c.base_.name: c for c in calibrations}
    # a record that fell back to its features in one model and not another (Calibration's
    # features_fallback) makes their likelihoods incomparable
    entered = {label: getattr(cal, "likelihoods_", None) for label, cal in calibrations.items()}
    if len({repr(v) for v in entered.values()}) > 1:
        raise ValueError(
            "the calibrations' recordings entered through different likelihoods ("
            + "; ".join(f"{label}: {v}" for label, v in entered.items())
            + "), which cannot be compared: fit them with features_fallback=False or with "
            "likelihood='features'")
    rows, pred = [], {}
    for label, cal in calibrations.items():
        post = cal.posterior_
        chain = cal.sampler_.get_chain()
        flat = chain.reshape(-1, chain.shape[-1])
        i = int(np.argmax(cal.sampler_.get_log_prob().reshape(-1)))  # flat priors: the MLE
        with _uninflated(cal):
            idata = post.to_inference_data(log_likelihood=True, n_draws=n_draws, seed=seed)
            max_ll = float(cal.log_posterior_.log_likelihood(flat[i:i + 1])[0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            w = az.waic(idata, scale="deviance")
        n_obs = int(idata.log_likelihood["delta"].shape[-1])
        k = len(cal.names_)
        rows.append({
            "model": label, "k": k, "n": n_obs, "max_loglike": max_ll,
            "bic": k * math.log(n_obs) - 2 * max_ll,
            "waic": float(w["elpd_waic"]) if "elpd_waic" in w else float(w.iloc[0]),
            "p_waic": float(w["p_waic"]), "waic_se": float(w["se"]),
        })
        pred[label] = post.predictive(n_draws=min(n_draws, 40), seed=seed)
    return ModelComparison(table=rows, predictive=pred)


def _jsonable(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
