"""One seeded generator of random truths and experiment designs, shared by benchmarks and tests.

Used by :mod:`tvcid.studies.benchmarks.discovery`, :mod:`tvcid.studies.benchmarks.coverage` and the tests. Two
sets of ranges (:data:`RANGES`); ``wide``, the default, is what a user's actuator and rig may be,
``papers`` stays near the papers' rig:

* structure: uniform over :func:`tvcid.models.structures.structure_space` (36 kept structures);
* linear block: paper 001's ``K1 = 305500``, ``K2 = 202.1``, ``K3 = 14520`` each times U(0.7, 1.3);
  ``K = 1.0697`` times U(0.85, 1.15) (paper 000's block, ``A B``, ``B``, ``C A B``, lies within
  0.1 % of paper 001's, so this spans both papers' blocks and the ones between);
* dead zone: on the error log-uniform around paper 002's 1.2e-3 rad, on the velocity signal around
  paper 001's 0.0083 rad/s; backlash around 1.1625e-4 rad; each over a decade (``wide``: a factor
  sqrt(10) either side) or a factor 2.5 either side (``papers``); delay log-uniform in [0.8, 8] ms
  (``wide``) or [1, 8] ms; friction offset ``-U(0.3, 0.9) z``; band-pass loop gain log-uniform in
  [30, 100], saturation log-uniform in [0.008, 0.02];
* design: limit cycles at 1-3 controller settings (A, B, or Kp U(4, 12), Kd U(0.04, 0.08),
  mu U(4, 14)), 20-40 s each; 0-2 open-loop tests of 5-30 mrad at 0.3-3 Hz, 8-12 s: squares or
  sines, and (``wide``) staircases of random levels held for U(0.5, 1.5) half-periods;
  acquisition at 200, 500, 1000 or 2000 Hz (``wide``) or 200 or 1000 Hz; controller held at
  200 Hz or continuous; sensor noise 1e-5 to 1e-4 rad; offset 0 or U(-3e-4, 3e-4) rad;
  quantisation 0 or 5e-6 to 3e-5 rad;
* ``short``: ``wide`` with every record 5-15 s long (short recordings at the rig).

Truths are redrawn until they oscillate at every closed-loop setting of the design. The recordings
are made by the plain-Python reference path (:func:`tvcid.models.reference.simulate_reference`, a second
implementation) and written with measured-style sidecars: no hypothesis, no parameters, commands
only as samples.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tvcid.models import ClosedLoop, OpenLoop, SimulationDiverged, simulate
from tvcid.models.cycle_reading import InsufficientPeriodsError, NoCycleError
from tvcid.models.cycle_settling import stationary_tail
from tvcid.models.hypotheses import KICK_X0, ActuatorParams
from tvcid.models.recording import save_recording
from tvcid.models.reference import simulate_reference
from tvcid.models.strict_json import dumps, write_json
from tvcid.models.structures import Structure, structure_space
from tvcid.models.synthetic import Acquisition

__all__ = ["RecordingDesign", "Acquisition", "Scenario", "Ranges", "RANGES", "draw_truth", "draw_design",
           "draw_scenario", "oscillates", "write_recordings", "write_recording", "ridge_scenario",
           "RIDGE_PARAMETERS", "provenance", "design_of", "record_added_test"]

CONTROLLERS = ((5.84, 0.062, 12.3), (9.8, 0.06, 4.5))
#: Step (s) of the kernel run that decides whether a drawn truth oscillates.
ACCEPT_DT = 2e-4
#: Step (s) of the reference path that makes the data (the fits use 5e-4). At 2e-4 the data
#: would carry RK4's own error near square edges and switching events (a drawn truth's 1 kHz
#: square: rms 1.35e-5, up to 8.7e-5 rad against 2.6e-5 of noise), which the discrepancy term
#: reads as a misfit of the true model (factor 12.8 at the truth; 1.17 with data at 5e-5;
#: ``tests/test_scenarios.py::test_the_data_step_keeps_the_solver_error_under_the_smallest_noise``).
DATA_DT = 5e-5
#: Seconds at the end of a 30 s run over which a truth's cycle must be settled
#: (:func:`tvcid.models.cycle_settling.stationary_tail`).
MIN_SETTLED = 8.0


@dataclass(frozen=True)
class RecordingDesign:
    """One recording: ``kind`` closed (kp, kd, mu, controller_rate) or open (waveform, amplitude
    rad, frequency Hz); ``duration`` s; ``rate`` Hz of acquisition."""

    kind: str
    duration: float
    rate: float
    kp: float = 0.0
    kd: float = 0.0
    mu: float = 0.0
    controller_rate: float | None = None
    waveform: str = ""
    amplitude: float = 0.0
    frequency: float = 0.0
    #: a ``piecewise`` command's edge times (s) and its levels (rad) before, between and after them
    edges: tuple = ()
    levels: tuple = ()

    def experiment(self):
        if self.kind == "closed":
            return ClosedLoop(self.kp, self.kd, self.mu, sample_rate=self.controller_rate)
        if self.waveform == "piecewise":
            return OpenLoop.piecewise(np.asarray(self.edges), np.asarray(self.levels))
        return getattr(OpenLoop, self.waveform)(self.amplitude, self.frequency)


@dataclass(frozen=True)
class Scenario:
    truth: ActuatorParams
    structure: Structure
    recordings: tuple
    acquisition: Acquisition
    seed: int
    ranges: str = "wide"

    def to_dict(self) -> dict:
        recordings = [{k: v for k, v in r.__dict__.items() if k not in ("edges", "levels") or v}
                      for r in self.recordings]
        return {"truth": self.truth.to_dict(), "structure": self.structure.name,
                "recordings": recordings, "acquisition": self.acquisition.__dict__,
                "seed": self.seed, "ranges": self.ranges}


#: Centres of the thresholds' ranges (rad; rad/s for a dead zone on the velocity signal).
DEAD_ZONE_CENTRE = {"error": 1.2e-3, "velocity": 0.0083}
BACKLASH_CENTRE = 1.1625e-4


@dataclass(frozen=True)
class Ranges:
    """What the generator draws from (the coverage benchmark builds its priors on it).

    Parameters
    ----------
    threshold_factor : float
        Dead zone and backlash log-uniform within this factor either side of their centres.
    delay : tuple of float
        Log-uniform range of the delay (s).
    rates : tuple of float
        Acquisition rates (Hz), one drawn per design.
    waveforms : tuple of str
        Open-loop commands: ``square``, ``sine``, ``piecewise`` (a staircase of random levels).
    closed_seconds, open_seconds : tuple of float
        Uniform range of a limit cycle's and of an open-loop test's recorded length (s).
    """

    threshold_factor: float
    delay: tuple
    rates: tuple
    waveforms: tuple
    closed_seconds: tuple = (20.0, 40.0)
    open_seconds: tuple = (8.0, 12.0)


#: ``wide``: thresholds and delays over a decade, 200 Hz to 2 kHz, staircases among the commands
#: (a user's actuator and rig); ``short``: ``wide`` with every record 5-15 s long;
#: ``papers``: within a factor 2.5 of the papers' thresholds.
RANGES = {
    "wide": Ranges(math.sqrt(10.0), (0.8e-3, 8e-3), (200.0, 500.0, 1000.0, 2000.0),
                   ("square", "sine", "piecewise")),
    "short": Ranges(math.sqrt(10.0), (0.8e-3, 8e-3), (200.0, 500.0, 1000.0, 2000.0),
                    ("square", "sine", "piecewise"), (5.0, 15.0), (5.0, 15.0)),
    "papers": Ranges(2.5, (1e-3, 8e-3), (200.0, 1000.0), ("square", "sine")),
}


def ranges_named(name) -> Ranges:
    """:data:`RANGES`' entry ``name``, or a one-line error naming the choices."""
    try:
        return RANGES[name]
    except KeyError:
        raise ValueError(f"unknown ranges {name!r}; choose one of {', '.join(RANGES)}") from None


