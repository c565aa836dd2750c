"""The combinations of parameters a posterior pins, and the directions it leaves to the prior.

A limit cycle fixes a few numbers (an amplitude, a frequency, a waveform's harmonics), so a
posterior on cycles alone is narrow along a few combinations of the parameters and as wide as
the prior along the rest: paper 002's one-parameter family of (dead zone, backlash) pairs that all
reproduce one cycle (its eqs. 13-18; :mod:`tvcid.discovery.calibration.ridge` draws it). One parameter's
interval then says little: each spans much of its prior while their combination is known to a
fraction of a percent.

:func:`pinned_combinations` finds those combinations from the posterior's draws. Each parameter
is taken in the coordinate its prior is flat in (the logarithm under a log-uniform prior, the
value under a uniform one) and scaled by the prior's sd there, so that the prior is a unit
variance in every direction; the principal directions of the draws' covariance in those units
whose sd is under :data:`PINNED_SHRINKAGE` are pinned: the recordings know them to that fraction
of what the prior allows. Each is written back in the parameters' own coordinates, its terms
under :data:`TERM_FLOOR` of the largest (in prior-sd units) dropped, the largest coefficient 1. Over log
coordinates alone a combination is a product of powers (``dead_zone * backlash^0.62``) and its
value is printed in the first parameter's unit raised to its powers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .priors import LogUniform

__all__ = ["PinnedCombination", "PinnedMap", "pinned_combinations", "PINNED_SHRINKAGE",
           "TERM_FLOOR"]

#: A direction is pinned when the draws' sd along it is under this fraction of the prior's.
PINNED_SHRINKAGE = 0.1
#: Terms of a pinned direction under this fraction of its largest (in prior-sd units) are left
#: out of its combination.
TERM_FLOOR = 0.1
#: The interval printed for a combination.
LEVEL = 0.90


@dataclass(frozen=True)
class PinnedCombination:
    """One combination of parameters the posterior pins.

    Attributes
    ----------
    terms : dict
        Parameter -> its coefficient on the parameter's prior-flat coordinate (``log`` of the
        parameter under a log-uniform prior, else the parameter); the largest in magnitude is 1.
    logs : dict
        Parameter -> whether its coordinate is the logarithm.
    median, low, high : float
        The combination's median and 90 % interval over the draws, in the prior-flat
        coordinates (``sum_j terms[j] * coordinate_j``).
    shrinkage : float
        The draws' sd along the direction over the prior's.
    """

    terms: dict
    logs: dict
    median: float
    low: float
    high: float
    shrinkage: float

    @property
    def product(self) -> bool:
        """Whether every term is a logarithm: the combination is a product of powers."""
        return all(self.logs[n] for n in self.terms)

    def text(self) -> str:
        """The combination in words, e.g. ``dead_zone * backlash^0.62 = 3.41e-05 (90 % 3.39e-05
        to 3.43e-05)``; a sum of coordinates where some are not logarithms."""
        def coef(c):
            return f"{abs(c):.2g}"

        if self.product:
            parts = []
            for i, (name, c) in enumerate(self.terms.items()):
                power = "" if abs(c - 1.0) < 5e-3 else f"^{c:.2g}"
                parts.append(("" if i == 0 else " * ") + name + power)
            value = [math.exp(v) for v in (self.median, self.low, self.high)]
        else:
            parts = []
            for i, (name, c) in enumerate(self.terms.items()):
                term = f"ln {name}" if self.logs[name] else name
                sign = ("-" if c < 0 else "") if i == 0 else (" - " if c < 0 else " + ")
                parts.append(sign + ("" if abs(abs(c) - 1.0) < 5e-3 else coef(c) + " ") + term)
            value = [self.median, self.low, self.high]
        return (f"{''.join(parts)} = {value[0]:.4g} ({100 * LEVEL:.0f} % {value[1]:.4g} to "
                f"{value[2]:.4g}; "
                f"{self.shrinkage:.2g} of the prior's sd)")

    def to_dict(self) -> dict:
        return {"terms": dict(self.terms), "logs": dict(self.logs), "median": self.median,
                "low": self.low, "high": self.high, "shrinkage": self.shrinkage,
                "text": self.text()}


@dataclass(frozen=True)
class PinnedMap:
    """What a posterior pins and what it leaves free.

    Attributes
    ----------
    pinned : tuple of PinnedCombination
        The pinned directions, most tightly pinned first.
    free : int
        The directions the draws leave at :data:`PINNED_SHRINKAGE` of the prior's sd or wider.
    shrinkages : tuple of float
        The draws' sd over the prior's along every principal direction, ascending.
    """

    pinned: tuple
    free: int
    shrinkages: tuple

    def to_dict(self) -> dict:
        return {"pinned": [c.to_dict() for c in self.pinned], "free": self.free,
                "shrinkages": list(self.shrinkages)}


def pinned_combinations(samples, names, priors, shrinkage=PINNED_SHRINKAGE,
                        floor=TERM_FLOOR) -> PinnedMap:
    """The combinations of parameters the draws ``samples`` pin (see the module's docstring).

    Parameters
    ----------
    samples : ndarray, shape (n, d)
        Posterior draws in the parameters' natural units.
    names : sequence of str
        The columns' parameters; those without a prior in ``priors`` (the noise sd) are left out.
    priors : dict
        Parameter -> :class:`tvcid.discovery.calibration.priors.Prior` (uniform in its internal
        coordinate).
    shrinkage, floor : float
        :data:`PINNED_SHRINKAGE` and :data:`TERM_FLOOR`.

    Returns
    -------
    PinnedMap
    """
    samples = np.asarray(samples, dtype=float)
    cols = [j for j, n in enumerate(names) if n in priors]
    if samples.ndim != 2 or samples.shape[0] < 3 or not cols:
        return PinnedMap((), len(cols), ())
    used = [names[j] for j in cols]
    logs = {n: isinstance(priors[n], LogUniform) for n in used}

    def flat(n, x):  # the coordinate the prior is flat in
        return np.log(x) if logs[n] else priors[n].to_internal(x)

    z = np.column_stack([flat(n, samples[:, j]) for n, j in zip(used, cols)])
    lo_hi = np.array([[flat(n, priors[n].low), flat(n, priors[n].high)] for n in used],
                     dtype=float)
    prior_sd = (lo_hi[:, 1] - lo_hi[:, 0]) / math.sqrt(12.0)
    u = (z - z.mean(axis=0)) / prior_sd
    cov = np.atleast_2d(np.cov(u, rowvar=False))
    values, vectors = np.linalg.eigh(cov)
    sds = np.sqrt(np.clip(values, 0.0, None))
    pinned = []
    for k in np.flatnonzero(sds < shrinkage):
        v = vectors[:, k]
        keep = np.abs(v) >= floor * np.max(np.abs(v))
        coef = np.where(keep, v / prior_sd, 0.0)  # on the prior-flat coordinates themselves
        order = sorted(np.flatnonzero(keep), key=lambda j: -abs(coef[j]))
        coef = coef / coef[order[0]]  # the largest coefficient 1 (sign included)
        values_k = z @ coef
        q_lo, q_mid, q_hi = np.quantile(values_k, (0.5 - LEVEL / 2, 0.5, 0.5 + LEVEL / 2))
        pinned.append(PinnedCombination(
            terms={used[j]: float(coef[j]) for j in order},
            logs={used[j]: logs[used[j]] for j in order},
            median=float(q_mid), low=float(q_lo), high=float(q_hi), shrinkage=float(sds[k])))
    return PinnedMap(tuple(pinned), int(np.sum(sds >= shrinkage)), tuple(float(s) for s in sds))
