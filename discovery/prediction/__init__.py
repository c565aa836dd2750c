"""tvcid.discovery.prediction: what a calibrated actuator does under other controllers.

* :func:`load_posterior_draws` -- posterior draws back from ``tvcid fit``/``discover`` output;
* :func:`predict_cycle`, :func:`cycle_map` -- the limit cycle at one controller setting or over a
  grid, median and 90 % band over the draws, beside the describing function of the median model;
* :func:`rank_experiments` -- which test to run next, by the expected information gain;
* :mod:`.discrimination` -- which further test would tell the set's structures apart;
* :mod:`.closure` -- whether the set's calibrated members would answer a user's questions alike.
"""
from .cycles import (
    CycleMap,
    CycleOutcomes,
    CyclePrediction,
    PredictionConfig,
    cycle_map,
    predict_cycle,
    simulate_cycles,
)
from .draws import NoPosteriorError, PosteriorDraws, load_posterior_draws, load_set_draws
from .settings import GRID_KEYS, ControllerSetting, parse_grid

__all__ = [
    "ControllerSetting",
    "CycleMap",
    "CycleOutcomes",
    "CyclePrediction",
    "GRID_KEYS",
    "NoPosteriorError",
    "PosteriorDraws",
    "PredictionConfig",
    "cycle_map",
    "load_posterior_draws",
    "load_set_draws",
    "parse_grid",
    "predict_cycle",
    "simulate_cycles",
]
