"""The members' shares of the weight read off the ranking's held-out scores, with no calibration:
the comparison :func:`.set_weights.evidence_weights` prints beside the weights, and the share of
the members the cap leaves uncalibrated.

**Weights from the ranking.** A structure's ``score`` is its two-fold held-out cost: the sum over
recordings of each recording's mean squared residual in units of what it resolves (about 1 per
recording for the generating model), not a log density, so ``exp(-score / 2)`` would count a
recording's hundreds of residuals as one, and ``exp(-n score / 2)`` would count their correlated
stretches as independent. The ranking's own yardstick is the standard error behind its margin
(:func:`tvcid.discovery.structure.indistinguishable.indistinguishable_margin`): that of a score's
difference from the best. A member's share is its probability of having the lowest expected held-out
score, its difference from the best normal with that standard error. The members the cap leaves
uncalibrated get their share this way (:func:`uncalibrated_share`), so the report can say what part
of the weight was not calibrated.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["UncalibratedShare", "ranking_shares", "uncalibrated_share", "RANKING_RULE",
           "RANKING_DRAWS"]

#: Draws of the ranking-based share (:func:`ranking_shares`).
RANKING_DRAWS = 20000
#: The ranking-based share's rule (:func:`ranking_shares`).
RANKING_RULE = ("probability of the lowest expected two-fold held-out score, each member's "
                "difference from the best normal with the standard error behind its margin "
                "(differences drawn independently)")


def ranking_shares(rows, seed=0, n_draws=RANKING_DRAWS) -> dict:
    """Approximate weights of the set's members from the ranking alone (no calibration).

    Each member's share is the probability that its expected two-fold held-out score is the lowest:
    its difference from the best score is drawn normal, with mean the observed difference and
    standard error ``margin_se``, the one behind its ``margin``
    (:func:`tvcid.discovery.structure.indistinguishable.indistinguishable_margin`; half the margin
    in a ranking that stores none); the best's own row (no margin) is exact; the differences are
    drawn independently with a seeded ``numpy.random.Generator``, which ignores that they share the
    best's error (the shares then lean slightly towards equal). A score is not a log density (the
    module docstring), so it is not put through ``exp(-score / 2)``.

    Parameters
    ----------
    rows : list of dict
        The members' rows of ``discovery.json``'s ``structures``: ``structure``, ``score`` and
        ``margin`` (``None`` for the best) and ``margin_se``.
    seed : int
    n_draws : int

    Returns
    -------
    dict
        Structure -> share, summing to 1 (0 for a row without a finite score).
    """
    names = [r["structure"] for r in rows]
    if not names:
        return {}
    score = np.array([_number(r.get("score")) for r in rows])
    se = np.array([_se(r) for r in rows])
    ok = np.isfinite(score) & np.isfinite(se)
    if not ok.any():
        return {n: 1.0 / len(names) for n in names}
    rng = np.random.default_rng(seed)
    draws = score[ok] + se[ok] * rng.standard_normal((int(n_draws), int(ok.sum())))
    wins = np.bincount(np.argmin(draws, axis=1), minlength=int(ok.sum())) / float(n_draws)
    shares = np.zeros(len(names))
    shares[ok] = wins
    return {n: float(s) for n, s in zip(names, shares)}


@dataclass
class UncalibratedShare:
    """The members the cap leaves uncalibrated, and their share of the weight by the ranking
    (:func:`uncalibrated_share`).

    Attributes
    ----------
    names : list of str
        The uncalibrated members, best score first.
    share : float
        Their share of the weight by the ranking (:func:`ranking_shares`).
    shares : dict
        Every member's share by the ranking.
    rule : str
    """

    names: list
    share: float
    shares: dict
    rule: str = RANKING_RULE

    def sentence(self) -> str:
        """``"dropped: X, Y (about Z % of the weight by their held-out scores)"``, or ``""``."""
        if not self.names:
            return ""
        return (f"dropped: {', '.join(self.names)} (about {100 * self.share:.0f} % of the weight "
                "by their held-out scores)")

    def to_dict(self) -> dict:
        return {"names": list(self.names), "share": self.share, "shares": dict(self.shares),
                "rule": self.rule}


def uncalibrated_share(rows, calibrated, seed=0) -> UncalibratedShare:
    """The members of ``rows`` not in ``calibrated``, and their share of the weight by the
    ranking (:func:`ranking_shares` over all of ``rows``).

    Parameters
    ----------
    rows : list of dict
        Every member's row (``structure``, ``score``, ``margin``), calibrated or not.
    calibrated : iterable of str
        The structures that were calibrated.
    seed : int
    """
    calibrated = set(calibrated)
    shares = ranking_shares(rows, seed=seed)
    names = [r["structure"] for r in rows if r["structure"] not in calibrated]
    return UncalibratedShare(names, float(sum(shares[n] for n in names)), shares)


def _se(row) -> float:
    """A row's standard error of its score's difference from the best: its ``margin_se``, or
    half its ``margin`` in a ranking that stores none; 0 for the best (no margin)."""
    if row.get("margin") is None:
        return 0.0
    if row.get("margin_se") is not None:
        return _number(row["margin_se"])
    return _number(row["margin"]) / 2.0


def _number(v) -> float:
    """A JSON number, ``None`` (an infinite value written as ``null``) as infinity."""
    return math.inf if v is None else float(v)
