"""The end-to-end discovery behind ``tvcid discover``: structure and parameters from the user's
own recordings, then MCMC.

Screening (SINDy seeds), fitting every structure by closed- and open-loop simulation, ranking by
two-fold out-of-sample error (:class:`discovery.structure.StructureDiscovery`), then the MCMC
calibration of every member of the set the recordings leave open, on all recordings
(:class:`discovery.calibration.Calibration`), combined by the members' weights; where
the recordings leave several structures, the test that would tell them apart (:func:`next_test`).
Nothing is lost to a killed run: ``discovery.json`` is written as soon as the ranking is done and
carries a hash of the inputs, so a rerun with the same recordings and options reuses it instead of
searching again, and the chain is checkpointed, so the MCMC resumes where it stopped.
:func:`discover` returns a :class:`DiscoveryResult` and writes ``discovery.json`` and
``report.md`` with the figures beside them (docs/methods/discovery.md). With ``dask``, the
classes' global searches (:mod:`discovery.structure.tasks`) and the members' calibrations
(:mod:`tvcid.members`) run on a Dask cluster, with the same result (docs/cluster.md).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from discovery.speed import cpu_seconds
from models.strict_json import jsonable, write_json

__all__ = ["DiscoveryResult", "add_recordings", "discover", "next_test", "inputs_hash"]

#: Layout of ``discovery.json``; ``--add`` refuses a directory written in another one.
DISCOVERY_FORMAT = 2
#: Distinct members of the set calibrated at most (best score first); the rest are listed in
#: ``set_posterior.not_calibrated`` with their share of the weight by the ranking.
MAX_MEMBERS = 6
#: Steps of every member's chain before the members are weighed and those under the deciding
#: share are screened (:func:`_calibrate`).
SCREEN_STEPS = 300


def _json_default(v):
    """Enums as their value, anything else as its text."""
    if hasattr(v, "value"):
        return v.value
    return str(v)


@dataclass
class DiscoveryResult:
    """What :func:`discover` found: the content of ``discovery.json``, with its readers.

    Attributes
    ----------
    summary : dict
        The ranking (``structures``, best first), the set the recordings cannot tell apart
        (``indistinguishable``), the structural choices they decide (``decided``), the sensor
        offsets and noise, the next test, the posterior over the set (``set_posterior``: each
        calibrated member's and their combination) and the winner's alone (``posterior``).
    out : Path or None
        The directory it was written to.
    """

    summary: dict
    out: Path | None = None

    @classmethod
    def load(cls, path) -> "DiscoveryResult":
        """A result from its ``discovery.json`` (or the directory holding it)."""
        path = Path(path)
        if path.is_dir():
            path = path / "discovery.json"
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: not a discovery.json ({exc})") from None
        if not isinstance(summary, dict) or "structures" not in summary:
            raise ValueError(f"{path}: not a discovery.json (no 'structures')")
        return cls(summary, path.parent)

    @property
    def best(self) -> dict:
        """The winner's row: ``structure``, ``score``, ``params``, ``coordinate_sd``, ..."""
        return self.summary["structures"][0]

    @property
    def indistinguishable(self) -> list:
        """Names of the structures the recordings cannot tell from the winner (merged ones too)."""
        return list(self.summary["indistinguishable"])

    @property
    def decided(self) -> dict:
        """Each structural choice: its value where the set agrees on it, else ``None``."""
        return dict(self.summary["decided"])

    @property
    def posterior(self):
        """The MCMC summary of the winner alone (``parameters``: q05, q50, q95 each), or
        ``None``; the set's combined posterior is :attr:`set_posterior`."""
        return self.summary.get("posterior")

    @property
    def set_posterior(self):
        """The posterior over the set the recordings leave open, or ``None`` (no MCMC).

        ``quantities`` maps each combined quantity (``delay``, ``dead_zone[velocity]``,
        ``dc_gain``, ...) to its median and 90 % interval (``q50``, ``q05``, ``q95``), unit and
        verdicts; ``members`` holds each calibrated structure's own posterior.
        """
        return self.summary.get("set_posterior")

    def interval(self, name, level=0.90) -> tuple:
        """The combined 90 % interval ``(q05, q95)`` of quantity ``name`` over the set.

        Parameters
        ----------
        name : str
            A key of ``set_posterior["quantities"]``: ``"delay"``, ``"dead_zone[velocity]"``,
            ``"dc_gain"``, ...
        level : float
            The interval's probability; the summary stores the 90 % interval only.

        Returns
        -------
        tuple of float
            ``(q05, q95)``; NaN where the summary holds no finite value.

        Raises
        ------
        ValueError
            No set posterior (a run with ``mcmc=False``), an unknown quantity (the message names
            those there are), or a level other than 0.90.
        """
        if not math.isclose(level, 0.90):
            raise ValueError(f"interval level {level!r}: the summary stores the 90 % interval "
                             "(q05, q95) only")
        quantities = (self.set_posterior or {}).get("quantities")
        if not quantities:
            raise ValueError("no set posterior: the run stopped after the ranking (run discover "
                             "with its MCMC to calibrate the set)")
        if name in (self.set_posterior.get("left_open_uncalibrated") or ()):
            raise ValueError(f"{name}: the set leaves its component open and no member with it "
                             "could be calibrated, so no interval is printed")
        if name not in quantities:
            raise ValueError(f"unknown quantity {name!r}; the set's posterior has "
                             f"{', '.join(quantities)}")
        # a fresh run's summary holds non-finite values as such, one read back as None
        ends = (quantities[name][k] for k in ("q05", "q95"))
        return tuple(float(v) if v is not None and math.isfinite(v) else math.nan for v in ends)

    def to_dict(self) -> dict:
        """The summary as strict JSON values (non-finite numbers as ``None``)."""
        return jsonable(self.summary, _json_default)

    def report(self) -> str:
        """``report.md``'s text (:func:`tvcid.report.discovery_report`)."""
        from .report import discovery_report

        return discovery_report(self.to_dict())

    def save(self, out=None) -> Path:
        """Write ``discovery.json`` and ``report.md`` into ``out`` (default: where it came from)."""
        out = Path(out if out is not None else self.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "discovery.json", self.summary, default=_json_default)
        (out / "report.md").write_text(self.report())
        self.out = out
        return out

    def plot(self, ax=None):
        """The ranking: each structure's out-of-sample score, the set the recordings cannot tell
        apart in colour; returns the axes."""
        import matplotlib.pyplot as plt

        rows = self.summary["structures"][:20]
        if ax is None:
            ax = plt.subplots(figsize=(7, 0.3 * len(rows) + 1.2))[1]
        scores = [s["score"] if s["score"] is not None else np.nan for s in rows]
        colours = ["C0" if s["indistinguishable_from_best"] else "0.7" for s in rows]
        y = np.arange(len(rows))[::-1]
        ax.barh(y, scores, color=colours)
        ax.set_yticks(y, [s["structure"] for s in rows], fontsize=7)
        ax.set_xscale("log")
        ax.set_xlabel(f"score ({rows[0]['criterion']}); in colour: the set left open")
        return ax


def _corrected(recordings, offsets):
    """The recordings with their estimated sensor offset removed from ``delta``."""
    from models.recording import Recording

    out = []
    for r in recordings:
        name = r.path.stem if r.path else "recording"
        cols = dict(r.columns)
        cols["delta"] = r.delta - offsets.get(name, 0.0)
        out.append(Recording(columns=cols, meta=r.meta, path=r.path))
    return out


def discover(files, out, fixed=None, seed=0, quick=False, max_steps=None, mcmc=True,
             progress=True, search="standard", dask=None) -> DiscoveryResult:
    """Run the whole discovery on ``files`` into ``out``: ``tvcid discover``'s pipeline.

    Parameters
    ----------
    files : sequence of str or Path
        Recordings (``NAME.csv`` with its ``NAME.json`` sidecar; :doc:`docs/recordings.md`).
    out : str or Path
        Output directory: ``discovery.json``, ``report.md``, the chain and the figures.
    fixed : dict, optional
        Known parameters or structural choices (``{"gain": 305500, "delay_position": "output"}``).
    seed : int
        Seed of every random draw.
    quick : bool
        A short chain (150 steps).
    max_steps : int, optional
        MCMC step cap (default 2000, 150 with ``quick``).
    mcmc : bool
        Calibrate the set's members after the ranking.
    search : {"standard", "thorough", ...}
        Search sizes (:data:`discovery.structure.structure_search.SEARCHES`).
    dask : str, optional
        Run the global searches of the classes' largest structures and the members'
        calibrations on the Dask scheduler at this address (``tcp://HOST:8786``), or on a
        cluster of ``N`` one-thread worker processes on this machine (``local:N``); the same
        result as without it (docs/cluster.md: on a cluster, ``out`` must be on a file system
        the workers share, for the chains).

    Returns
    -------
    DiscoveryResult

    ``search`` names the search sizes (:data:`discovery.structure.structure_search.SEARCHES`);
    ``quick`` only shortens the chain.

    A finished ranking of the same inputs already in ``out`` is reused (``resumed_ranking``), and
    an interrupted chain resumes from its checkpoint.
    """
    from discovery.executors import check_dask_address, executor_from
    from discovery.structure import validate_recordings
    from discovery.threads import one_blas_thread

    if dask is not None:
        check_dask_address(dask)  # a bad address, or no Dask: one line before any work
    out = Path(out)
    recs = validate_recordings(files)
    out.mkdir(parents=True, exist_ok=True)
    # every stage: the kernels own the cores (discovery.threads; the workers' tasks limit their own)
    with executor_from(dask=dask) as executor, one_blas_thread():
        return _discover(recs, out, fixed, seed, quick, max_steps, mcmc, progress, search,
                         executor)


def _discover(recs, out, fixed, seed, quick, max_steps, mcmc, progress, search, executor):
    """:func:`discover` on validated recordings, the independent work through ``executor``."""
    from models.structures import shared_choices

    inputs = inputs_hash(recs, fixed, seed, search)
    previous = _previous_ranking(out, inputs)
    if previous is not None:
        summary = previous
        summary["resumed_ranking"] = True
        # the same data under the names given now (a run copied from elsewhere)
        summary["recordings"] = [str(r.path) for r in recs]
        offsets = summary["sensor_offset"]
        t_disc = summary["timings"].get("discovery", 0.0)
        summary.setdefault("decided", shared_choices(summary["indistinguishable"]))
    else:
        summary, offsets, t_disc = _rank_structures(
            recs, fixed, seed, search, progress, inputs, executor=executor)
        _write(out, summary)  # the ranking survives whatever happens to the chain
    if mcmc:  # a finished chain resumes at once; a larger --max-steps continues it
        summary = _calibrate(summary, recs, offsets, fixed, seed, quick, max_steps,
                             progress, out, executor)
        _write(out, summary)
    if "next_test" not in summary:  # after the weights: it splits the members that carry them
        t0, c0 = time.perf_counter(), cpu_seconds()
        spent = {"simulated_seconds": 0.0, "simulated_steps": 0.0}
        summary["next_test"] = next_test(summary, recs, seed, out, spent)
        summary["timings"]["next_test"] = time.perf_counter() - t0
        summary.setdefault("cpu_seconds", {})["next_test"] = cpu_seconds() - c0
        summary.setdefault("simulated_seconds", {})["next_test"] = spent["simulated_seconds"]
        summary.setdefault("simulated_steps", {})["next_test"] = spent["simulated_steps"]
    summary["timings"]["discovery"] = t_disc
    _write(out, summary)
    return DiscoveryResult(summary, out)


def _hash_samples(h, rec):
    """Feed a recording's columns (names and samples) to the hash ``h``."""
    for name in sorted(rec.columns):
        h.update(name.encode())
        h.update(np.ascontiguousarray(rec.columns[name], dtype=float).tobytes())


def _data_hash(rec) -> str:
    """Digest of a recording's samples: the same data under another file name match."""
    h = hashlib.sha256()
    _hash_samples(h, rec)
    return h.hexdigest()


def _earlier_run(out, fixed):
    """The earlier run's ``discovery.json`` in ``out``, checked for ``--add``."""
    path = out / "discovery.json"
    if not path.is_file():
        raise ValueError(f"--add: {out} holds no discovery.json (run tvcid discover --out {out} "
                         "first)")
    try:
        earlier = json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"--add: {path} is not valid JSON ({exc})") from None
    if not isinstance(earlier, dict) or earlier.get("format") != DISCOVERY_FORMAT:
        found = earlier.get("format") if isinstance(earlier, dict) else None
        raise ValueError(f"--add: {path} was written by another version of tvcid discover (layout "
                         f"{found!r}, this one adds to {DISCOVERY_FORMAT}); run the discovery again")
    given = {k: getattr(v, "value", v) for k, v in (fixed or {}).items()}
    if given and given != earlier["fixed"]:
        raise ValueError(f"--add: --fix {given} differs from the earlier run's fixed set-up "
                         f"{earlier['fixed'] or 'none'} (--add keeps the earlier set-up; leave "
                         "--fix out)")
    return earlier


