"""What ``tvcid discover`` knows about its run, typed: :class:`RunRecord`, the content of
``discovery.json``, and :class:`RunCost`, what each stage cost.

The stages of :mod:`tvcid.pipeline` and :mod:`tvcid.set_stage` read and fill the record's fields;
``discovery.json`` is its :meth:`RunRecord.to_dict`, read back by :meth:`RunRecord.from_dict`:
its keys are the record's fields, with the cost's ledgers under ``timings``, ``cpu_seconds``,
``simulated_seconds`` and ``simulated_steps``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

__all__ = ["DISCOVERY_FORMAT", "RunCost", "RunRecord"]

#: Layout of ``discovery.json``; ``--add`` refuses a directory written in another one.
DISCOVERY_FORMAT = 2

#: The JSON key of each of :class:`RunCost`'s ledgers.
_COST_KEYS = {"wall": "timings", "cpu": "cpu_seconds", "simulated_seconds": "simulated_seconds",
              "simulated_steps": "simulated_steps"}
#: The structure search's stages, which the ledgers' ``discovery`` entry sums; added up in its
#: place by a ``discovery.json`` whose simulated ledgers have no such entry (``refit``: an
#: ``--add``'s search, every structure refitted from its earlier optimum).
_SEARCH_STAGES = ("sindy", "global", "nested", "refit", "ranking")
#: The stages after the search: the set's calibration and the next test.
_AFTER_SEARCH = ("mcmc", "next_test")


@dataclass
class RunCost:
    """What each stage of a run cost, one ledger per measure, each keyed by stage.

    Attributes
    ----------
    wall : dict of str to float
        Wall seconds (``timings`` in ``discovery.json``).
    cpu : dict of str to float
        Process CPU seconds, a worker's included (``cpu_seconds``).
    simulated_seconds : dict of str to float
        Nominal simulated seconds.
    simulated_steps : dict of str to float
        Kernel steps.
    """

    wall: dict = field(default_factory=dict)
    cpu: dict = field(default_factory=dict)
    simulated_seconds: dict = field(default_factory=dict)
    simulated_steps: dict = field(default_factory=dict)

    def add(self, stage, *, wall=None, cpu=None, simulated_seconds=None, simulated_steps=None):
        """Set ``stage``'s entry in every ledger given a value."""
        for name, value in (("wall", wall), ("cpu", cpu), ("simulated_seconds", simulated_seconds),
                            ("simulated_steps", simulated_steps)):
            if value is not None:
                getattr(self, name)[stage] = float(value)

    def totals(self) -> dict:
        """The whole run's ``wall_seconds``, ``cpu_seconds``, ``simulated_seconds`` and
        ``kernel_steps``: the search (its ``discovery`` entry, else the sum of its stages) plus
        the set's calibration and the next test; parts of a stage (``mcmc_start``,
        ``global_open_loop_stage``) are not counted twice."""
        out = {}
        for name, key in (("wall", "wall_seconds"), ("cpu", "cpu_seconds"),
                          ("simulated_seconds", "simulated_seconds"),
                          ("simulated_steps", "kernel_steps")):
            ledger = getattr(self, name)
            search = ledger.get("discovery", sum(ledger.get(k, 0.0) for k in _SEARCH_STAGES))
            out[key] = float(search + sum(ledger.get(k, 0.0) for k in _AFTER_SEARCH))
        return out

    def to_dict(self) -> dict:
        """The ledgers under their ``discovery.json`` keys."""
        return {key: dict(getattr(self, name)) for name, key in _COST_KEYS.items()}

    @classmethod
    def from_dict(cls, d) -> "RunCost":
        """The ledgers from ``discovery.json``'s keys (a missing one empty)."""
        return cls(**{name: dict(d.get(key) or {}) for name, key in _COST_KEYS.items()})


