"""Describing functions and harmonic balance: the classic method of paper 002 (and paper 001 s. 2).

Modules, one concept each:

* :mod:`.analytic` -- closed-form describing functions (dead zone, play-operator backlash in both
  width conventions, saturation, relay, friction offset);
* :mod:`.elements` and :mod:`.numeric` -- the elements as callables on sampled signals and the
  numeric first-harmonic describing function of any element or chain, memory included;
* :mod:`.harmonic_balance` -- every zero of ``1 + L N`` in a rectangle, stability by Loeb's
  criterion; the single-nonlinearity (Lur'e) loop;
* :mod:`.actuator_loop` -- a hypothesis (:class:`tvcid.models.ActuatorParams`) and a controller as a
  first-harmonic loop with the exact delay ``exp(-jw Td)`` at any of its three positions, the
  friction offset and the band-pass loop (balanced at the fundamental only); the controller is
  any :class:`tvcid.models.ClosedLoop` (PD, compensator ``F(s)``, bending mode, a zero-order hold as
  its first harmonic);
* :mod:`.inverse` -- paper 002's family of (backlash, dead zone) pairs, printed and corrected, and
  the exact inverse harmonic balance;
* :mod:`.validation` -- a prediction beside the simulated cycle.

The approximation is honest about its limits: for M002 at controller A it predicts 8.88 rad/s
where the simulator gives 8.60 (:data:`.actuator_loop.DF_CAVEAT`), and the exact inverse has no
solution at 8.57 rad/s with a 7 ms output delay.
"""
from .actuator_loop import (
    BANDPASS_CAVEAT,
    COMPENSATOR_CAVEAT,
    DF_CAVEAT,
    ActuatorDescribingLoop,
    describe_controller,
    predict_limit_cycles,
    vehicle_controller_response,
)
from .analytic import (
    backlash_df,
    dead_zone_df,
    dead_zone_friction_df,
    friction_offset_df,
    inverse_dead_zone_df,
    relay_df,
    saturation_df,
)
from .elements import (
    Chain,
    DeadZone,
    FrictionOffset,
    Gain,
    PlayOperator,
    Relay,
    Saturation,
)
from .errors import (
    AmplitudeBelowDeadZoneError,
    DescribingFunctionError,
    NoHarmonicBalanceSolution,
    UnsupportedStructureError,
)
from .harmonic_balance import (
    HarmonicBalanceResult,
    LimitCycle,
    frequency_response,
    lure_limit_cycles,
    solve_harmonic_balance,
)
from .inverse import (
    FAMILY_BACKLASH_HALF_WIDTHS,
    BacklashDeadZoneFamily,
    BacklashDeadZonePair,
    paper002_family,
    solve_backlash_and_dead_zone,
)
from .numeric import describing_function, numeric_df
from .validation import SimulationComparison, compare_with_simulation

__all__ = [
    "ActuatorDescribingLoop",
    "AmplitudeBelowDeadZoneError",
    "BANDPASS_CAVEAT",
    "BacklashDeadZoneFamily",
    "BacklashDeadZonePair",
    "COMPENSATOR_CAVEAT",
    "Chain",
    "DF_CAVEAT",
    "DeadZone",
    "DescribingFunctionError",
    "FAMILY_BACKLASH_HALF_WIDTHS",
    "FrictionOffset",
    "Gain",
    "HarmonicBalanceResult",
    "LimitCycle",
    "NoHarmonicBalanceSolution",
    "PlayOperator",
    "Relay",
    "Saturation",
    "UnsupportedStructureError",
    "backlash_df",
    "dead_zone_df",
    "dead_zone_friction_df",
    "describe_controller",
    "describing_function",
    "frequency_response",
    "friction_offset_df",
    "inverse_dead_zone_df",
    "lure_limit_cycles",
    "numeric_df",
    "paper002_family",
    "predict_limit_cycles",
    "relay_df",
    "saturation_df",
    "SimulationComparison",
    "compare_with_simulation",
    "solve_backlash_and_dead_zone",
    "solve_harmonic_balance",
    "vehicle_controller_response",
]
