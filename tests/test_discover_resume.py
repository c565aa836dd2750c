"""tvcid discover stopped during the set's calibration: the rerun resumes every member's chain.

The ranking is a stand-in (two members of an open band-pass saturation, as a fresh search hands
them over: infinity in memory, ``null`` once read back from ``discovery.json``), so that the test
is about the chains, not the search.
"""
import json
import math
from pathlib import Path

import emcee
import numpy as np
import pytest

from tvcid.discovery.calibration.backend import CheckpointBackend
from tvcid.discovery.structure.ranking import StructureFit
from tvcid.discovery.structure.targets import make_target
from tvcid.models import CONTROLLER_A, hypothesis, simulate
from tvcid.models.recording import recording_from_trajectory, save_recording
from tvcid.models.structures import Structure
from tvcid.cli import main

#: M000 without its band-pass loop: no saturation either (``bandpass_saturation`` open).
TRUTH = hypothesis("M000", bandpass_gain=0.0, bandpass_saturation=math.inf, noise_seed=1,
                   noise_power=4e-13)
#: Everything but the dead zone, the delay and the delay's position known: two sampled
#: parameters (16 walkers), a chain step of a fraction of a second.
FIXED = {"dead_zone_position": "velocity", "friction_offset": TRUTH.friction_offset,
         "backlash": TRUTH.backlash, "bandpass_gain": 0.0, "gain": TRUTH.gain,
         "damping": TRUTH.damping, "stiffness": TRUTH.stiffness,
         "feedback_gain": TRUTH.feedback_gain}
STEPS, STOP_AT = 6, 3


class _Ranking:
    """Stands in for :class:`tvcid.discovery.structure.StructureDiscovery`: the truth at two delay
    positions, both in the set, the truth's first."""

    def __init__(self, **options):
        pass

    def fit(self, recordings, previous=None, previous_race=None):
        self.targets_ = [make_target(r, 5e-4) for r in recordings]
        fits = []
        for i, position in enumerate(("before_first_integrator", "before_integrator")):
            params = TRUTH.replace(delay_position=position)
            fits.append(StructureFit(
                Structure.of_params(params), params, np.zeros(2), 1.0 + i, {"rec": 1.0 + i},
                "stand-in", score=1.0 + 0.1 * i, criterion="stand-in score", margin=0.5,
                indistinguishable_from_best=True, held_out={"rec": 1.0 + 0.1 * i},
                fold_costs=np.array([[1.0 + 0.1 * i], [1.0 + 0.1 * i]])))
        self.ranking_ = self.indistinguishable_ = fits
        self.decided_ = {"dead_zone_position": "velocity", "delay_position": None,
                         "friction": True, "backlash": True, "bandpass": False}
        self.pruned_, self.sindy_, self.searches_, self.race_ = {}, {}, {}, None
        self.offsets_ = {"rec": 0.0}
        self.noise_ = {"rec": 2e-5}
        self.n_simulations_ = 1
        self.timings_ = self.cpu_seconds_ = {"total": 0.0}
        self.simulated_seconds_ = {"global": 0.0, "nested": 0.0, "ranking": 0.0}
        self.simulated_steps_ = {"global": 0.0, "nested": 0.0, "ranking": 0.0}
        return self


@pytest.fixture
def recording(tmp_path):
    """A 14 s limit cycle of :data:`TRUTH` under controller A, as a measured recording."""
    columns, meta = recording_from_trajectory(simulate(TRUTH, CONTROLLER_A, 14.0, rate=1000.0))
    meta = {k: meta[k] for k in ("kind", "kp", "kd", "mu")}
    return str(save_recording(tmp_path / "rec.csv", {k: columns[k] for k in ("t", "u", "delta")},
                              meta))


def _saved_steps(monkeypatch, stop_in=None):
    """Record every checkpointed step as ``(chain file, iteration)``; with ``stop_in`` (a
    number of chains), stop the run as Ctrl-C does once chain ``stop_in`` holds
    :data:`STOP_AT` steps (after that step's checkpoint)."""
    saved = []
    save_step = CheckpointBackend.save_step

    def recording_save_step(self, state, accepted):
        save_step(self, state, accepted)
        name = Path(self.filename).name
        saved.append((name, self.iteration))
        chains = list(dict.fromkeys(n for n, _ in saved))
        if stop_in is not None and len(chains) == stop_in and self.iteration == STOP_AT:
            raise KeyboardInterrupt(f"interrupted after step {self.iteration}")

    monkeypatch.setattr(CheckpointBackend, "save_step", recording_save_step)
    return saved