def _log_uniform(rng, centre, factor):
    return float(centre * math.exp(rng.uniform(-math.log(factor), math.log(factor))))


def draw_truth(rng, structure=None, ranges="wide") -> ActuatorParams:
    """A random truth of ``structure`` (drawn uniformly over the kept space when ``None``) within
    :data:`RANGES` ``[ranges]``."""
    r = ranges_named(ranges)
    if structure is None:
        kept, _ = structure_space()
        structure = kept[int(rng.integers(len(kept)))]
    z = _log_uniform(rng, DEAD_ZONE_CENTRE[structure.dead_zone_position.value], r.threshold_factor)
    values = dict(
        gain=305500.0 * rng.uniform(0.7, 1.3), damping=202.1 * rng.uniform(0.7, 1.3),
        stiffness=14520.0 * rng.uniform(0.7, 1.3), feedback_gain=1.0697 * rng.uniform(0.85, 1.15),
        dead_zone=z, backlash=_log_uniform(rng, BACKLASH_CENTRE, r.threshold_factor),
        delay=float(math.exp(rng.uniform(*np.log(r.delay)))),
        friction_offset=-rng.uniform(0.3, 0.9) * z,
        bandpass_gain=float(math.exp(rng.uniform(math.log(30.0), math.log(100.0)))),
        bandpass_saturation=float(math.exp(rng.uniform(math.log(0.008), math.log(0.02)))),
        x0=KICK_X0, y0=0.0, yd0=0.0,
    )
    for comp, fields in (("friction", ("friction_offset",)), ("backlash", ("backlash",)),
                         ("bandpass", ("bandpass_gain", "bandpass_saturation"))):
        if not getattr(structure, comp):
            for f in fields:
                values.pop(f)
    return structure.to_params(**values)