def add_recordings(new_files, out, fixed=None, quick=False, max_steps=None, mcmc=True,
                   progress=True, dask=None) -> DiscoveryResult:
    """The experiment loop: add recordings to an earlier :func:`discover` run in ``out``.

    Every structure is refitted by least squares from its optimum of the earlier run on all the
    recordings (:meth:`discovery.structure.StructureDiscovery.fit` with ``previous``), then
    ranked; the set, its posterior and the next test are made again. The earlier run's fixed
    set-up, seed and search sizes are kept. Refused with one line, before anything is written:
    no earlier run in ``out``, one of another version, a different ``fixed``, or a recording
    already in the run. Rerun after an interruption, the same ``--add`` resumes. ``dask`` runs
    the members' calibrations as :func:`discover`'s does (the refits run in this process).
    """
    from discovery.executors import check_dask_address
    from discovery.structure import validate_recordings
    from models import params_from_dict

    if dask is not None:
        check_dask_address(dask)
    out = Path(out)
    earlier = _earlier_run(out, fixed)
    added = earlier.get("added") or []
    new = validate_recordings(new_files)
    new_paths = [str(r.path) for r in new]
    if added and new_paths == added[-len(new_paths):] and all(p in earlier["recordings"] for p in new_paths):
        # the same --add, interrupted after its ranking: resume it
        return discover(earlier["recordings"], out, fixed=earlier["fixed"], seed=earlier["seed"],
                        quick=quick, max_steps=max_steps, mcmc=mcmc, progress=progress,
                        search=earlier["search"], dask=dask)
    old = validate_recordings(earlier["recordings"])
    known = {Path(r.path).resolve(): r for r in old}
    hashes = {_data_hash(r): r for r in old}
    for r in new:
        twin = known.get(Path(r.path).resolve()) or hashes.get(_data_hash(r))
        if twin is not None:
            raise ValueError(f"--add: {r.path} is already in the run (as {twin.path})")
    recs = old + new
    fixed, seed, search = earlier["fixed"], earlier["seed"], earlier["search"]
    previous = {}
    for row in earlier["structures"]:
        if row.get("cost") is not None and math.isfinite(row["cost"]):
            previous[row["structure"]] = params_from_dict("custom", row["params"])
    inputs = inputs_hash(recs, fixed, seed, search)
    summary, offsets, t_disc = _rank_structures(recs, fixed, seed, search, progress,
                                                inputs, previous=previous)
    summary["added"] = added + new_paths
    summary["earlier_set"] = earlier["indistinguishable"]
    _write(out, summary)  # the ranking survives whatever happens to the chains
    return discover(summary["recordings"], out, fixed=fixed, seed=seed, quick=quick,
                    max_steps=max_steps, mcmc=mcmc, progress=progress, search=search, dask=dask)