@dataclass
class RunRecord:
    """A discovery run: the ranking, the set it leaves open, the set's posterior, the next test
    and what every stage cost; ``discovery.json`` is :meth:`to_dict`.

    Attributes
    ----------
    structures : list of dict
        The ranking, best first: each structure's row
        (:meth:`tvcid.discovery.structure.StructureFit.to_dict`: ``structure``, ``score``,
        ``params``, ``indistinguishable_from_best``, ``merged_into``, ...).
    recordings : list of str
        The recordings' paths.
    targets : list
        What each recording is fitted as.
    fixed : dict
        The known parameters and structural choices (``--fix``).
    indistinguishable : list of str
        The structures the recordings cannot tell from the winner.
    decided : dict
        Each structural choice: its value where the set agrees on it, else ``None``.
    pruned, race, sindy, simulations, searches : object
        The search's own records (what it pruned, its race, SINDy's seeds, its counts).
    sensor_offset, sensor_noise : dict of str to float
        Per recording, rad.
    estimated : dict of str to str
        How the offsets and the noise were estimated.
    cost : RunCost
        Each stage's wall and CPU seconds, simulated seconds and kernel steps.
    seed : int
        Seed of every random draw.
    search : str
        The search sizes.
    inputs : str or None
        Hash of what determines the ranking (:func:`tvcid.pipeline.inputs_hash`).
    resumed_ranking : bool
        The ranking was read from an earlier run's ``discovery.json``.
    added, earlier_set : list of str or None
        ``--add``: the recordings added, and the set before they were.
    set_screening, posterior, set_posterior : dict or None
        The set stage's screening round, the first calibrated member's posterior and the set's
        (:func:`tvcid.set_stage.calibrate_set`).
    next_test : dict or None
        The test that would split the set (:func:`tvcid.pipeline.next_test`); ``None`` for a set
        of one.
    next_test_named : bool
        The next-test stage has run (``next_test`` is its answer).
    """

    structures: list
    recordings: list = field(default_factory=list)
    targets: list = field(default_factory=list)
    fixed: dict = field(default_factory=dict)
    indistinguishable: list = field(default_factory=list)
    decided: dict = field(default_factory=dict)
    pruned: object = None
    race: object = None
    sindy: object = None
    sensor_offset: dict = field(default_factory=dict)
    sensor_noise: dict = field(default_factory=dict)
    estimated: dict = field(default_factory=dict)
    simulations: object = None
    searches: dict = field(default_factory=dict)
    cost: RunCost = field(default_factory=RunCost)
    seed: int = 0
    search: str = "standard"
    inputs: str | None = None
    resumed_ranking: bool = False
    added: list | None = None
    earlier_set: list | None = None
    set_screening: dict | None = None
    posterior: dict | None = None
    set_posterior: dict | None = None
    next_test: dict | None = None
    next_test_named: bool = False
    format: int = DISCOVERY_FORMAT

    def set_rows(self) -> list:
        """The rows of the set's distinct members (in the set, not merged into another), best
        score first."""
        return [s for s in self.structures
                if s["indistinguishable_from_best"] and s["merged_into"] is None]

    def member_weights(self) -> dict:
        """Each calibrated member's weight in the set's posterior (empty before the set stage)."""
        members = (self.set_posterior or {}).get("members") or ()
        return {m["structure"]: m["weight"] for m in members}

    def to_dict(self) -> dict:
        """``discovery.json``'s content: every field under its name, the cost's ledgers under
        theirs; the set stage's and the next test's keys only once they have run."""
        d = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "cost":
                d.update(value.to_dict())
            elif f.name == "next_test_named":
                continue
            elif f.name == "next_test":
                if self.next_test_named:
                    d["next_test"] = value
            elif f.name in _WRITTEN_ONCE_SET and value is None:
                continue
            else:
                d[f.name] = value
        return d

    @classmethod
    def from_dict(cls, d) -> "RunRecord":
        """A record from ``discovery.json``'s content.

        Raises
        ------
        ValueError
            Not a dict, no ``structures``, or a key this version does not write (named).
        """
        if not isinstance(d, dict) or "structures" not in d:
            raise ValueError("not a discovery.json (no 'structures')")
        own = {f.name for f in fields(cls)} - {"cost", "next_test_named"}
        unknown = sorted(set(d) - own - set(_COST_KEYS.values()))
        if unknown:
            raise ValueError(f"not a discovery.json of this version (unknown key "
                             f"{', '.join(map(repr, unknown))})")
        return cls(**{k: v for k, v in d.items() if k in own}, cost=RunCost.from_dict(d),
                   next_test_named="next_test" in d)


#: Fields written only once set (a ranking alone has none of them).
_WRITTEN_ONCE_SET = frozenset({"added", "earlier_set", "set_screening", "posterior",
                               "set_posterior"})
