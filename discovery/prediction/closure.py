"""Is the set closed? Whether the structures the recordings cannot tell apart would answer a
user's questions alike.

A set is *closed* when it holds one structure, or when its calibrated members agree on

* every test of the menu (:func:`.discrimination.default_candidates`): each member's posterior
  draws are simulated through the test as the discovery would see it (the target made from the
  first member's median model, residuals in noise units as in
  :mod:`.discrimination`). Two members agree on a test when the median squared distance between
  a draw of one and a draw of the other is no larger than the 90th percentile of the distances
  between two draws of the same member (their difference is inside their own spread), or below
  :data:`.discrimination.DECIDES` (no recording of the test could tell them apart);
* the limit cycle at controller settings the recordings did not use
  (:func:`tvcid.discovery.prediction.set_prediction.predict_cycle_over_set`: both oscillate or both not,
  and their medians of amplitude and frequency differ by no more than a difference of two
  measurements allows, each member's 90 % half-width and what a recording of the cycle resolves
  added in quadrature).

Then the choice between them does not matter to what a user would measure or design for; a set
that is not closed says at which test or setting the members part. Where the members carry
weights, a member under the deciding share
(:data:`tvcid.discovery.structure.indistinguishable.DECIDING_SHARE`) whose weight is final is not
counted: the data have decided against it, as the set's prediction and the next test leave it
out (it is still simulated, and the verdict counting every member is kept beside); a set whose
weight one member holds all but that share of is closed. A member whose weight is not final (its
chain stopped at its cap, or its evidence is unreliable:
:func:`tvcid.discovery.members.set_weights.unsure_members`) is counted whatever its weight.
"""
from __future__ import annotations

import dataclasses
import itertools
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .discrimination import DECIDES, _target_of

__all__ = ["SetClosure", "menu_agreement", "set_closure"]

#: Percentile of the within-member distances a cross-member distance is compared with.
WITHIN_PERCENTILE = 90.0


def _squared_distances(a, b):
    """Squared Euclidean distances between the rows of ``a`` and those of ``b``."""
    return np.maximum(np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None, :] - 2 * a @ b.T, 0.0)


def _within(r):
    d = _squared_distances(r, r)
    iu = np.triu_indices(len(r), 1)
    return float(np.percentile(d[iu], WITHIN_PERCENTILE)) if len(iu[0]) else 0.0


def menu_agreement(member_sets: dict, candidate, noise_sd, dt=5e-4, seed=0, reference=None) -> dict:
    """Whether the members agree on one test (the module's rule).

    ``member_sets``: structure name -> list of :class:`tvcid.models.ActuatorParams` (posterior draws);
    ``reference`` (default: the first member's first set) makes the target. Returns ``{"name",
    "agree", "pairs": [{"members", "cross", "within", "agree"}]}`` or, where the test cannot be
    simulated for that model, ``{"name", "skipped"}``."""
    names = list(member_sets)
    with tempfile.TemporaryDirectory() as tmp:
        target = _target_of(reference or member_sets[names[0]][0], candidate, noise_sd, dt, seed,
                            Path(tmp) / "test.csv")
    if isinstance(target, str):
        return {"name": candidate.name, "skipped": target}
    residuals = {}
    for n in names:
        sets = member_sets[n]
        if target.initial_conditions():
            sets = [p.replace(**target.initial_conditions(p)) for p in sets]
        r = np.asarray(target.residuals(sets), dtype=float)
        residuals[n] = r[np.all(np.isfinite(r), axis=1)]
    pairs = []
    for a, b in itertools.combinations(names, 2):
        ra, rb = residuals[a], residuals[b]
        if len(ra) < 2 or len(rb) < 2:  # most draws diverge or stop oscillating: they differ
            pairs.append({"members": [a, b], "cross": None, "within": None, "agree": False})
            continue
        cross = float(np.median(_squared_distances(ra, rb)))
        within = max(_within(ra), _within(rb))
        pairs.append({"members": [a, b], "cross": cross, "within": within,
                      "agree": bool(cross <= within or cross < DECIDES)})
    return {"name": candidate.name, "agree": all(p["agree"] for p in pairs), "pairs": pairs}


