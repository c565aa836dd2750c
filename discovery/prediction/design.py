"""Which test to run next: candidate experiments ranked by what they would teach.

Paper 002 broke the dead-zone/backlash ridge of one limit cycle by adding a second controller
setting and open-loop tests; this module asks the question before the test is run. Each candidate
is simulated for every posterior draw and seen through the likelihood term a fit would give it
(:func:`tvcid.discovery.calibration.likelihood.make_term`: limit-cycle features or the phase-aligned
waveform in closed loop, the output error in open loop), built on a synthetic record of the median
model with the posterior's noise; its observables are whitened by that term's noise model.

The expected posterior after the test is averaged over hypothetical truths ``theta_j`` drawn from
the posterior, each with its own noise realisation ``e_j`` (the preposterior of Bayesian design):

* while the test leaves many draws plausible, the updated posterior is the draws reweighted by the
  test's likelihood, ``w_i ~ exp(-|y_i - y_j - e_j|^2 / 2)`` (exact for any nonlinearity, e.g. the
  curved dead-zone/backlash ridge of one limit cycle);
* when the weights collapse onto a few draws (effective sample size below ``min_ess``) the test is
  sharper than the draws can resolve, and the update is the Laplace one at the truth,
  ``C' = (C^-1 + J_j^T J_j)^-1``, with ``J_j`` the whitened observables' Jacobian at ``theta_j``
  (central differences in the sampler's coordinates) and ``C`` the draws' covariance.

The expected information gain on the chosen parameters is the mean of ``0.5 ln(det C/det C'_j)``
(nats, Gaussian entropies) and the expected shrinkage of a parameter's 90 % width the mean of
``sqrt(C'_j,kk / C_kk)``.
"""
from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvcid.models.experiments import OpenLoop

from ..calibration.priors import SIGMA
from .settings import ControllerSetting

__all__ = ["Candidate", "DesignRanking", "load_candidates", "rank_experiments"]

#: Keys of one candidate in the menu file.
CLOSED_KEYS = {"name", "kind", "kp", "kd", "mu", "controller_rate", "lead_zero", "lead_pole",
               "notch_frequency", "notch_damping", "notch_depth", "duration", "sample_rate"}
OPEN_KEYS = {"name", "kind", "waveform", "amplitude", "frequency", "offset", "duration",
             "sample_rate"}


@dataclass(frozen=True)
class Candidate:
    """One experiment of the menu.

    Attributes
    ----------
    name : str
    experiment : ClosedLoop or OpenLoop
    duration : float
        Record length (s): in closed loop the simulated run, whose last part is measured.
    sample_rate : float
        Acquisition rate (Hz).
    """

    name: str
    experiment: object
    duration: float
    sample_rate: float = 1000.0

    @property
    def kind(self) -> str:
        return self.experiment.kind


