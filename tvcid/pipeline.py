"""The end-to-end discovery behind ``tvcid discover``: structure and parameters from the user's
own recordings, then MCMC.

Screening (SINDy seeds), fitting every structure by closed- and open-loop simulation, ranking by
two-fold out-of-sample error (:class:`tvcid.discovery.structure.StructureDiscovery`), then the MCMC
calibration of every member of the set the recordings leave open, on all recordings
(:class:`tvcid.discovery.calibration.Calibration`), combined by the members' weights; where
the recordings leave several structures, the test that would tell them apart (:func:`next_test`).
Nothing is lost to a killed run: ``discovery.json`` is written as soon as the ranking is done and
carries a hash of the inputs, so a rerun with the same recordings and options reuses it instead of
searching again, and the chain is checkpointed, so the MCMC resumes where it stopped.
:func:`discover` returns a :class:`DiscoveryResult` and writes ``discovery.json`` and
``report.md`` with the figures beside them (docs/methods/discovery.md). With ``dask``, the
classes' global searches (:mod:`tvcid.discovery.structure.tasks`) and the members' calibrations
(:mod:`tvcid.members`) run on a Dask cluster, with the same result (docs/cluster.md).
"""
from __future__ import annotations

import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np

from tvcid.discovery.speed import cpu_seconds

from .result import DiscoveryResult
from .run_record import DISCOVERY_FORMAT, RunCost, RunRecord
from .set_stage import calibrate_set