def oscillates(params, experiment) -> bool:
    """A settled limit cycle of plausible size and frequency over the last 10 s of a 30 s run.

    Settled as discovery reads a record: its stationary tail (the periods whose peak-to-peak stays
    within 15 % of the last ones') covers at least ``MIN_SETTLED`` s.
    """
    try:
        tr = simulate(params, experiment, 30.0, dt=ACCEPT_DT)
        f = tr.features(window=10.0)
        tail_t, _, _ = stationary_tail(tr.t, tr.delta)
    except (SimulationDiverged, InsufficientPeriodsError, NoCycleError, ValueError):
        return False
    # a settled cycle, not an irregular oscillation whose amplitude changes from period to period
    return (f.n_periods >= 4 and 3e-4 <= f.amplitude <= 0.05 and 2.0 <= f.frequency <= 40.0
            and abs(f.amplitude_drift) < 0.05 and tail_t[-1] - tail_t[0] >= MIN_SETTLED)


def _staircase(rng, duration, amplitude, frequency):
    """Edge times and levels of a staircase: levels U(-amplitude, amplitude), each held for
    U(0.5, 1.5) half-periods of ``frequency``, over ``duration`` s."""
    edges, t = [], 0.0
    while True:
        t += float(rng.uniform(0.5, 1.5)) / (2.0 * frequency)
        if t >= duration:
            break
        edges.append(t)
    return tuple(edges), tuple(float(rng.uniform(-amplitude, amplitude)) for _ in range(len(edges) + 1))


def draw_design(rng, ranges="wide"):
    """``(recordings, acquisition)`` of a random experiment design within :data:`RANGES`
    ``[ranges]``."""
    r = ranges_named(ranges)
    rate = float(rng.choice(list(r.rates)))
    ctrl_rate = 200.0 if rng.uniform() < 0.5 else None
    pool = list(CONTROLLERS) + [(rng.uniform(4, 12), rng.uniform(0.04, 0.08), rng.uniform(4, 14))]
    n_closed = int(rng.integers(1, 4))
    picks = rng.permutation(len(pool))[:n_closed]
    recs = [RecordingDesign("closed", float(rng.uniform(*r.closed_seconds)), rate, *map(float, pool[i]),
                            controller_rate=ctrl_rate) for i in picks]
    for _ in range(int(rng.integers(0, 3))):
        duration = float(rng.uniform(*r.open_seconds))
        waveform = str(rng.choice(list(r.waveforms)))
        amplitude = float(rng.uniform(5e-3, 30e-3))
        frequency = float(math.exp(rng.uniform(math.log(0.3), math.log(3.0))))
        edges, levels = (_staircase(rng, duration, amplitude, frequency)
                         if waveform == "piecewise" else ((), ()))
        recs.append(RecordingDesign("open", duration, rate, waveform=waveform, amplitude=amplitude,
                                    frequency=frequency, edges=edges, levels=levels))
    acq = Acquisition(
        noise_sd=float(math.exp(rng.uniform(math.log(1e-5), math.log(1e-4)))),
        offset=0.0 if rng.uniform() < 0.3 else float(rng.uniform(-3e-4, 3e-4)),
        quantisation=0.0 if rng.uniform() < 0.5 else float(math.exp(rng.uniform(math.log(5e-6), math.log(3e-5)))),
    )
    return tuple(recs), acq