@dataclass
class SetClosure:
    """Whether a set is closed, test by test and setting by setting.

    Every calibrated member is simulated; the verdict counts the members the weights have not
    decided against, and :attr:`closed_counting_every_member` is the verdict had every member
    counted.

    Attributes
    ----------
    members : list of str
        Every member simulated.
    tests : list of dict
        :func:`menu_agreement` of every test of the menu.
    settings : list of dict
        Per controller setting: its values, ``members_agree`` and the ``disagreeing`` pairs.
    not_counted : list of str
        Members under the deciding share of the weight, left out of the verdict.
    """

    members: list
    tests: list = field(default_factory=list)
    settings: list = field(default_factory=list)
    not_counted: list = field(default_factory=list)

    @property
    def counted(self) -> list:
        """The members the verdict counts."""
        return [m for m in self.members if m not in self.not_counted]

    def _parting(self, counted) -> tuple:
        """The tests and the settings at which two of ``counted`` part."""
        def counts(pair):
            return all(m in counted for m in pair)

        tests = [t["name"] for t in self.tests
                 if ("pairs" in t and any(counts(p["members"]) and not p["agree"]
                                          for p in t["pairs"]))
                 or ("pairs" not in t and not t.get("agree", True))]
        settings = [s["setting"] for s in self.settings
                    if ("disagreeing" in s and any(counts(d["members"]) for d in s["disagreeing"]))
                    or ("disagreeing" not in s and not s["members_agree"])]
        return (tests, settings) if len(counted) > 1 else ([], [])

    @property
    def parting_tests(self) -> list:
        """Names of the menu's tests at which two counted members part."""
        return self._parting(self.counted)[0]

    @property
    def parting(self) -> list:
        """Names of the tests and settings at which two counted members part."""
        return sum(self._parting(self.counted), [])

    @property
    def closed(self) -> bool:
        return not self.parting

    @property
    def closed_counting_every_member(self) -> bool:
        return not sum(self._parting(self.members), [])

    def to_dict(self) -> dict:
        return {"closed": self.closed, "members": self.members, "counted": self.counted,
                "not_counted": self.not_counted, "parting": self.parting,
                "closed_counting_every_member": self.closed_counting_every_member,
                "tests": self.tests, "settings": self.settings}


def set_closure(member_draws: dict, candidates, settings, noise_sd, n_draws=24, dt=5e-4,
                seed=0, config=None, resolution=None, weights=None, unsure=()) -> SetClosure:
    """Whether the members of a set agree on every test of ``candidates`` and on the cycle at
    every controller setting of ``settings``.

    Parameters
    ----------
    member_draws : dict
        Structure name -> :class:`tvcid.discovery.prediction.draws.PosteriorDraws`
        (:func:`tvcid.discovery.prediction.draws.load_set_draws` of a discover directory).
    candidates : sequence of :class:`tvcid.discovery.prediction.design.Candidate`
        The menu (:func:`.discrimination.default_candidates`).
    settings : sequence of :class:`tvcid.discovery.prediction.settings.ControllerSetting`
    noise_sd : float
        Sensor noise sd (rad) of the simulated tests.
    dt : float
        Integration step (s) of the tests, halved until one step fits under the draws' shortest
        delay (:func:`.cycles.step_under_delays`).
    n_draws : int
        Posterior draws per member (the first ``n_draws`` of each, which
        :func:`~tvcid.discovery.prediction.draws.load_set_draws` already drew at random).
    resolution : dict, optional
        What a recording resolves of a cycle
        (:func:`tvcid.discovery.prediction.set_prediction.measurement_resolution`), by which the
        predicted cycles' bands are widened before they are compared.
    weights : dict, optional
        Structure name -> the member's weight in the set
        (:func:`tvcid.discovery.prediction.draws.load_set_weights`); a member the data decide
        against (under the deciding share, its weight final:
        :func:`tvcid.discovery.members.set_weights.decided_against`) is simulated but not
        counted in the verdict. ``None``: every member counts.
    unsure : iterable of str
        Members whose weight is not final
        (:func:`tvcid.discovery.prediction.draws.load_unsure_members`): counted whatever their
        weight.
    """
    from tvcid.discovery.members.set_weights import decided_against

    from .cycles import PredictionConfig, step_under_delays
    from .set_prediction import predict_cycle_over_set

    names = list(member_draws)
    not_counted = sorted(decided_against(
        None if weights is None else {n: weights.get(n, 1.0) for n in names}, unsure))
    if len(names) <= 1:
        return SetClosure(names, not_counted=not_counted)
    sets = {n: [d.params(i) for i in range(min(n_draws, len(d)))] for n, d in member_draws.items()}
    dt = step_under_delays(dataclasses.replace(PredictionConfig(), dt=dt),
                           [p for v in sets.values() for p in v]).dt
    reference = member_draws[names[0]].median_params()
    tests = [menu_agreement(sets, c, noise_sd, dt, seed, reference) for c in candidates]
    rows = []
    for s in settings:
        pred = predict_cycle_over_set(member_draws, s, config or PredictionConfig(),
                                      describing=False, resolution=resolution).to_dict()
        rows.append({"setting": f"Kp {s.kp:.3g}, Kd {s.kd:.3g}, mu {s.mu:.3g}",
                     "members_agree": pred["members_agree"], "disagreeing": pred["disagreeing"]})
    return SetClosure(names, tests, rows, not_counted)
