"""Structure discovery by closed- and open-loop simulation.

Stages, one module each:

* :mod:`.targets` -- what a simulation is compared with, per recording (limit-cycle features,
  output error with the sensor offset profiled out);
* :mod:`.coordinates` -- the search box of a structure, in coordinates that follow what the data
  determine;
* :mod:`.search` -- one structure's batch objective, global search, least-squares refinement,
  local spread;
* :mod:`.structure_search` -- every structure of :func:`tvcid.models.structures.structure_space`
  searched and refined in-sample (search sizes, staged searches, nested fits, seeds, repairs);
* :mod:`.tasks` -- the classes' global searches as self-contained tasks of an executor (this
  process, or a Dask cluster);
* :mod:`.ranking` -- the two-fold out-of-sample ranking of the fits (:class:`StructureFit`);
* :mod:`.indistinguishable` -- the set rule: the structures the recordings cannot tell from the
  best, and the merges;
* :mod:`.estimator` -- :class:`StructureDiscovery`, which runs them in turn, and
  :func:`validate_recordings`.

The set's members are calibrated, weighted and mixed in :mod:`tvcid.discovery.members`; which
further test would tell them apart, and whether they would answer a user's questions alike, is
in :mod:`tvcid.discovery.prediction` (``discrimination``, ``closure``).
"""
from .coordinates import SearchSpace, UnknownParameterError
from .estimator import DiscoveryInputError, StructureDiscovery, validate_recordings
from .ranking import StructureFit

__all__ = [
    "DiscoveryInputError",
    "SearchSpace",
    "StructureDiscovery",
    "StructureFit",
    "UnknownParameterError",
    "validate_recordings",
]
