"""tvcid: discover and calibrate the nonlinear model of a thrust-vector-control electro-hydraulic
actuator from the limit cycle it shows in closed loop.

The public API, for scripts and notebooks (the ``tvcid`` command line runs the same functions)::

    import tvcid

    result = tvcid.discover(["cycle_A.csv", "square.csv"], "out")   # -> DiscoveryResult
    print(result.best["structure"], result.indistinguishable)
    print(result.interval("delay"))          # the 90 % interval over the set the data leave open
    truth = tvcid.hypothesis("M000")
    trajectory = tvcid.simulate(truth, tvcid.CONTROLLER_A, 20.0)

Names are imported on first use, so that ``import tvcid`` (and ``tvcid --help``) stays fast.
"""
from __future__ import annotations

import importlib

#: Public name -> the module that defines it.
_EXPORTS = {
    # the end-to-end pipeline and its result
    "discover": "tvcid.pipeline",
    "DiscoveryResult": "tvcid.result",
    "add_recordings": "tvcid.pipeline",
    # models: hypotheses, experiments, simulation, recordings
    "hypothesis": "tvcid.models.hypotheses",
    "HYPOTHESES": "tvcid.models.hypotheses",
    "ActuatorParams": "tvcid.models.hypotheses",
    "Structure": "tvcid.models.structures",
    "ClosedLoop": "tvcid.models.experiments",
    "OpenLoop": "tvcid.models.experiments",
    "CONTROLLER_A": "tvcid.models.experiments",
    "CONTROLLER_B": "tvcid.models.experiments",
    "simulate": "tvcid.models.simulate",
    "limit_cycle_features": "tvcid.models.cycle_reading",
    "load_recording": "tvcid.models.recording",
    "load_recordings": "tvcid.models.recording",
    "save_recording": "tvcid.models.recording",
    "synthetic_recording": "tvcid.models.synthetic",
    "Acquisition": "tvcid.models.synthetic",
    # discovery: the estimators
    "StructureDiscovery": "tvcid.discovery.structure",
    "Calibration": "tvcid.discovery.calibration",
    "predict_limit_cycles": "tvcid.discovery.describing",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'tvcid' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(list(globals()) + __all__)
