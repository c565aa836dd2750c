"""tvcid.models: the actuator hypotheses of the papers as fast closed- and open-loop simulators.

This package never fits anything; :mod:`tvcid.discovery` does.
"""
from .controllers import BendingMode, TransferFunction
from .experiments import CONTROLLER_A, CONTROLLER_B, ClosedLoop, OpenLoop
from .cycle_reading import InsufficientPeriodsError, LimitCycleFeatures, limit_cycle_features
from .hypotheses import (
    HYPOTHESES,
    M000,
    M002,
    ActuatorParams,
    DeadZonePosition,
    DelayPosition,
    M001f,
    M001i,
    UnknownHypothesisError,
    hypothesis,
    params_from_dict,
)
from .simulate import (
    DEFAULT_DT,
    BatchResult,
    SimulationDiverged,
    Trajectory,
    simulate,
    simulate_batch,
)

__all__ = [
    "ActuatorParams",
    "BatchResult",
    "BendingMode",
    "CONTROLLER_A",
    "CONTROLLER_B",
    "ClosedLoop",
    "DEFAULT_DT",
    "DeadZonePosition",
    "DelayPosition",
    "HYPOTHESES",
    "InsufficientPeriodsError",
    "LimitCycleFeatures",
    "M000",
    "M001f",
    "M001i",
    "M002",
    "OpenLoop",
    "SimulationDiverged",
    "Trajectory",
    "TransferFunction",
    "UnknownHypothesisError",
    "hypothesis",
    "limit_cycle_features",
    "params_from_dict",
    "simulate",
    "simulate_batch",
]