def _candidate(spec, i) -> Candidate:
    if not isinstance(spec, dict):
        raise ValueError(f"candidate {i}: expected an object, got {spec!r}")
    kind = spec.get("kind")
    if kind not in ("closed", "open"):
        raise ValueError(f"candidate {i}: kind must be 'closed' or 'open' (got {kind!r})")
    allowed = CLOSED_KEYS if kind == "closed" else OPEN_KEYS
    unknown = sorted(set(spec) - allowed)
    if unknown:
        raise ValueError(f"candidate {i} ({kind}): unknown key(s) {', '.join(unknown)}; "
                         f"allowed: {', '.join(sorted(allowed))}")
    try:
        duration = float(spec.get("duration", 20.0 if kind == "closed" else 10.0))
        rate = float(spec.get("sample_rate", 1000.0))
    except (TypeError, ValueError):
        raise ValueError(f"candidate {i}: duration and sample_rate must be numbers") from None
    if not (duration > 0 and rate > 0):
        raise ValueError(f"candidate {i}: duration and sample_rate must be > 0")
    try:
        if kind == "closed":
            values = {k: spec[k] for k in ("kp", "kd", "mu")}
            for k in ("lead_zero", "lead_pole", "notch_frequency", "notch_damping",
                      "notch_depth"):
                if k in spec:
                    values[k] = spec[k]
            setting = ControllerSetting(sample_rate=spec.get("controller_rate"), **values)
            exp = setting.closed_loop()
            default = f"closed loop Kp {exp.kp:g} Kd {exp.kd:g} mu {exp.mu:g}"
        else:
            exp = OpenLoop(spec.get("waveform"), amplitude=spec.get("amplitude", 0.0),
                           frequency=spec.get("frequency", 0.0), offset=spec.get("offset", 0.0))
            default = f"open-loop {exp.waveform} {exp.amplitude:g} rad"
            if exp.waveform in ("square", "sine"):
                default += f" {exp.frequency:g} Hz"
    except KeyError as exc:
        raise ValueError(f"candidate {i} ({kind}): missing key {exc.args[0]}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"candidate {i} ({kind}): {exc}") from None
    return Candidate(name=str(spec.get("name", default)), experiment=exp, duration=duration,
                     sample_rate=rate)


def load_candidates(source) -> list:
    """Candidates from a JSON file (or an already parsed object): a list of objects, or
    ``{"candidates": [...]}``; each ``{"kind": "closed", "kp", "kd", "mu", ...}`` or
    ``{"kind": "open", "waveform": "square"|"sine"|"step", "amplitude", "frequency", ...}``
    with optional ``name``, ``duration`` (s) and ``sample_rate`` (Hz)."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ValueError(f"{path}: no such candidates file") from None
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from None
    else:
        data = source
    if isinstance(data, dict):
        data = data.get("candidates")
    if not isinstance(data, list) or not data:
        raise ValueError("the candidates file must hold a non-empty list of experiments "
                         "(or {\"candidates\": [...]})")
    out = [_candidate(spec, i) for i, spec in enumerate(data)]
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise ValueError("candidate names must be unique")
    return out


def weighted_covariance(z, log_w):
    """Covariance of the rows of ``z`` under normalised weights ``exp(log_w)``, and their
    effective sample size."""
    w = np.exp(log_w - np.max(log_w))
    w /= w.sum()
    mean = w @ z
    dev = z - mean
    return (dev * w[:, None]).T @ dev, float(1.0 / np.sum(w * w))


def laplace_update(prior_cov, jacobian):
    """``(C^-1 + J^T J)^-1``: a Gaussian prior updated by a locally linear, whitened test."""
    precision = np.linalg.inv(prior_cov) + jacobian.T @ jacobian
    return np.linalg.inv(precision)


@dataclass(frozen=True)
class DesignRanking:
    """Candidates ranked by expected information gain on the chosen parameters.

    Attributes
    ----------
    rows : list of dict
        Best first: ``name``, ``kind``, ``information_gain`` (nats), ``shrinkage`` (name ->
        expected ratio of the 90 % width after/before), ``predicted_width``, ``current_width``,
        ``valid_draws``, ``duration``.
    params : tuple of str
    """

    rows: list
    params: tuple
    criterion: str = ("expected information gain (nats; reweighted draws, Laplace where the test "
                      "is sharper than the draws)")

    @property
    def best(self) -> dict:
        return self.rows[0]

    def to_dict(self) -> dict:
        return {"params": list(self.params), "criterion": self.criterion, "ranking": self.rows}

    def plot(self, ax=None):
        """Expected width ratio of every chosen parameter, per candidate (best at the top)."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(7, 0.5 * len(self.rows) + 1.5))
        names = [r["name"] for r in self.rows][::-1]
        y = np.arange(len(names))
        h = 0.8 / max(1, len(self.params))
        for j, p in enumerate(self.params):
            ax.barh(y + j * h, [r["shrinkage"][p] for r in self.rows][::-1], height=h, label=p)
        ax.set_yticks(y + 0.4 - h / 2)
        ax.set_yticklabels(names, fontsize=8)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set_xlabel("expected 90 % width after / before")
        ax.legend(fontsize=8)
        return ax


def _observables(term, param_sets, sigma):
    """Whitened observables of each parameter set through ``term`` (NaN rows: invalid runs)."""
    if hasattr(term, "whitened_residuals"):
        return -term.whitened_residuals(param_sets, np.full(len(param_sets), term.sigma_hat))
    return -term.residuals(param_sets) / sigma


def _jacobian(term, draws, z, sigma, step):
    """Central-difference Jacobian of the whitened observables in the sampler's coordinates."""
    d = z.size
    points = np.repeat(z[None, :], 2 * d, axis=0)
    for k in range(d):
        points[2 * k, k] += step[k]
        points[2 * k + 1, k] -= step[k]
    natural = np.column_stack([draws.priors[n].to_natural(points[:, k])
                               for k, n in enumerate(draws.names)])
    sets = [draws.params_at(row) for row in natural]
    y = _observables(term, sets, sigma)
    return np.column_stack([(y[2 * k] - y[2 * k + 1]) / (2 * step[k]) for k in range(d)])


def expected_update(term, draws, sigma, rng, n_truths=24, min_ess=30.0):
    """Posterior covariances expected after ``term``'s test, one per hypothetical truth.

    Returns
    -------
    prior_cov : ndarray (d, d)
        The draws' covariance in the sampler's coordinates.
    covs : list of ndarray (d, d)
    methods : list of str
        ``"reweighted"`` or ``"laplace"`` per truth.
    valid : int
        Draws whose simulation of the test ran.
    """
    y = _observables(term, draws.param_sets(), sigma)
    ok = np.all(np.isfinite(y), axis=1)
    z, y = draws.internal[ok], y[ok]
    if z.shape[0] < 2 * z.shape[1] + 2:
        raise ValueError(f"{term.name}: only {z.shape[0]} posterior draws run this test")
    prior_cov = np.cov(z.T).reshape(z.shape[1], z.shape[1])
    step = 0.05 * np.sqrt(np.diag(prior_cov))
    truths = rng.choice(z.shape[0], size=min(n_truths, z.shape[0]), replace=False)
    covs, methods = [], []
    for j in truths:
        data = y[j] + rng.standard_normal(y.shape[1])
        log_w = -0.5 * np.sum((y - data) ** 2, axis=1)
        cov, ess = weighted_covariance(z, log_w)
        if ess >= min_ess:
            covs.append(cov)
            methods.append("reweighted")
            continue
        jac = _jacobian(term, draws, z[j], sigma, step)
        if not np.all(np.isfinite(jac)):
            covs.append(cov)
            methods.append("reweighted")
            continue
        covs.append(laplace_update(prior_cov, jac))
        methods.append("laplace")
    return prior_cov, covs, methods, int(ok.sum())


def rank_experiments(draws, candidates, params=None, noise=None, seed=0, n_truths=24,
                     progress=False):
    """Rank ``candidates`` by the information they are expected to add to ``draws``.

    Parameters
    ----------
    draws : PosteriorDraws
    candidates : list of Candidate
    params : sequence of str, optional
        Parameters whose widths matter (default: every sampled one but ``sigma``).
    noise : float, optional
        Sensor-noise sd (rad) of the new test; default the posterior's noise.
    seed : int
        Seed of the synthetic records' noise and of the hypothetical truths.
    n_truths : int
        Hypothetical truths averaged per candidate.

    Raises
    ------
    ValueError
        For a parameter that was not sampled, or no noise level to assume.
    """
    from tvcid.models.synthetic import synthetic_recording

    from ..calibration.likelihood import make_term

    names = list(draws.names)
    chosen = list(params) if params else [n for n in names if n != SIGMA]
    bad = [p for p in chosen if p not in names or p == SIGMA]
    if bad:
        raise ValueError(f"--params {', '.join(bad)}: not sampled in this posterior (sampled: "
                         f"{', '.join(n for n in names if n != SIGMA)})")
    sigma = noise if noise is not None else draws.sigma()
    if sigma is None or not sigma > 0:
        raise ValueError("no noise level known for the new tests: give one (--noise)")
    cfg = draws.config
    idx = [names.index(p) for p in chosen]
    sub = np.ix_(idx, idx)
    median = draws.median_params()
    current = draws.widths()
    features = {"features": tuple(cfg["features"])} if cfg.get("features") else {}
    rng = np.random.default_rng(seed)
    rows = []
    iterator = candidates
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(candidates, desc="candidates", unit="test")
    with tempfile.TemporaryDirectory() as tmp:
        for k, cand in enumerate(iterator):
            rec = synthetic_recording(median, cand.experiment, cand.duration, float(sigma),
                                      seed + k, Path(tmp) / f"candidate{k}.csv",
                                      rate=cand.sample_rate)
            window = min(float(cfg.get("window", 10.0)), 0.5 * cand.duration)
            term = make_term(rec, cfg.get("likelihood", "waveform"), window,
                             float(cfg.get("transient", 6.0)), float(cfg.get("dt", 5e-4)),
                             name=cand.name, rng=np.random.default_rng(seed + k), **features)
            term.setup(median)
            prior, covs, methods, valid = expected_update(term, draws, float(sigma), rng,
                                                          n_truths=n_truths)
            logdet0 = np.linalg.slogdet(prior[sub])[1]
            gains = [0.5 * (logdet0 - np.linalg.slogdet(c[sub])[1]) for c in covs]
            ratios = np.mean([np.sqrt(np.diag(c)[idx] / np.diag(prior)[idx]) for c in covs],
                             axis=0)
            rows.append({
                "name": cand.name,
                "kind": cand.kind,
                "duration": cand.duration,
                "information_gain": float(np.mean(gains)),
                "shrinkage": {p: float(r) for p, r in zip(chosen, ratios)},
                "current_width": {p: current[p] for p in chosen},
                "predicted_width": {p: current[p] * float(r) for p, r in zip(chosen, ratios)},
                "valid_draws": valid,
                "laplace_fraction": float(np.mean([m == "laplace" for m in methods])),
                "likelihood": type(term).__name__,
            })
    rows.sort(key=lambda r: -r["information_gain"])
    return DesignRanking(rows=rows, params=tuple(chosen))
