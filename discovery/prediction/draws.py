"""Posterior draws read back from the output directory of ``tvcid fit`` or ``tvcid discover``.

Both commands checkpoint their chain in an HDF5 file whose ``tvcid`` group records the set-up
(``config``: the hypothesis with every fixed value, the sampled names and their priors). That is all
a prediction needs: the draws become complete :class:`tvcid.models.ActuatorParams`, without the
recordings.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tvcid.models.hypotheses import ActuatorParams, params_from_dict

from ..calibration.priors import SIGMA, LogUniform, Uniform

__all__ = ["NoPosteriorError", "PosteriorDraws", "load_chain_draws", "load_posterior_draws",
           "load_set_draws", "load_set_weights", "load_unsure_members"]

_PRIOR_KINDS = {"Uniform": Uniform, "LogUniform": LogUniform}


class NoPosteriorError(ValueError):
    """A directory that holds no tvcid chain."""


@dataclass(frozen=True)
class PosteriorDraws:
    """Draws of a calibrated posterior as complete parameter sets.

    Attributes
    ----------
    names : tuple of str
        Sampled parameters (``sigma`` included when it was sampled).
    samples : ndarray (n, len(names))
        The draws in natural units.
    internal : ndarray (n, len(names))
        The same in the sampler's coordinates (log for log-uniform priors).
    base : ActuatorParams
        The hypothesis with every non-sampled value as it was fixed.
    priors : dict name -> Prior
    config : dict
        The calibration's set-up as stored in the chain (likelihood, window, dt, ...).
    source : str
        The chain file.
    fixed_sigma : float or None
        The sensor-noise sd (rad) the likelihood used when ``sigma`` was not sampled.
    """

    names: tuple
    samples: np.ndarray
    internal: np.ndarray
    base: ActuatorParams
    priors: dict
    config: dict = field(repr=False)
    source: str = ""
    fixed_sigma: float | None = None

    def __len__(self) -> int:
        return self.samples.shape[0]

    @property
    def physical_names(self) -> tuple:
        return tuple(n for n in self.names if n != SIGMA)

    def params_at(self, row) -> ActuatorParams:
        """A natural-unit row over :attr:`names` as a complete :class:`ActuatorParams`."""
        return self.base.replace(
            **{n: float(row[j]) for j, n in enumerate(self.names) if n != SIGMA}
        )

    def params(self, i) -> ActuatorParams:
        """Draw ``i`` as a complete :class:`ActuatorParams`."""
        return self.params_at(self.samples[i])

    def param_sets(self) -> list:
        return [self.params(i) for i in range(len(self))]

    def median_params(self) -> ActuatorParams:
        """The coordinate-wise posterior median as a parameter set (the DF's "median model")."""
        return self.params_at(np.median(self.samples, axis=0))

    def sigma(self) -> float | None:
        """Posterior median of the sensor-noise sd (rad), or the value it was fixed at."""
        if SIGMA not in self.names:
            return self.fixed_sigma
        return float(np.median(self.samples[:, self.names.index(SIGMA)]))

    def widths(self, level=0.90) -> dict:
        """Central ``level`` interval width of every sampled parameter (natural units)."""
        lo, hi = 0.5 * (1 - level), 0.5 * (1 + level)
        q = np.quantile(self.samples, [lo, hi], axis=0)
        return {n: float(q[1, j] - q[0, j]) for j, n in enumerate(self.names)}


def _chain_file(directory: Path) -> Path:
    if not directory.is_dir():
        raise NoPosteriorError(f"{directory}: no such directory (give the --out of tvcid fit or discover)")
    fit_chain = directory / "chain.h5"
    if fit_chain.is_file():
        return fit_chain
    discovery = directory / "discovery.json"
    if discovery.is_file():
        try:
            name = json.loads(discovery.read_text())["posterior"]["chain"]
        except (ValueError, KeyError, TypeError):
            raise NoPosteriorError(
                f"{discovery} names no posterior chain (was discover run with its MCMC stage?)"
            ) from None
        path = directory / name
        if path.is_file():
            return path
        raise NoPosteriorError(f"{discovery} names the chain {name}, which is not in {directory}")
    raise NoPosteriorError(
        f"{directory} holds no chain (chain.h5 from tvcid fit, or discovery.json from tvcid "
        "discover): run one of them with --out there first"
    )


def _burn_in(backend, iterations) -> int:
    try:
        tau = backend.get_autocorr_time(tol=0)
        tmax = float(np.max(tau))
    except Exception:  # noqa: BLE001 - emcee raises several kinds on very short chains
        tmax = np.nan
    if not np.isfinite(tmax):
        tmax = iterations / 10.0
    return int(min(max(2 * tmax, 0), iterations // 2))


def load_posterior_draws(directory, n_draws=200, seed=0) -> PosteriorDraws:
    """Read ``n_draws`` posterior draws from a ``tvcid fit`` or ``tvcid discover`` directory.

    The first ``2 tau`` steps (at most half the chain) are discarded, as
    :meth:`tvcid.discovery.calibration.Posterior.from_sampler` does, and ``n_draws`` are drawn without
    replacement (with replacement if the chain holds fewer) by a seeded generator.

    Raises
    ------
    NoPosteriorError
        When the directory holds no chain, or the chain no samples.
    """
    return load_chain_draws(_chain_file(Path(directory)), n_draws=n_draws, seed=seed)


def load_chain_draws(path, n_draws=200, seed=0) -> PosteriorDraws:
    """:func:`load_posterior_draws` from one chain file (a discover directory holds one per
    member of its set); where the calibration adopted an importance or nested run and ran no
    chain, ``n_draws`` of its points resampled by their weights."""
    from ..calibration.backend import CheckpointBackend, read_weighted_posterior
    from ..calibration.importance import systematic_resample

    path = Path(path)
    if not path.is_file():
        raise NoPosteriorError(f"{path}: no such chain file")
    if not isinstance(n_draws, (int, np.integer)) or n_draws < 1:
        raise ValueError(f"n_draws must be a positive integer (got {n_draws!r})")
    backend = CheckpointBackend(str(path), name="mcmc", read_only=True)
    try:
        with backend.open("r") as f:
            if "tvcid" not in f or "config" not in f["tvcid"].attrs:
                raise NoPosteriorError(f"{path} is not a tvcid chain (no set-up stored in it)")
            config = json.loads(f["tvcid"].attrs["config"])
            fixed_sigma = f["tvcid"].attrs.get("sigma")
            weighted = read_weighted_posterior(f)
            iterations = int(f["mcmc"].attrs["iteration"]) if "mcmc" in f else 0
    except OSError as exc:
        raise NoPosteriorError(f"{path} cannot be read as a chain ({exc})") from None
    rng = np.random.default_rng(seed)
    if iterations >= 2:  # a chain (only ever run after any run adopted without one)
        z = backend.get_chain(discard=_burn_in(backend, iterations), flat=True)
        z = z[rng.choice(z.shape[0], size=n_draws, replace=z.shape[0] < n_draws)]
    elif weighted is not None:  # an importance or nested run adopted as the posterior
        points, weights = weighted
        z = points[systematic_resample(weights, rng, n_draws)]
    else:
        raise NoPosteriorError(f"{path} holds {iterations} steps: no posterior to draw from yet")
    names = tuple(config["params"])
    priors = {}
    for n in names:
        d = config["priors"][n]
        priors[n] = _PRIOR_KINDS[d["kind"]](d["low"], d["high"])
        if d.get("coordinate") == "linear":
            priors[n] = priors[n].in_linear_coordinate()
    x = np.column_stack([priors[n].to_natural(z[:, j]) for j, n in enumerate(names)])
    base_dict = dict(config["base"])
    base = params_from_dict(config["hypothesis"], base_dict)
    return PosteriorDraws(names=names, samples=x, internal=z, base=base, priors=priors,
                          config=config, source=str(path),
                          fixed_sigma=None if fixed_sigma is None else float(fixed_sigma))


def _set_members(directory: Path) -> list:
    """The ``set_posterior.members`` of a discover directory's ``discovery.json``; ``[]`` for a
    ``tvcid fit`` directory or a discover directory without a set posterior."""
    discovery = directory / "discovery.json"
    if not discovery.is_file() or (directory / "chain.h5").is_file():
        return []
    try:
        members = json.loads(discovery.read_text())["set_posterior"]["members"]
    except (ValueError, KeyError, TypeError):
        return []
    return members if isinstance(members, list) else []


def load_set_draws(directory, n_draws=200, seed=0) -> dict:
    """Posterior draws of every calibrated member of a ``tvcid discover`` directory's set, as
    structure name -> :class:`PosteriorDraws` (best score first; ``n_draws`` each); a
    ``tvcid fit`` directory, or a discover directory without a set posterior, gives its one
    chain under the name of its hypothesis."""
    directory = Path(directory)
    members = _set_members(directory)
    if not members:
        draws = load_posterior_draws(directory, n_draws=n_draws, seed=seed)
        return {draws.base.name: draws}
    out = {}
    for m in members:
        chain = m["posterior"]["chain"]
        out[m["structure"]] = load_chain_draws(directory / chain, n_draws=n_draws, seed=seed)
    return out


def load_set_weights(directory) -> dict | None:
    """The weight of every member of a ``tvcid discover`` directory's set, as structure name ->
    weight normalised to sum 1 over the members :func:`load_set_draws` reads.

    The weights are ``discovery.json``'s ``set_posterior.members[i].weight``. ``None`` when no
    member stores one, or the directory holds a single structure: the members then weigh
    alike.

    Raises
    ------
    ValueError
        When some members store a weight and others not, a weight is not a finite number
        >= 0, or every weight is 0.
    """
    directory = Path(directory)
    members = _set_members(directory)
    if len(members) < 2:
        return None
    stored = {m["structure"]: m.get("weight") for m in members}
    if all(w is None for w in stored.values()):
        return None
    where = directory / "discovery.json"
    missing = [n for n, w in stored.items() if w is None]
    if missing:
        raise ValueError(f"{where}: member {missing[0]} stores no weight while others do")
    for name, w in stored.items():
        number = isinstance(w, (int, float)) and not isinstance(w, bool)
        if not (number and np.isfinite(w) and w >= 0):
            raise ValueError(f"{where}: member {name}'s weight {w!r} is not a finite number >= 0")
    total = float(sum(stored.values()))
    if total <= 0:
        raise ValueError(f"{where}: every member's weight is 0")
    return {n: float(w) / total for n, w in stored.items()}


def load_unsure_members(directory) -> tuple:
    """The members of a ``tvcid discover`` directory's set whose weight is not final
    (:func:`tvcid.discovery.members.set_weights.stored_unsure`). Empty for a single structure
    or a ``tvcid fit`` directory."""
    from tvcid.discovery.members.set_weights import stored_unsure

    directory = Path(directory)
    if not _set_members(directory):
        return ()
    return tuple(stored_unsure(json.loads((directory / "discovery.json").read_text())
                               ["set_posterior"]))