def median_sensor_noise(summary) -> float:
    """The median of a discovery's per-recording sensor-noise estimates (rad); 1e-6 rad for
    noise-free recordings, where the code's own tolerance sets the units."""
    noises = [float(v) for v in summary["sensor_noise"].values()
              if isinstance(v, (int, float)) and math.isfinite(v) and v > 0]
    return float(np.median(noises)) if noises else 1e-6


def next_test(summary, recs, seed, out, spent=None):
    """The test that would tell apart the structures the recordings cannot
    (:func:`discovery.structure.discrimination.discriminating_tests` on the set's unmerged
    members at their fitted parameters, refitted to the recordings for the best
    candidates; the default menu acquired at the recordings' highest rate, the recordings'
    median noise); writes ``next_test.png``. A calibrated member whose weight is under
    :data:`discovery.structure.set_weights.DECIDING_SHARE` is left out (``left_out``: the data
    have decided against it); one beyond the calibration's cap stays. ``None`` for a set of one.
    A dict ``spent`` gets what it simulated, ``simulated_seconds`` and ``simulated_steps``."""
    from discovery.structure.discrimination import (
        default_candidates,
        discriminating_tests,
    )
    from discovery.structure.set_weights import DECIDING_SHARE
    from discovery.structure.targets import make_target
    from models import params_from_dict

    weight = {m["structure"]: m["weight"]
              for m in (summary.get("set_posterior") or {}).get("members") or ()}
    rows = [s for s in summary["structures"]
            if s["indistinguishable_from_best"] and s["merged_into"] is None]
    left_out = [{"structure": s["structure"], "weight": weight[s["structure"]]} for s in rows
                if weight.get(s.get("structure"), 1.0) < DECIDING_SHARE]
    members = [params_from_dict("custom", s["params"]) for s in rows
               if weight.get(s.get("structure"), 1.0) >= DECIDING_SHARE]
    spent = spent if spent is not None else {}
    spent.update(simulated_seconds=0.0, simulated_steps=0.0)
    if len(members) < 2:  # the weights leave one structure: nothing to split
        return ({"best": None, "tests": [], "left_out": left_out,
                 "members": [s["structure"] for s in rows if s["structure"] not in
                             {x["structure"] for x in left_out}]} if left_out else None)
    noise = median_sensor_noise(summary)
    rate = max(r.sample_rate for r in recs)
    recorded = [make_target(r, 5e-4) for r in recs]  # the targets ignore a constant offset
    ranking = discriminating_tests(members, default_candidates(rate), noise_sd=noise, seed=seed,
                                   recorded=recorded)
    spent.update(simulated_seconds=ranking.simulated_seconds,
                 simulated_steps=ranking.simulated_steps)
    from .figures import pyplot

    plt = pyplot()
    ax = ranking.plot()
    ax.figure.tight_layout()
    ax.figure.savefig(out / "next_test.png", dpi=90)
    plt.close(ax.figure)
    result = ranking.to_dict()
    result["tests"] = result["tests"][:8]  # the best few; the figure shows twelve
    result["left_out"] = left_out
    return result