def draw_scenario(seed, structure=None, max_tries=200, ranges="wide") -> Scenario:
    """Design, then a truth redrawn until it oscillates at every closed-loop setting, within
    :data:`RANGES` ``[ranges]``."""
    rng = np.random.default_rng(seed)
    recs, acq = draw_design(rng, ranges)
    closed = [r.experiment() for r in recs if r.kind == "closed"]
    for _ in range(max_tries):
        truth = draw_truth(rng, structure, ranges)
        if all(oscillates(truth, e) for e in closed):
            return Scenario(truth, Structure.of_params(truth), recs, acq, int(seed), ranges)
    raise RuntimeError(f"scenario {seed}: no truth of {structure or 'any structure'} oscillated "
                       f"at every controller setting in {max_tries} draws")


#: What the ridge case samples: the thresholds, the delay and the friction offset.
RIDGE_PARAMETERS = ("dead_zone", "backlash", "delay", "friction_offset")


def ridge_scenario(seed, duration=40.0, noise_sd=1e-4, ranges="wide") -> Scenario:
    """The calibration benchmark's ridge case with a drawn truth: paper 001's placement without the
    band-pass loop (dead zone on the velocity signal, friction offset, backlash, delay before the
    integrator), the thresholds, delay, friction offset and linear block drawn as :func:`draw_truth`
    does within ``ranges``; limit cycles at controllers A and B, ``duration`` s each at 1 kHz,
    white sensor noise."""
    from tvcid.models import M001f

    structure = Structure.of_params(M001f().replace(bandpass_gain=0.0))
    rng = np.random.default_rng(seed)
    recs = tuple(RecordingDesign("closed", float(duration), 1000.0, *c) for c in CONTROLLERS)
    for _ in range(200):
        truth = draw_truth(rng, structure, ranges)
        if all(oscillates(truth, r.experiment()) for r in recs):
            return Scenario(truth, structure, recs, Acquisition(float(noise_sd), 0.0, 0.0), int(seed),
                            ranges)
    raise RuntimeError(f"ridge scenario {seed}: no truth oscillated at A and B in 200 draws")


def write_recordings(scenario: Scenario, directory, dt=None, reuse=False) -> list:
    """Make the data with the reference path (step ``dt``, default :data:`DATA_DT`) and write
    measured-style recordings; CSV paths.

    ``reuse``: keep the recordings already in ``directory`` when its ``truth/scenario.json`` holds
    the same scenario made at the same step (benchmarks rerun on the same draws; the reference
    path at 5e-5 s costs about 1-3 s per simulated second), and, of a directory left unfinished,
    each recording whose ``truth/recNN.json`` (written once the recording is) holds it. Delete the
    directory after changing the reference path itself.
    """
    directory = Path(directory)
    (directory / "truth").mkdir(parents=True, exist_ok=True)
    dt = dt or DATA_DT
    stored_provenance = provenance(scenario, dt)
    names = [directory / f"rec{i:02d}_{rd.kind}.csv" for i, rd in enumerate(scenario.recordings)]
    stored = directory / "truth" / "scenario.json"

    def made(path, record):
        return (reuse and record.exists() and path.exists() and path.with_suffix(".json").exists()
                and json.loads(record.read_text()) == stored_provenance)

    if made(names[0], stored) and all(p.exists() and p.with_suffix(".json").exists() for p in names):
        return names
    for i, path in enumerate(names):
        record = directory / "truth" / f"rec{i:02d}.json"
        if not made(path, record):
            write_recording(scenario, i, path, dt)
            write_json(record, stored_provenance)
    write_json(stored, stored_provenance)
    return names


