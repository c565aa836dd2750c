"""The studies ``tvcid study`` knows, in the order ``tvcid study all`` runs them.

Each study module exposes ``NAME``, a frozen ``Config``, ``QUICK`` and
``run(config, seed, out_dir) -> dict``; ``LONG_RUNNING = True`` makes ``tvcid study all --jobs N``
start it first.
"""
from __future__ import annotations

from . import (
    bundled_discovery,
    h1_deadzone_backlash,
    h2_friction_bandpass,
    h3_initial_conditions,
    h4_delay_position,
    h5_noise,
    h6_controller_design,
    reference_cycles,
)

STUDIES = {module.NAME: module for module in (reference_cycles, h1_deadzone_backlash, h2_friction_bandpass, h3_initial_conditions, h4_delay_position, h5_noise, bundled_discovery,
                                          h6_controller_design)}
