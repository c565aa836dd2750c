"""Structure discovery by closed- and open-loop simulation (issue 11).

Stages, one module each:

* :mod:`.targets` -- what a simulation is compared with, per recording (limit-cycle features,
  output error with the sensor offset profiled out);
* :mod:`.coordinates` -- the search box of a structure, in coordinates that follow what the data
  determine;
* :mod:`.search` -- the batch objective, global search, least-squares refinement, local spread;
* :mod:`.discover` -- :class:`StructureDiscovery`, every structure of
  :func:`models.structures.structure_space` fitted and ranked out of sample.
"""
from .coordinates import SearchSpace, UnknownParameterError
from .discover import DiscoveryInputError, StructureDiscovery, StructureFit, validate_recordings
from .targets import NoCycleError

__all__ = [
    "DiscoveryInputError",
    "NoCycleError",
    "SearchSpace",
    "StructureDiscovery",
    "StructureFit",
    "UnknownParameterError",
    "validate_recordings",
]