def inputs_hash(recs, fixed, seed, search) -> str:
    """Hash of what determines the ranking: every recording's data and sidecar, the options."""
    h = hashlib.sha256()
    for r in recs:
        _hash_samples(h, r)
        h.update(json.dumps(r.meta, sort_keys=True, default=str).encode())
    h.update(json.dumps([{k: getattr(v, "value", v) for k, v in (fixed or {}).items()}, seed,
                         str(search)], sort_keys=True, default=str).encode())
    return h.hexdigest()


def _previous_ranking(out, inputs):
    """A finished ranking of the same inputs in ``out``, or ``None``."""
    path = out / "discovery.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if summary.get("inputs") != inputs or not summary.get("structures"):
        return None
    return summary


def _rank_structures(recs, fixed, seed, search, progress, inputs, previous=None, executor=None):
    from discovery.structure import StructureDiscovery

    t0 = time.perf_counter()
    disc = StructureDiscovery(fixed=fixed, seed=seed, search=search, progress=progress,
                              executor=executor).fit(recs, previous=previous)
    t_disc = time.perf_counter() - t0
    summary = {
        "format": DISCOVERY_FORMAT,
        "recordings": [str(r.path) for r in recs],
        "targets": [t.describe() for t in disc.targets_],
        "fixed": {k: (v if not hasattr(v, "value") else v.value) for k, v in (fixed or {}).items()},
        "structures": [f.to_dict() for f in disc.ranking_],
        "indistinguishable": [f.structure.name for f in disc.indistinguishable_],
        "decided": disc.decided_,
        "pruned": disc.pruned_,
        "sindy": disc.sindy_,
        "sensor_offset": disc.offsets_,
        "sensor_noise": disc.noise_,
        "estimated": {"sensor_offset": "per recording, profiled (least squares) at the best fit",
                      "sensor_noise": "open loop: rms output error at the best fit; closed loop: "
                                      "second differences"},
        "simulations": disc.n_simulations_,
        "searches": dict(disc.searches_),
        "timings": {**disc.timings_},
        "cpu_seconds": {**disc.cpu_seconds_, "discovery": disc.cpu_seconds_["total"]},
        "simulated_seconds": {**disc.simulated_seconds_},
        "simulated_steps": {**disc.simulated_steps_},
        "seed": seed,
        "search": search,
        "inputs": inputs,
        "resumed_ranking": False,
    }
    summary["timings"]["discovery"] = t_disc
    return summary, disc.offsets_, t_disc