__all__ = ["DiscoveryResult", "add_recordings", "discover", "next_test", "inputs_hash"]


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
        Search sizes (:data:`tvcid.discovery.structure.structure_search.SEARCHES`).
    dask : str, optional
        Run the global searches of the classes' largest structures and the members'
        calibrations on the Dask scheduler at this address (``tcp://HOST:8786``), or on a
        cluster of ``N`` one-thread worker processes on this machine (``local:N``); the same
        result as without it (docs/cluster.md: on a cluster, ``out`` must be on a file system
        the workers share, for the chains).

    Returns
    -------
    DiscoveryResult

    ``search`` names the search sizes (:data:`tvcid.discovery.structure.structure_search.SEARCHES`);
    ``quick`` only shortens the chain.

    A finished ranking of the same inputs already in ``out`` is reused (``resumed_ranking``), and
    an interrupted chain resumes from its checkpoint.
    """
    from tvcid.discovery.executors import check_dask_address, executor_from
    from tvcid.discovery.structure import validate_recordings
    from tvcid.discovery.threads import one_blas_thread

    if dask is not None:
        check_dask_address(dask)  # a bad address, or no Dask: one line before any work
    out = Path(out)
    recs = validate_recordings(files)
    out.mkdir(parents=True, exist_ok=True)
    # every stage: the kernels own the cores (tvcid.discovery.threads; the workers' tasks limit their own)
    with executor_from(dask=dask) as executor, one_blas_thread():
        return _discover(recs, out, fixed, seed, quick, max_steps, mcmc, progress, search,
                         executor)


def _discover(recs, out, fixed, seed, quick, max_steps, mcmc, progress, search, executor):
    """:func:`discover` on validated recordings, the independent work through ``executor``."""
    from tvcid.models.structures import shared_choices

    inputs = inputs_hash(recs, fixed, seed, search)
    record = _previous_ranking(out, inputs)
    if record is not None:
        record.resumed_ranking = True
        # the same data under the names given now (a run copied from elsewhere)
        record.recordings = [str(r.path) for r in recs]
        record.decided = record.decided or shared_choices(record.indistinguishable)
    else:
        record = _rank_structures(recs, fixed, seed, search, progress, inputs,
                                  executor=executor)
        _write(out, record)  # the ranking survives whatever happens to the chain
    if mcmc:  # a finished chain resumes at once; a larger --max-steps continues it
        calibrate_set(record, recs, fixed, seed, quick, max_steps, progress, out, executor)
        _write(out, record)
    if not record.next_test_named:  # after the weights: it splits the members that carry them
        t0, c0 = time.perf_counter(), cpu_seconds()
        spent = {"simulated_seconds": 0.0, "simulated_steps": 0.0}
        record.next_test = next_test(record, recs, seed, out, spent)
        record.next_test_named = True
        record.cost.add("next_test", wall=time.perf_counter() - t0, cpu=cpu_seconds() - c0,
                        **spent)
    _write(out, record)
    return DiscoveryResult(record, out)


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
    found = earlier.get("format") if isinstance(earlier, dict) else None
    record = None
    if found == DISCOVERY_FORMAT:
        try:
            record = RunRecord.from_dict(earlier)
        except ValueError:
            pass  # a key this version does not write: refused as another layout
    if record is None:
        raise ValueError(f"--add: {path} was written by another version of tvcid discover (layout "
                         f"{found!r}, this one adds to {DISCOVERY_FORMAT}); run the discovery "
                         "again")
    earlier = record
    given = {k: getattr(v, "value", v) for k, v in (fixed or {}).items()}
    if given and given != earlier.fixed:
        raise ValueError(f"--add: --fix {given} differs from the earlier run's fixed set-up "
                         f"{earlier.fixed or 'none'} (--add keeps the earlier set-up; leave "
                         "--fix out)")
    return earlier


def add_recordings(new_files, out, fixed=None, quick=False, max_steps=None, mcmc=True,
                   progress=True, dask=None) -> DiscoveryResult:
    """The experiment loop: add recordings to an earlier :func:`discover` run in ``out``.

    Every structure is refitted by least squares from its optimum of the earlier run on all the
    recordings (:meth:`tvcid.discovery.structure.StructureDiscovery.fit` with ``previous``), then
    ranked; the set, its posterior and the next test are made again. The earlier run's fixed
    set-up, seed and search sizes are kept. Refused with one line, before anything is written:
    no earlier run in ``out``, one of another version, a different ``fixed``, or a recording
    already in the run. Rerun after an interruption, the same ``--add`` resumes. ``dask`` runs
    the members' calibrations as :func:`discover`'s does (the refits run in this process).
    """
    from tvcid.discovery.executors import check_dask_address
    from tvcid.discovery.structure import validate_recordings
    from tvcid.models import params_from_dict

    if dask is not None:
        check_dask_address(dask)
    out = Path(out)
    earlier = _earlier_run(out, fixed)
    added = earlier.added or []
    new = validate_recordings(new_files)
    new_paths = [str(r.path) for r in new]
    if added and new_paths == added[-len(new_paths):] \
            and all(p in earlier.recordings for p in new_paths):
        # the same --add, interrupted after its ranking: resume it
        return discover(earlier.recordings, out, fixed=earlier.fixed, seed=earlier.seed,
                        quick=quick, max_steps=max_steps, mcmc=mcmc, progress=progress,
                        search=earlier.search, dask=dask)
    old = validate_recordings(earlier.recordings)
    known = {Path(r.path).resolve(): r for r in old}
    hashes = {_data_hash(r): r for r in old}
    for r in new:
        twin = known.get(Path(r.path).resolve()) or hashes.get(_data_hash(r))
        if twin is not None:
            raise ValueError(f"--add: {r.path} is already in the run (as {twin.path})")
    recs = old + new
    fixed, seed, search = earlier.fixed, earlier.seed, earlier.search
    previous = {}
    for row in earlier.structures:
        if row.get("cost") is not None and math.isfinite(row["cost"]):
            previous[row["structure"]] = params_from_dict("custom", row["params"])
    inputs = inputs_hash(recs, fixed, seed, search)
    record = _rank_structures(recs, fixed, seed, search, progress, inputs, previous=previous,
                              previous_race=earlier.race)
    record.added = added + new_paths
    record.earlier_set = earlier.indistinguishable
    _write(out, record)  # the ranking survives whatever happens to the chains
    return discover(record.recordings, out, fixed=fixed, seed=seed, quick=quick,
                    max_steps=max_steps, mcmc=mcmc, progress=progress, search=search, dask=dask)


def median_sensor_noise(sensor_noise) -> float:
    """The median of a discovery's per-recording sensor-noise estimates (``sensor_noise``,
    recording to rad); 1e-6 rad for noise-free recordings, where the code's own tolerance sets
    the units."""
    noises = [float(v) for v in sensor_noise.values()
              if isinstance(v, (int, float)) and math.isfinite(v) and v > 0]
    return float(np.median(noises)) if noises else 1e-6


def next_test(record, recs, seed, out, spent=None):
    """The test that would tell apart the structures the recordings cannot
    (:func:`tvcid.discovery.prediction.discrimination.discriminating_tests` on the set's unmerged
    members at their fitted parameters, refitted to the recordings for the best
    candidates; the default menu acquired at the recordings' highest rate, the recordings'
    median noise); writes ``next_test.png``. A calibrated member the data decide against
    (:func:`tvcid.discovery.members.set_weights.decided_against`: under the deciding share, its
    weight final) is left out (``left_out``), the weight of the members merged into it counted
    as its own; one beyond the calibration's cap, or whose weight is not final, stays. ``None``
    for a set of one.
    A dict ``spent`` gets what it simulated, ``simulated_seconds`` and ``simulated_steps``."""
    from tvcid.discovery.prediction.discrimination import (
        default_candidates,
        discriminating_tests,
    )
    from tvcid.discovery.members.set_weights import decided_against, stored_unsure
    from tvcid.discovery.structure.targets import make_target
    from tvcid.models import params_from_dict

    weight = record.member_weights()
    sp = record.set_posterior or {}
    unsure = set(stored_unsure(sp))
    for s in record.structures:  # a merged member's weight, and its being unsure, its structure's
        if s["indistinguishable_from_best"] and s["merged_into"] and s.get("structure") in weight:
            into = s["merged_into"]
            weight[into] = weight.get(into, 0.0) + weight.pop(s["structure"])
            unsure |= {into} if s["structure"] in unsure else set()
    rows = record.set_rows()
    against = set(decided_against(weight, unsure))
    left_out = [{"structure": s["structure"], "weight": weight[s["structure"]]} for s in rows
                if s.get("structure") in against]
    members = [params_from_dict("custom", s["params"]) for s in rows
               if s.get("structure") not in against]
    spent = spent if spent is not None else {}
    spent.update(simulated_seconds=0.0, simulated_steps=0.0)
    if len(members) < 2:  # the weights leave one structure: nothing to split
        return ({"best": None, "tests": [], "left_out": left_out,
                 "members": [s["structure"] for s in rows if s["structure"] not in
                             {x["structure"] for x in left_out}]} if left_out else None)
    noise = median_sensor_noise(record.sensor_noise)
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
        record = RunRecord.from_dict(json.loads(path.read_text()))
    except (OSError, ValueError):
        return None
    if record.inputs != inputs or not record.structures:
        return None
    return record


def _rank_structures(recs, fixed, seed, search, progress, inputs, previous=None, executor=None,
                     previous_race=None):
    from tvcid.discovery.structure import StructureDiscovery

    t0 = time.perf_counter()
    disc = StructureDiscovery(fixed=fixed, seed=seed, search=search, progress=progress,
                              executor=executor).fit(recs, previous=previous,
                                                     previous_race=previous_race)
    cost = RunCost(wall={**disc.timings_}, cpu={**disc.cpu_seconds_},
                   simulated_seconds={**disc.simulated_seconds_},
                   simulated_steps={**disc.simulated_steps_})
    # the search's whole cost in every ledger: a run's totals then need no list of its stages
    cost.add("discovery", wall=time.perf_counter() - t0, cpu=disc.cpu_seconds_["total"],
             simulated_seconds=sum(disc.simulated_seconds_.values()),
             simulated_steps=sum(disc.simulated_steps_.values()))
    return RunRecord(
        structures=[f.to_dict() for f in disc.ranking_],
        recordings=[str(r.path) for r in recs],
        targets=[t.describe() for t in disc.targets_],
        fixed={k: (v if not hasattr(v, "value") else v.value) for k, v in (fixed or {}).items()},
        indistinguishable=[f.structure.name for f in disc.indistinguishable_],
        decided=disc.decided_, pruned=disc.pruned_, race=disc.race_, sindy=disc.sindy_,
        sensor_offset=disc.offsets_, sensor_noise=disc.noise_,
        estimated={"sensor_offset": "per recording, profiled (least squares) at the best fit",
                   "sensor_noise": "open loop: rms output error at the best fit; closed loop: "
                                   "second differences"},
        simulations=disc.n_simulations_, searches=dict(disc.searches_), cost=cost, seed=seed,
        search=search, inputs=inputs)


def _write(out, record):
    DiscoveryResult(record, out).save()
