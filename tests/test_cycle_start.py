"""The closed-loop target's start: a model with coexisting cycles must be able to show the record's.

The initial conditions select the limit cycle (docs/models.md#m000). Recordings drawn by the
benchmark's generator (:func:`tvcid.studies.benchmarks.scenarios.draw_scenario`) start from the
hypotheses' kick (``tvcid.models.hypotheses.KICK_X0``), the target's simulations from the recorded cycle's
state; on these draws one start alone settles the TRUE model on a cycle the record does not show
(costs 2001 and 124 at the truth with ``y = x'``, 133841 with the threshold-consistent start alone),
which no search can repair.
"""
import numpy as np
import pytest

from tvcid.discovery.structure.search import Objective
from tvcid.discovery.structure.targets import SECOND_START_COST, make_target
from tvcid.models.recording import Recording
from tvcid.models.simulate import simulate
from tvcid.studies.benchmarks.scenarios import draw_scenario


def _noise_free_record(seed, index):
    """Recording ``index`` of draw ``seed``, simulated (kernel, fine step) without noise."""
    scenario = draw_scenario(seed)
    rd = scenario.recordings[index]
    tr = simulate(scenario.truth, rd.experiment(), rd.duration + 10.0, dt=1e-4, rate=rd.rate)
    keep = tr.t >= 10.0 - 1e-9
    meta = {"kind": "closed", "kp": rd.kp, "kd": rd.kd, "mu": rd.mu,
            "controller_rate": rd.controller_rate}
    rec = Recording(columns={"t": tr.t[keep] - tr.t[keep][0], "u": tr.u[keep],
                             "delta": tr.delta[keep]}, meta=meta)
    return scenario.truth, rec


@pytest.mark.parametrize("seed, index", [(1005, 0), (1041, 2), (1002, 1)])
def test_the_truth_reaches_its_recorded_cycle(seed, index):
    truth, rec = _noise_free_record(seed, index)
    target = make_target(rec, 5e-4)
    cost = Objective([target]).costs([truth])[0, 0]
    # units are the floors (0.1 % of the frequency, 0.3 % of H1): a wrong cycle costs hundreds
    assert cost < SECOND_START_COST


def test_the_start_carries_the_threshold_of_the_velocity_dead_zone():
    truth, rec = _noise_free_record(1005, 0)
    target = make_target(rec, 5e-4)
    plain = target.initial_conditions()["y0"]
    consistent = target.initial_conditions(truth)["y0"]
    assert consistent - plain == pytest.approx(np.sign(plain) * (truth.dead_zone - truth.friction_offset))