def provenance(scenario: Scenario, dt=None) -> dict:
    """What ``truth/scenario.json`` holds for ``scenario`` made at step ``dt`` (default
    :data:`DATA_DT`), as a JSON reader gets it back: strict JSON, so a non-finite parameter (the
    saturation ``inf`` of a structure without the band-pass loop) reads as ``None``."""
    return json.loads(dumps({**scenario.to_dict(), "data_dt": dt or DATA_DT}, default=str))


def write_recording(scenario: Scenario, index, path, dt=None):
    """Recording ``index`` of ``scenario`` made by the reference path (step ``dt``, default
    :data:`DATA_DT`), measured by the scenario's sensor (noise drawn from
    ``default_rng([seed, index])``) and written with a measured-style sidecar to ``path``."""
    rd = scenario.recordings[index]
    lead = 10.0 if rd.kind == "closed" else 0.0
    tr = simulate_reference(scenario.truth, rd.experiment(), rd.duration + lead, dt=dt or DATA_DT,
                            rate=rd.rate)
    keep = tr.t >= lead - 1e-9
    t = tr.t[keep] - tr.t[keep][0]
    rng = np.random.default_rng([scenario.seed, index])
    delta = scenario.acquisition.measure(tr.delta[keep], rng)
    meta = {"kind": rd.kind, "source": "simulated",
            "generator": "studies/benchmarks/scenarios.py (reference path)"}
    if rd.kind == "closed":
        meta.update(kp=rd.kp, kd=rd.kd, mu=rd.mu, controller_rate=rd.controller_rate)
    save_recording(path, {"t": t, "u": tr.u[keep], "delta": delta}, meta)
    return Path(path)


def design_of(candidate, rate) -> RecordingDesign:
    """A test of the next-test menu (:class:`tvcid.discovery.prediction.discrimination.CandidateTest`) as
    a recording of the generator's designs, acquired at ``rate`` (Hz)."""
    exp = candidate.experiment
    if candidate.kind == "closed":
        return RecordingDesign("closed", candidate.duration, rate, exp.kp, exp.kd, exp.mu,
                               controller_rate=exp.sample_rate)
    return RecordingDesign("open", candidate.duration, rate, waveform=exp.waveform,
                           amplitude=exp.amplitude, frequency=exp.frequency)


def record_added_test(scenario: Scenario, design: RecordingDesign, directory):
    """``scenario`` with ``design`` added, and the added test recorded from its truth by the
    reference path (:func:`write_recording`) into ``directory`` as ``recNN_KIND.csv``; returns
    ``(extended scenario, path)``. The recording is kept, not made again, when
    ``directory/truth/recNN.json`` holds the same extended scenario (the reference path costs
    about 10 s per simulated second)."""
    extended = replace(scenario, recordings=scenario.recordings + (design,))
    index = len(extended.recordings) - 1
    directory = Path(directory)
    (directory / "truth").mkdir(parents=True, exist_ok=True)
    path = directory / f"rec{index:02d}_{design.kind}.csv"
    stored = directory / "truth" / f"rec{index:02d}.json"
    made = provenance(extended)
    if not (stored.exists() and json.loads(stored.read_text()) == made and path.exists()
            and path.with_suffix(".json").exists()):
        write_recording(extended, index, path)
        write_json(stored, made)
    return extended, path


def shortened(scenario: Scenario, closed=None, open_=None) -> Scenario:
    """The scenario with shorter recordings (tests: the reference path costs ~0.3 s per s)."""
    recs = tuple(replace(r, duration=(closed if r.kind == "closed" else open_) or r.duration)
                 for r in scenario.recordings)
    return replace(scenario, recordings=recs)