def _chain(path):
    return emcee.backends.HDFBackend(str(path), read_only=True, name="mcmc").get_chain()


def test_a_run_stopped_in_its_second_members_chain_resumes_both_where_they_stopped(
        tmp_path, recording, monkeypatch, capsys):
    """Stopped (Ctrl-C: status 130) after step 3 of the second member's chain, the same command
    again reuses the ranking, adds no step to the first member's finished chain, and continues
    the second one from step 4 on the steps already saved: two chain files, as many as
    members."""
    import tvcid.discovery.structure
    import tvcid.pipeline

    out = tmp_path / "out"
    args = ["discover", recording, *[a for k, v in FIXED.items() for a in ("--fix", f"{k}={v}")],
            "--quick", "--seed", "1", "--max-steps", str(STEPS), "--no-progress", "--out", str(out)]
    with monkeypatch.context() as m:
        m.setattr(tvcid.discovery.structure, "StructureDiscovery", _Ranking)
        m.setattr(tvcid.pipeline, "next_test", lambda *a: None)  # the next test is not at issue
        first = _saved_steps(m, stop_in=2)
        assert main(args) == 130
    assert "interrupted" in capsys.readouterr().err
    chains = list(dict.fromkeys(n for n, _ in first))
    assert len(chains) == 2 and first[-1] == (chains[1], STOP_AT)
    assert [i for n, i in first if n == chains[0]] == list(range(1, STEPS + 1))
    done, stopped = _chain(out / chains[0]), _chain(out / chains[1])
    assert len(stopped) == STOP_AT

    ranking = json.loads((out / "discovery.json").read_text())
    assert ranking["structures"][0]["params"]["bandpass_saturation"] is None
    with monkeypatch.context() as m:
        again = _saved_steps(m)
        assert main(args) == 0
    resumed = json.loads((out / "discovery.json").read_text())
    assert resumed["resumed_ranking"]
    # the first member's chain is read, not resampled; the second continues where it stopped
    assert again == [(chains[1], i) for i in range(STOP_AT + 1, STEPS + 1)], again
    assert sorted(p.name for p in out.glob("chain-*.h5")) == sorted(chains)
    assert [m["posterior"]["chain"] for m in resumed["set_posterior"]["members"]] == chains
    assert np.array_equal(_chain(out / chains[0]), done)
    continued = _chain(out / chains[1])
    assert len(continued) == STEPS and np.array_equal(continued[:STOP_AT], stopped)


def test_a_member_whose_chain_cannot_start_is_left_out_and_named(tmp_path, recording,
                                                                   monkeypatch):
    """The second member's calibration finds no starting point with a finite posterior (a
    set-coverage draw's member whose runs do not sustain the recorded cycle): the run goes on,
    the set's posterior is the first member's, and the report names the member left out."""
    from tvcid.discovery.calibration.start import NoFiniteStartError
    from tvcid.discovery.members import member_calibration

    import tvcid.discovery.structure
    import tvcid.pipeline

    monkeypatch.setattr(tvcid.discovery.structure, "StructureDiscovery", _Ranking)
    monkeypatch.setattr(tvcid.pipeline, "next_test", lambda *a: None)
    calibrate = member_calibration.calibrate_member

    def second_fails(params, structure, *args, **kwargs):
        if structure.delay_position.value == "before_integrator":
            raise NoFiniteStartError("could not place the walkers where the posterior is finite")
        return calibrate(params, structure, *args, **kwargs)

    monkeypatch.setattr(member_calibration, "calibrate_member", second_fails)
    out = tmp_path / "run"
    fixes = [a for k, v in FIXED.items() for a in ("--fix", f"{k}={v}")]
    assert main(["discover", recording, *fixes, "--quick", "--seed", "1", "--max-steps",
                 str(STEPS), "--no-progress", "--out", str(out)]) == 0
    summary = json.loads((out / "discovery.json").read_text())
    sp = summary["set_posterior"]
    assert [m["structure"] for m in sp["members"]] == [Structure.of_params(TRUTH).name]
    assert [f["structure"] for f in sp["failed"]] == [
        Structure.of_params(TRUTH.replace(delay_position="before_integrator")).name]
    report = (out / "report.md").read_text().split("## Recordings")[0]
    assert "Could not be calibrated, and left out of the combined posterior: `dz_velocity+" in report