def _calibrate_member(row, recs, offsets, fixed, seed, quick, max_steps, progress, out):
    """MCMC of one member of the set
    (:func:`discovery.structure.member_calibration.calibrate_member`) on all recordings with
    their offsets removed, checkpointed in ``out``. Returns ``(posterior, priors, simulated
    seconds of the start and of the sampling, chain file name)``.

    The chain's file is named by a hash of the member's parameters as strict JSON
    (:func:`models.strict_json.jsonable` of the rebuilt :class:`models.ActuatorParams`): the
    ranking of a fresh run holds an open saturation as infinity, the same ranking read back from
    ``discovery.json`` as ``null``, and both must name the same chain for a rerun to resume it.
    """
    from discovery.structure.member_calibration import calibrate_member
    from models import params_from_dict
    from models.structures import Structure

    p = params_from_dict("custom", row["params"])
    tag = hashlib.sha256(json.dumps([jsonable(p.to_dict()), "set member", quick, seed],
                                    sort_keys=True, allow_nan=False).encode()).hexdigest()[:10]
    post, priors, simulated = calibrate_member(
        p, Structure.parse(row["structure"]), _corrected(recs, offsets), fixed=fixed, seed=seed,
        max_steps=max_steps or (150 if quick else 2000), backend=out / f"chain-{tag}.h5",
        progress=progress)
    return post, priors, simulated, f"chain-{tag}.h5"


