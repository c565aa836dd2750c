"""The weights of the set's members: how much of the combined posterior each structure gets.

The set (:mod:`discovery.structure.indistinguishable`) holds the structures whose held-out scores
the two folds cannot separate from the best; each member is calibrated on its own
(:func:`discovery.structure.member_calibration.calibrate_member`). This module weighs the
calibrated members by their out-of-sample predictive densities:

* :func:`member_pointwise` -- a member's pointwise log-likelihood draws over every recording
  (:meth:`discovery.calibration.Posterior.pointwise_log_likelihood`, without the discrepancy
  factor, as :func:`discovery.calibration.posterior.compare` evaluates them);
* :func:`align_pointwise` -- the same observations in every member, grouped into the units the
  comparison leaves out one at a time;
* :func:`member_weights` -- the weights (pseudo-BMA+ on PSIS-LOO), their diagnostics, stacking's
  weights and the equal-weight alternative beside them;
* :func:`weigh_set` -- the two above as ``tvcid discover`` uses them, with the held-out scores'
  weights (:mod:`.ranking_shares`, which also weighs the members the cap leaves uncalibrated)
  where PSIS-LOO cannot weigh the members.

**The weights: pseudo-BMA+, not stacking.** Each member's leave-one-unit-out predictive density
is estimated by Pareto-smoothed importance sampling (PSIS-LOO, :func:`arviz.loo`); the weights
are pseudo-BMA+ (Yao, Vehtari, Simpson & Gelman 2018, "Using stacking to average Bayesian
predictive distributions", Bayesian Analysis 13(3), section 3.3): Akaike-type weights
``exp(elpd_loo)`` averaged over a Bayesian bootstrap of the units (``arviz.compare(...,
method="BB-pseudo-BMA")``), which carries the elpd estimates' uncertainty into the weights.
Stacking (the same paper's section 3.2, ``method="stacking"``) is computed too and returned as an
alternative, not used: it optimises the mixture's predictive density, and the set's members are
structures whose predictions nearly coincide (a delay at another place, a component at its
zero), where that optimum is flat and its maximiser falls on a corner by the noise: on two
copies of the same Gaussian model, stacking hands one of them nearly all the weight on the
draws' Monte Carlo noise alone, where pseudo-BMA+ gives each about half
(tests/test_set_weights.py). The combined posterior states what the recordings leave open about
the structure, so a weight that jumps between 0 and 1 on the noise is the ranking on noise the
set exists to avoid; pseudo-BMA+ stays graded where an elpd difference is inside its error and
goes to 0 where it is far outside.

**The unit left out.** The units must be the same observations in every member.

* A closed-loop record enters the calibration as its limit-cycle features (frequency,
  harmonics, in a fixed order), whitened by the Cholesky factor ``L`` of the member's own
  covariance: the record's (sensor noise, wander) plus the member's solver-error and
  start-imprint variances, which differ from member to member. Whitened feature ``j`` is then the ``j``-th
  factor of the chain rule, ``p(r) = prod_j p(r_j | r_1 .. r_(j-1))``: the same data (the
  first ``j`` features' residuals) in every member, each member's own conditional density of
  it. The likelihood spreads the log-determinant evenly over the features;
  :func:`member_pointwise` gives each factor its own normaliser, ``log L_jj``, so that a unit is
  exactly that conditional density (the record's total is unchanged). Each feature is a unit.
* An open-loop record enters as thousands of samples whose misfit is correlated over many of
  them: left out one at a time, a sample is predicted by its neighbours, and a bootstrap over
  samples counts each correlated stretch as many independent draws, so that an elpd difference
  inside the noise reads as decisive. Blocks of twice the integrated autocorrelation time of
  the members' pointwise differences (at least five a record) keep two members of equal quality
  near equal weights on a correlated misfit where single samples do not
  (tests/test_set_weights.py). Each block is a unit (:func:`align_pointwise`).

The log-likelihood is each member's own without the discrepancy factor that tempers its
posterior, as :func:`discovery.calibration.posterior.compare` evaluates it (a tempered
likelihood is not a density, and its normalising constant differs by member): PSIS then removes
a unit with the untempered power, which overstates the removal in a member whose factor exceeds
1 and makes its elpd and Pareto k, if anything, pessimistic.

**Reliability, and where PSIS-LOO cannot weigh.** PSIS is unreliable where a unit's Pareto k
exceeds ``min(1 - 1/log10(S), 0.7)`` for ``S`` draws (arviz's ``good_k``: 0.57 at 200 draws): the
diagnostics give each member's largest k and how many units exceed it, and the notes say so. A
unit whose removal moves the posterior far is common here: a few features pin several
parameters, so each is influential. Where any unit of any member is unreliable, or fewer than two
units remain, :func:`weigh_set` uses the held-out scores' weights
(:func:`.ranking_shares.ranking_shares`), computed from refits on held-out halves of every
recording: a cross-validation that needs no importance sampling.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from .ranking_shares import RANKING_RULE, ranking_shares

__all__ = ["MemberPointwise", "Alignment", "SetWeights", "member_pointwise", "align_pointwise",
           "member_weights", "weigh_set", "EQUAL_RULE", "BLOCK_TAU", "MIN_BLOCKS"]

#: Blocks of an open-loop record are at least this many integrated autocorrelation times long.
BLOCK_TAU = 2.0
#: ... and a record holds at least this many blocks (a longer correlation gives fewer, longer
#: blocks no further).
MIN_BLOCKS = 5
#: Bayesian-bootstrap draws of pseudo-BMA+.
B_SAMPLES = 1000
#: The equal-weight alternative's rule.
EQUAL_RULE = ("equal weights: 1/n for each of the n calibrated members, by count, since every "
              "member's held-out score is within the margin of the best")
#: The weights' rule (:func:`member_weights`).
PSEUDO_BMA_RULE = ("pseudo-BMA+ (Yao et al. 2018): exp(elpd_loo) of each member's PSIS "
                   "leave-one-out predictive density, averaged over a Bayesian bootstrap of the "
                   "units ({units})")


# -- the members' pointwise log-likelihoods ------------------------------------------------------
@dataclass(frozen=True)
class MemberPointwise:
    """One calibrated member's pointwise log-likelihood draws (:func:`member_pointwise`).

    Attributes
    ----------
    log_lik : ndarray (n_draws, n_obs)
        Log-likelihood of every observation at each posterior draw, without the discrepancy
        factor; ``-inf`` where a draw's run failed. A closed-loop record's column ``j`` is the
        conditional density of its feature ``j`` given the features before it (the module
        docstring).
    records : tuple of (name, kind, n)
        The observations' recordings in column order: ``kind`` ``"features"`` (a closed-loop
        record's whitened features) or ``"open"`` (an open-loop record's samples), ``n`` columns.
    inflation : tuple of float
        The discrepancy factor each recording's likelihood is divided by in the member's
        posterior (not applied to ``log_lik``).
    features : dict
        Closed-loop record -> its features' names, in column order.
    """

    log_lik: np.ndarray
    records: tuple
    inflation: tuple = ()
    features: dict = field(default_factory=dict)


def member_pointwise(posterior, n_draws=200, seed=0) -> MemberPointwise:
    """Pointwise log-likelihood draws of one calibrated member over every recording.

    :meth:`discovery.calibration.Posterior.pointwise_log_likelihood` at ``n_draws`` posterior
    draws (chosen with a seeded ``numpy.random.Generator``), with each recording's discrepancy
    factor set aside as :func:`discovery.calibration.posterior.compare` does: a tempered
    log-likelihood is not a density, and its normalising constant differs from member to member.
    A closed-loop record's whitened features get their own normalisers (:func:`_chain_rule_offsets`
    of the covariance the member whitens them with), which makes each the conditional density
    of one feature given the ones before it.

    Parameters
    ----------
    posterior : discovery.calibration.Posterior
        A member's posterior with its calibration (``calibrate_member``'s first return value).
    n_draws : int
        Posterior draws evaluated (each simulates every recording once).
    seed : int

    Returns
    -------
    MemberPointwise
    """
    from discovery.calibration.log_posterior import term_size
    from discovery.calibration.posterior import _uninflated

    cal = posterior.calibration
    if cal is None:
        raise ValueError("member_pointwise: the posterior has no calibration to evaluate "
                         "(a posterior read back from JSON cannot be)")
    with _uninflated(cal):
        ll = np.asarray(posterior.pointwise_log_likelihood(n_draws=n_draws, seed=seed), dtype=float)
    terms = cal.log_posterior_.terms
    records = tuple((t.name, "open" if t.recording.kind == "open" else t.kind, int(term_size(t)))
                    for t in terms)
    if sum(r[2] for r in records) != ll.shape[1]:
        raise RuntimeError(f"member_pointwise: {ll.shape[1]} columns for records {records}")
    start, features = 0, {}
    for t, (name, kind, n) in zip(terms, records):
        if getattr(t, "kind", "") == "features":
            ll[:, start:start + n] += _chain_rule_offsets(t.cov_hat)[None, :]
            features[name] = tuple(t.features)
        start += n
    inflation = tuple(float(np.max(t.inflation)) for t in terms)
    return MemberPointwise(ll, records, inflation, features)


def _chain_rule_offsets(cov):
    """What turns a Gaussian's whitened pointwise log densities, each carrying ``1/k`` of the
    log-determinant, into the chain rule's conditional densities: ``log det(C) / (2k) - log
    L_jj`` for the Cholesky factor ``L`` of the ``k x k`` covariance ``C`` (they sum to 0)."""
    diag = np.log(np.diag(np.linalg.cholesky(np.asarray(cov, dtype=float))))
    return diag.mean() - diag


@dataclass
class Alignment:
    """The members' log-likelihoods on common units (:func:`align_pointwise`).

    Attributes
    ----------
    pointwise : dict
        Member -> ``(n_draws, n_units)``, each unit's log-likelihood (its observations summed).
    units : list of str
        ``record:feature`` for a feature, ``record:first-last`` for a block of samples.
    block : dict
        Open-loop record -> samples per block.
    notes : list of str
        Recordings left out, and why.
    """

    pointwise: dict
    units: list
    block: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


def align_pointwise(members) -> Alignment:
    """Put the members' pointwise log-likelihoods on the same units.

    A recording enters only where every member holds it with the same kind and number of
    observations (the same record, window and likelihood); one that does not is left out, with
    a note, as is a closed-loop record whose features differ in name or order
    (:attr:`MemberPointwise.features`, where given). A closed-loop record's features are a unit
    each (the module docstring says why they are the same observations). An open-loop record's
    samples are cut into contiguous blocks of ``BLOCK_TAU`` integrated autocorrelation times of
    the members' pointwise differences from the best member (emcee's estimator on their
    posterior means; the longest over the members), at least 1 sample and at most
    ``n / MIN_BLOCKS`` (the module docstring says why).

    Parameters
    ----------
    members : dict
        Member name -> :class:`MemberPointwise`.

    Returns
    -------
    Alignment
    """
    from emcee.autocorr import integrated_time

    names = list(members)
    if not names:
        raise ValueError("align_pointwise: no member")
    spans = {}
    for name in names:
        start, own = 0, {}
        for rec, kind, n in members[name].records:
            own[rec] = (kind, n, start)
            start += n
        spans[name] = own
    notes, kept = [], []
    for rec, kind, n in members[names[0]].records:
        named = {members[m].features.get(rec) for m in names} - {None}
        if all(spans[m].get(rec, (None, None))[:2] == (kind, n) for m in names) and len(named) < 2:
            kept.append((rec, kind, n))
        else:
            seen = "; ".join(f"{m}: {spans[m][rec][:2] if rec in spans[m] else 'absent'}"
                             f" {members[m].features.get(rec) or ''}".rstrip() for m in names)
            notes.append(f"{rec} left out of the weights: its observations differ between the "
                         f"members ({seen})")
    for m in names[1:]:
        for rec in spans[m]:
            if rec not in spans[names[0]]:
                notes.append(f"{rec} left out of the weights: not in every member")

    def columns(m, rec):
        _, n, start = spans[m][rec]
        return members[m].log_lik[:, start:start + n]

    groups, units, block = [], [], {}
    for rec, kind, n in kept:
        if kind == "features":
            labels = members[names[0]].features.get(rec) or tuple(range(n))
            groups += [(rec, [j]) for j in range(n)]
            units += [f"{rec}:{label}" for label in labels]
            continue
        means = {m: _finite_mean(columns(m, rec)) for m in names}
        ref = max(names, key=lambda m: float(np.sum(means[m])))
        series = [means[m] - means[ref] for m in names if m != ref] or [means[ref]]
        tau = max(float(integrated_time(s - s.mean(), c=5, tol=0, quiet=True)[0])
                  if np.ptp(s) > 0 else 1.0 for s in series)
        length = int(min(max(1, math.ceil(BLOCK_TAU * tau)), max(1, n // MIN_BLOCKS)))
        block[rec] = length
        for first in range(0, n, length):
            last = min(n, first + length)
            if n - last < length // 2:  # a short tail joins the last block
                last = n
            groups.append((rec, list(range(first, last))))
            units.append(f"{rec}:{first}-{last - 1}")
            if last == n:
                break
    pointwise = {m: np.column_stack([columns(m, rec)[:, cols].sum(axis=1) for rec, cols in groups])
                 if groups else np.zeros((members[m].log_lik.shape[0], 0)) for m in names}
    return Alignment(pointwise, units, block, notes)


def _finite_mean(ll):
    """Posterior mean of each column over the draws whose every value is finite."""
    ok = np.all(np.isfinite(ll), axis=1)
    return ll[ok].mean(axis=0) if ok.any() else np.zeros(ll.shape[1])


# -- the weights ----------------------------------------------------------------------------------
@dataclass
class SetWeights:
    """The members' weights (:func:`member_weights`).

    Attributes
    ----------
    weights : dict
        Member -> weight, summing to 1 (the members' order kept).
    method : str
        ``"pseudo-BMA+"``; ``"held-out scores"`` (:func:`weigh_set`'s fallback) or ``"equal"``
        where PSIS-LOO could not weigh the members (``notes`` say why); ``"single member"``.
    rule : str
        How ``weights`` are made, in words (for the report and ``combine``'s ``criterion``).
    equal : dict
        Member -> ``1/n``, the equal-weight alternative; ``equal_rule`` states it.
    equal_rule : str
    stacking : dict or None
        Member -> stacking weight (Yao et al. 2018, section 3.2): an alternative, not used (the
        module docstring says why).
    pseudo_bma : dict or None
        Member -> pseudo-BMA+ weight, where computed (also when not the one used).
    diagnostics : dict
        Member -> ``elpd_loo`` and its ``se`` (nats), ``p_loo``, ``elpd_diff`` and ``dse`` (from
        the best member), ``pareto_k_max``, ``good_k`` (the PSIS threshold at this many draws),
        ``n_bad_k`` (units above it), ``psis_reliable``, ``n_units``, ``n_draws`` and
        ``dropped_draws`` (draws with a failed run), ``inflation`` where given.
    notes : list of str
        What the reader must know: left-out recordings, unreliable PSIS, fallbacks.
    """

    weights: dict
    method: str
    rule: str
    equal: dict
    equal_rule: str = EQUAL_RULE
    stacking: dict | None = None
    pseudo_bma: dict | None = None
    diagnostics: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    @property
    def psis_reliable(self) -> bool:
        """Every member's PSIS-LOO is reliable on every unit (``False`` where not computed)."""
        return bool(self.diagnostics) and all(d.get("psis_reliable", False)
                                              for d in self.diagnostics.values())

    def of(self, names) -> list:
        """The weights of ``names``, in that order (``combine``'s ``weights`` argument)."""
        return [self.weights[n] for n in names]

    def to_dict(self) -> dict:
        return {"weights": dict(self.weights), "method": self.method, "rule": self.rule,
                "equal": dict(self.equal), "equal_rule": self.equal_rule,
                "stacking": None if self.stacking is None else dict(self.stacking),
                "pseudo_bma": None if self.pseudo_bma is None else dict(self.pseudo_bma),
                "diagnostics": self.diagnostics, "notes": list(self.notes)}


def member_weights(pointwise, units=None, seed=0, notes=(), inflation=None,
                   b_samples=B_SAMPLES) -> SetWeights:
    """Weigh the members by their leave-one-out predictive densities: pseudo-BMA+ on PSIS-LOO.

    Each member's elpd per unit is estimated by PSIS-LOO (:func:`arviz.loo`, relative efficiency
    1: the draws are picked at random from a thinned chain); the weights are
    ``arviz.compare(..., method="BB-pseudo-BMA")`` (pseudo-BMA+, Yao, Vehtari, Simpson & Gelman
    2018, "Using stacking to average Bayesian predictive distributions", section 3.3), with a
    Bayesian bootstrap of ``b_samples`` Dirichlet(1) draws from a seeded
    ``numpy.random.Generator``. Stacking's weights (section 3.2) are computed beside them; the
    module docstring says why they are not the ones used.

    Parameters
    ----------
    pointwise : dict
        Member name -> ``(n_draws, n_obs)`` log-likelihood draws on the same observations in
        every member (:func:`align_pointwise`'s ``pointwise``); draws with a non-finite value are
        dropped, member by member.
    units : sequence, optional
        A label per observation: observations with the same label are summed into one unit,
        which the comparison leaves out as a whole (e.g. a block of correlated samples).
        Default: every observation its own unit.
    seed : int
    notes : sequence of str
        Notes carried into the result (:attr:`Alignment.notes`).
    inflation : dict, optional
        Member -> its discrepancy factors (:attr:`MemberPointwise.inflation`), for the
        diagnostics.
    b_samples : int
        Bayesian-bootstrap draws.

    Returns
    -------
    SetWeights
        Equal weights, with the reason in ``notes``, where there are fewer than two units or a
        member has no finite draw.
    """
    import arviz as az

    names = list(pointwise)
    if not names:
        raise ValueError("member_weights: no member")
    equal = {n: 1.0 / len(names) for n in names}
    notes = list(notes)
    if len(names) == 1:
        return SetWeights({names[0]: 1.0}, "single member", "a single member takes all the weight",
                          equal, notes=notes)
    arrays = {n: np.atleast_2d(np.asarray(pointwise[n], dtype=float)) for n in names}
    n_obs = {a.shape[1] for a in arrays.values()}
    if len(n_obs) != 1:
        raise ValueError("member_weights: the members' observations differ in number "
                         f"({ {n: a.shape[1] for n, a in arrays.items()} }); align them first "
                         "(align_pointwise)")
    if units is not None:
        labels = list(units)
        if len(labels) != next(iter(n_obs)):
            raise ValueError(f"member_weights: {len(labels)} unit labels for {next(iter(n_obs))} "
                             "observations")
        position = {u: k for k, u in enumerate(dict.fromkeys(labels))}
        order = list(position)
        index = np.array([position[u] for u in labels])
        arrays = {n: np.column_stack([a[:, index == k].sum(axis=1) for k in range(len(order))])
                  for n, a in arrays.items()}
    kept, dropped = {}, {}
    for n, a in arrays.items():
        ok = np.all(np.isfinite(a), axis=1)
        kept[n], dropped[n] = a[ok], int((~ok).sum())
    n_units = next(iter(arrays.values())).shape[1]
    short = [n for n, a in kept.items() if a.shape[0] < 2]
    if n_units < 2 or short:
        why = (f"{n_units} unit(s) to leave out" if n_units < 2
               else f"no finite draw of {', '.join(short)}")
        notes.append(f"PSIS-LOO cannot weigh the members: {why}")
        return SetWeights(dict(equal), "equal", EQUAL_RULE, equal, notes=notes,
                          diagnostics={n: {"n_units": n_units, "dropped_draws": dropped[n]}
                                       for n in names})

    loo = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # arviz's Pareto-k warnings: reported below instead
        for n, a in kept.items():
            idata = az.from_dict(posterior={"_": np.zeros((1, a.shape[0]))},
                                 log_likelihood={"y": a[None]})
            loo[n] = az.loo(idata, pointwise=True, reff=1.0)
        table = az.compare(loo, method="BB-pseudo-BMA", b_samples=b_samples,
                           seed=np.random.default_rng(seed))
        stacked = az.compare(loo, method="stacking")
    weights = {n: float(table.loc[n, "weight"]) for n in names}
    total = sum(weights.values())
    weights = {n: w / total for n, w in weights.items()}
    diagnostics = {}
    for n in names:
        e = loo[n]
        k = np.asarray(e.pareto_k, dtype=float)
        good = float(e.good_k)
        bad = int(np.sum(k > good))
        diagnostics[n] = {
            "elpd_loo": float(e.elpd_loo), "se": float(e.se), "p_loo": float(e.p_loo),
            "elpd_diff": float(table.loc[n, "elpd_diff"]), "dse": float(table.loc[n, "dse"]),
            "pareto_k_max": float(np.max(k)), "good_k": good, "n_bad_k": bad,
            "psis_reliable": bad == 0, "n_units": n_units, "n_draws": int(kept[n].shape[0]),
            "dropped_draws": dropped[n],
        }
        if inflation is not None and n in inflation:
            diagnostics[n]["inflation"] = list(inflation[n])
        if bad:
            notes.append(f"{n}: PSIS unreliable on {bad} of {n_units} units (Pareto k up to "
                         f"{np.max(k):.2f} > {good:.2f}); its elpd_loo is approximate")
    unit_text = (f"{n_units} units, one observation each" if units is None
                 else f"{n_units} units of summed observations")
    return SetWeights(weights, "pseudo-BMA+", PSEUDO_BMA_RULE.format(units=unit_text), equal,
                      stacking={n: float(stacked.loc[n, "weight"]) for n in names},
                      pseudo_bma=dict(weights), diagnostics=diagnostics, notes=notes)


def weigh_set(members, rows=None, seed=0) -> SetWeights:
    """The calibrated members' weights, as ``tvcid discover`` makes them.

    :func:`align_pointwise`, then :func:`member_weights` (pseudo-BMA+ on PSIS-LOO). Where that
    cannot weigh the members -- fewer than two units, or PSIS unreliable on any unit of any
    member (Pareto k above arviz's threshold: leaving that unit out moves the posterior beyond
    what importance sampling can follow, and its elpd is not an estimate) -- the weights are
    the held-out scores' (:func:`.ranking_shares.ranking_shares` over the calibrated members'
    ``rows``): those
    come from refits on held-out halves, an exact cross-validation, and need no importance
    sampling. Without ``rows``, equal weights. The pseudo-BMA+ and stacking weights stay in the
    result as alternatives, and ``notes`` say which rule was used and why.

    Parameters
    ----------
    members : dict
        Member name (its structure) -> :class:`MemberPointwise` (:func:`member_pointwise`).
    rows : list of dict, optional
        The members' rows of ``discovery.json``'s ``structures`` (``structure``, ``score``,
        ``margin``).
    seed : int

    Returns
    -------
    SetWeights
    """
    aligned = align_pointwise(members)
    w = member_weights(aligned.pointwise, seed=seed, notes=aligned.notes,
                       inflation={n: m.inflation for n, m in members.items()})
    if w.method == "pseudo-BMA+":
        blocks = ", ".join(f"{rec}: {n} samples" for rec, n in aligned.block.items())
        w.rule = PSEUDO_BMA_RULE.format(units=f"{len(aligned.units)} units: each closed-loop "
                                        "feature" + (f", blocks of open-loop samples ({blocks})"
                                                     if blocks else ""))
    if w.method == "single member" or (w.method == "pseudo-BMA+" and w.psis_reliable):
        return w
    why = ("PSIS-LOO is unreliable" if w.method == "pseudo-BMA+"
           else "PSIS-LOO cannot weigh the members")
    names = list(members)
    shares = ranking_shares([r for r in rows or () if r["structure"] in members], seed=seed)
    total = sum(shares.values())
    if total > 0:
        w.weights = {n: shares.get(n, 0.0) / total for n in names}
        w.method, w.rule = "held-out scores", RANKING_RULE
        w.notes.append(f"weights by the held-out scores, since {why}")
    else:
        w.weights, w.method, w.rule = dict(w.equal), "equal", EQUAL_RULE
        w.notes.append(f"equal weights, since {why} and no held-out score is given")
    return w