def _calibrate(summary, recs, offsets, fixed, seed, quick, max_steps, progress, out,
               executor=None):
    """The posterior over the set: every distinct member calibrated (:func:`_calibrate_member`,
    at most :data:`MAX_MEMBERS`, best score first), and the richer structure of each component
    the set leaves open that no distinct member has
    (:func:`discovery.structure.set_posterior.richer_members`).

    A set of several members is calibrated in two rounds. First every member's chain runs
    :data:`SCREEN_STEPS` steps and the members are weighed by their evidence
    (:func:`discovery.structure.set_weights.evidence_weights`); a member whose weight stays under
    :data:`discovery.structure.set_weights.DECIDING_SHARE` even at its estimate's allowance is
    *screened*: its chain stops there and its short chain gives its ranges (the report says so).
    Then the others' chains continue to the cap. The screening is stored in ``discovery.json``
    (``set_screening``), so a resumed run screens the same members. Each member's step error is
    measured (:func:`discovery.calibration.step_error.measure_step_error`) and its evidence
    estimated again from its final chain; the members are combined by those weights
    (:func:`discovery.structure.set_posterior.combine`), and the members beyond the cap named
    with their share of the weight by the ranking. A member whose chain cannot start (no point
    about its fit where every recording's likelihood is finite) is left out and named in
    ``set_posterior.failed``. Adds ``posterior`` (the first calibrated member's, the winner's
    where it calibrates) and ``set_posterior`` (the members', their weights and the combined
    one). Each member's own work is a task of ``executor``
    (:func:`tvcid.members.calibrate_member_task`; default: one after the other in this
    process), combined here in the members' order; each member's row of
    ``set_posterior.members`` gets what its tasks cost (``simulated_steps``,
    ``simulated_seconds``, ``cpu_seconds``, ``wall_seconds``), and the stage's cost goes to
    ``timings``, ``cpu_seconds``, ``simulated_seconds`` and ``simulated_steps`` (``mcmc``, of
    which ``mcmc_start`` in seconds and ``mcmc_evidence``)."""
    from discovery.executors import LocalProcesses
    from discovery.structure.ranking_shares import uncalibrated_share
    from discovery.structure.set_posterior import (
        MemberPosterior,
        combine,
        left_open_quantities,
        richer_members,
    )
    from discovery.structure.set_weights import DECIDING_SHARE, evidence_weights, weighed_choices

    from .members import calibrate_member_task

    t0, c0 = time.perf_counter(), cpu_seconds()
    rows = [s for s in summary["structures"]
            if s["indistinguishable_from_best"] and s["merged_into"] is None]
    best_score = rows[0]["score"]
    calibrated = rows[:MAX_MEMBERS] + richer_members(summary["structures"], summary["decided"])
    executor = executor if executor is not None else LocalProcesses(1)
    here = isinstance(executor, LocalProcesses) and executor.jobs == 1
    n = len(calibrated)
    cap = max_steps or (150 if quick else 2000)
    shared = (recs, offsets, fixed, seed, quick)
    show = progress and here  # a worker's bars would garble this terminal
    cost = {"simulated_seconds": 0.0, "simulated_steps": 0.0, "start": 0.0,
            "evidence_seconds": 0.0, "evidence_steps": 0.0, "elsewhere_cpu": 0.0,
            "cpu_at_start": c0}
    by_member = {}  # both rounds of each member's task

    def account(run):
        cost["simulated_seconds"] += run.simulated_seconds
        cost["simulated_steps"] += run.simulated_steps
        cost["start"] += run.start_seconds
        cost["evidence_seconds"] += run.evidence_seconds
        cost["evidence_steps"] += run.evidence_steps
        if run.pid != os.getpid():  # a worker's CPU: not on this process's clock
            cost["elsewhere_cpu"] += run.cpu_seconds
        own = by_member.setdefault(run.structure, dict.fromkeys(
            ("simulated_steps", "simulated_seconds", "cpu_seconds", "wall_seconds"), 0.0))
        for key in own:
            own[key] += getattr(run, key)

    screened, first_draws, first_failed = set(), {}, {}
    screen_steps = min(SCREEN_STEPS, cap)
    if n > 1 and screen_steps < cap:
        screening = summary.get("set_screening")
        names_now = [r["structure"] for r in calibrated]
        if not screening or screening.get("members") != names_now \
                or screening.get("steps") != screen_steps:
            runs = executor.map(calibrate_member_task, calibrated, *([x] * n for x in shared),
                                [screen_steps] * n, [show] * n, [out.resolve()] * n, [True] * n,
                                [True] * n)
            for row, run in zip(calibrated, runs):
                account(run)
                if run.failed is None:
                    first_draws[row["structure"]] = run.draws
                else:  # not started again below
                    first_failed[row["structure"]] = run.failed
            weighed = (evidence_weights(first_draws, rows=calibrated, seed=seed)
                       if len(first_draws) > 1 else None)
            screening = {"members": names_now, "steps": screen_steps,
                         "share": DECIDING_SHARE,
                         "weights": None if weighed is None else weighed.weights,
                         "upper": None if weighed is None else weighed.upper,
                         "screened": [] if weighed is None else weighed.screened()}
            summary["set_screening"] = screening
            _write(out, summary)  # a resumed run screens the same members
        screened = set(screening["screened"])
    todo = [r for r in calibrated if r["structure"] not in first_failed]
    m = len(todo)
    caps = [screen_steps if r["structure"] in screened else cap for r in todo]
    # a screened member's draws are the first round's where it ran here (its chain has not moved
    # since; on a resumed run they are drawn again, the same draws)
    weigh = [n > 1 and not (r["structure"] in screened and r["structure"] in first_draws)
             for r in todo]
    runs = executor.map(calibrate_member_task, todo, *([x] * m for x in shared), caps,
                        [show] * m, [out.resolve()] * m, weigh, [False] * m)
    members, draws = [], {}
    failed = [{"structure": name, "reason": why} for name, why in first_failed.items()]
    for row, run in zip(todo, runs):
        account(run)
        if run.failed is not None:
            # the rest of the set still has its posterior; the report names this member
            failed.append({"structure": row["structure"], "reason": run.failed})
            continue
        if not members:
            summary["posterior"] = run.kept
            from .figures import write_posterior_figures

            write_posterior_figures(run.posterior, out, seed=seed)
        margin = row.get("margin")
        ratio = (row["score"] - best_score) / margin if margin else 0.0
        kept = run.kept
        if row["structure"] in screened:
            kept = {**kept, "screened": {"steps": screen_steps, "share": DECIDING_SHARE,
                                         "upper_weight": summary["set_screening"]["upper"][
                                             row["structure"]]}}
        members.append(MemberPosterior(
            row["structure"], run.quantities, kept, float(ratio),
            log_prob=run.posterior.log_prob, prior_quantities=run.prior_quantities,
            step_error=run.step_error))
        d = run.draws if run.draws is not None else first_draws.get(row["structure"])
        if d is not None:
            draws[row["structure"]] = d
    names = [m.structure for m in members]
    if not members:
        summary["set_posterior"] = {"criterion": "no member calibrated", "quantities": {},
                                    "members": [], "failed": failed,
                                    "not_calibrated": [r["structure"] for r in rows[MAX_MEMBERS:]]}
        _record_cost(summary, t0, cost)
        return summary
    if len(members) > 1:
        weighting = evidence_weights({m: draws[m] for m in names},
                                     rows=[r for r in calibrated if r["structure"] in names],
                                     seed=seed)
        weights = weighting.weights
    else:
        weighting, weights = None, {names[0]: 1.0}
    choices = weighed_choices(summary["decided"], weights, summary["indistinguishable"])
    # a component whose other side only uncalibrated members hold prints "present or absent"
    left_open = left_open_quantities({c: None if v["by"] == "open" and None in v["weights"].values()
                                      else True for c, v in choices.items()})
    if weighting is not None:
        combined = combine(members, weights=weighting.of(names), seed=seed,
                           criterion=weighting.rule, left_open=left_open).to_dict()
        combined["weighting"] = weighting.to_dict()
    else:
        combined = combine(members, seed=seed, criterion="one structure",
                           left_open=left_open).to_dict()
    combined["choices"] = choices
    dropped = uncalibrated_share(rows + [r for r in calibrated if r not in rows], names, seed=seed)
    combined["not_calibrated"] = dropped.names
    combined["not_calibrated_share"] = dropped.share if dropped.names else None
    combined["failed"] = failed
    combined["screened"] = sorted(screened & set(names))
    for row in combined["members"]:  # what each member's own work cost, both rounds
        row.update(by_member[row["structure"]])
    summary["set_posterior"] = combined
    _record_cost(summary, t0, cost)
    return summary


def _record_cost(summary, t0, cost):
    """The set stage's wall time, CPU seconds (this process's, its ended children's and its
    workers'), simulated seconds and kernel steps into ``summary``."""
    summary["timings"]["mcmc"] = time.perf_counter() - t0
    summary.setdefault("cpu_seconds", {})["mcmc"] = (cpu_seconds() - cost["cpu_at_start"]
                                                     + cost["elsewhere_cpu"])
    summary.setdefault("simulated_seconds", {})["mcmc"] = cost["simulated_seconds"]
    summary["simulated_seconds"]["mcmc_start"] = cost["start"]  # of which the chains' starts
    # of which the importance draws of the members' evidence, for the weights
    summary["simulated_seconds"]["mcmc_evidence"] = cost["evidence_seconds"]
    summary.setdefault("simulated_steps", {})["mcmc"] = cost["simulated_steps"]
    summary["simulated_steps"]["mcmc_evidence"] = cost["evidence_steps"]


def _write(out, summary):
    DiscoveryResult(summary, out).save()
