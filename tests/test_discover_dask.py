"""``tvcid discover --dask``: the classes' global searches and the set members' calibrations as
tasks of a Dask cluster give the answer of the run in this process.

The default suite runs real tasks on a ``local:2`` cluster: the searches of a small structure
space (two dead-zone positions, the band-pass loop on and off: two waves of two searches) cut
short, and the calibrations of a stand-in ranking's two members with short chains; a bad
``--dask`` is one line. The slow test compares whole ``tvcid discover`` runs.

The Dask tests need the ``dask`` extra (``pip install tvcid[dask]``) and are skipped without it.
"""
import json
import sys

import pytest
from test_discover_resume import FIXED, STEPS, TRUTH, _Ranking

from tvcid.discovery.executors import executor_from
from tvcid.discovery.structure import StructureDiscovery
from tvcid.models import CONTROLLER_A, simulate
from tvcid.models.recording import recording_from_trajectory, save_recording
from tvcid.cli import main

#: A structure space of four: the dead zone on the error or the velocity signal, the band-pass
#: loop off or on (the other choices fixed); the searches cut short (the test is about where
#: they run, not what they find).
SPACE = {"delay_position": TRUTH.delay_position.value, "friction_offset": 0.0,
         "backlash": TRUTH.backlash}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A 14 s limit cycle of :data:`test_discover_resume.TRUTH` under controller A."""
    columns, meta = recording_from_trajectory(simulate(TRUTH, CONTROLLER_A, 14.0, rate=1000.0))
    meta = {k: meta[k] for k in ("kind", "kp", "kd", "mu")}
    path = tmp_path_factory.mktemp("dask") / "rec.csv"
    return str(save_recording(path, {k: columns[k] for k in ("t", "u", "delta")}, meta))


def _ranking(disc):
    """What a discovery found and spent; the ranking's refits add their simulated seconds from
    threads in the order they finish, so those sums are compared to rounding."""
    rows = [(f.structure.name, f.origin, f.cost, f.score, f.indistinguishable_from_best,
             f.merged_into, tuple(f.theta)) for f in disc.ranking_]
    return (rows, disc.n_simulations_, disc.searches_, disc.repaired_,
            [getattr(t, "second_starts", 0) for t in disc.targets_])


def test_searches_on_a_dask_cluster_give_this_process_ranking(recording, monkeypatch):
    pytest.importorskip("distributed")
    import tvcid.discovery.structure.structure_search as structure_search

    # the sizes travel with each search; a module constant patched here would not
    monkeypatch.setitem(structure_search.SEARCHES, "standard", structure_search.SearchSizes(
        pop=3, gens=3, open_pop=3, open_gens=3, nfev=4, rank_nfev=3))
    here = StructureDiscovery(fixed=SPACE, seed=0, use_sindy=False).fit([recording])
    with executor_from(dask="local:2") as executor:
        there = StructureDiscovery(fixed=SPACE, seed=0, use_sindy=False,
                                   executor=executor).fit([recording])
    assert len(here.ranking_) == 4 and here.searches_["global"] >= 4
    assert _ranking(there) == _ranking(here)
    assert there.simulated_seconds_ == pytest.approx(here.simulated_seconds_, rel=1e-12)
    assert there.simulated_steps_ == pytest.approx(here.simulated_steps_, rel=1e-12)
    assert there.simulated_seconds_["global"] > 0


def _calibrated(recording, out, dask, monkeypatch):
    """The stand-in ranking's members calibrated into ``out``, in this process (``dask`` None)
    or on the cluster ``dask``; returns the summary."""
    import tvcid.discovery.structure
    import tvcid.pipeline

    monkeypatch.setattr(tvcid.discovery.structure, "StructureDiscovery", _Ranking)
    monkeypatch.setattr(tvcid.pipeline, "next_test", lambda *a: None)  # not at issue
    return tvcid.pipeline.discover([recording], out, fixed=FIXED, seed=1, quick=True,
                                   max_steps=STEPS, progress=False, dask=dask).summary


def test_members_calibrated_on_a_dask_cluster_give_this_process_posterior(recording, tmp_path,
                                                                          monkeypatch):
    """The stand-in ranking's two members (:class:`test_discover_resume._Ranking`), each
    calibrated on a worker of ``local:2``: the same members in the same order, the same
    posteriors, step errors, weights and combination as in this process; each chain is in its
    own file of the output directory; the figures are written by this process."""
    pytest.importorskip("distributed")
    here = _calibrated(recording, tmp_path / "here", None, monkeypatch)
    there = _calibrated(recording, tmp_path / "there", "local:2", monkeypatch)
    members = [m["structure"] for m in here["set_posterior"]["members"]]
    assert len(members) == 2 and not here["set_posterior"]["failed"]
    assert json.dumps(there["posterior"], sort_keys=True) == json.dumps(here["posterior"],
                                                                        sort_keys=True)
    assert (json.dumps(_untimed(there["set_posterior"]), sort_keys=True)
            == json.dumps(_untimed(here["set_posterior"]), sort_keys=True))
    for key in ("simulated_seconds", "simulated_steps"):
        assert there[key]["mcmc"] == pytest.approx(here[key]["mcmc"], rel=1e-12)
    # each member's CPU seconds are its worker's there; the stage's add them to this process's
    for run in (here, there):
        rows = run["set_posterior"]["members"]
        assert all(m["cpu_seconds"] > 0 and m["wall_seconds"] > 0 for m in rows)
        assert run["cpu_seconds"]["mcmc"] >= sum(m["cpu_seconds"] for m in rows)
    chains = sorted(p.name for p in (tmp_path / "there").glob("chain-*.h5"))
    assert chains == sorted(p.name for p in (tmp_path / "here").glob("chain-*.h5"))
    assert chains == sorted(m["posterior"]["chain"] for m in there["set_posterior"]["members"])
    assert (tmp_path / "there" / "corner.png").is_file()


@pytest.mark.parametrize("address, says", [
    ("nowhere", "argument --dask: 'nowhere': not a Dask scheduler address"),
    ("local:0", "argument --dask: 'local:0': local:N needs N"),
])
def test_a_bad_dask_address_is_one_line(recording, tmp_path, capsys, address, says):
    pytest.importorskip("distributed")  # the address is checked once Dask is there
    with pytest.raises(SystemExit) as stop:
        main(["discover", recording, "--dask", address, "--out", str(tmp_path / "out")])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_dask_without_dask_installed_names_the_extra(recording, tmp_path, monkeypatch, capsys):
    import tvcid

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed: ImportError
    with pytest.raises(SystemExit) as stop:
        main(["discover", recording, "--dask", "local:2", "--out", str(tmp_path / "out")])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.endswith(
        "Dask's distributed scheduler is not installed: pip install tvcid[dask] "
        "(see tvcid discover --help)")
    with pytest.raises(ImportError, match=r"pip install tvcid\[dask\]"):
        tvcid.discover([recording], tmp_path / "api", dask="local:2")
    assert not (tmp_path / "api").exists()  # refused before any work


#: ``tvcid discover`` on four structures (:data:`SPACE`) with short chains.
RUN = ["--fix", f"delay_position={TRUTH.delay_position.value}", "--fix", "friction_offset=0",
       "--fix", f"backlash={TRUTH.backlash}", "--quick", "--max-steps", "20", "--seed", "3",
       "--no-progress"]


def _untimed(set_posterior):
    """``set_posterior`` without its members' CPU and wall seconds."""
    return {**set_posterior, "members": [
        {k: v for k, v in m.items() if k not in ("cpu_seconds", "wall_seconds")}
        for m in set_posterior["members"]]}


def _without_timings(summary):
    summary = dict(summary)
    for key in ("timings", "cpu_seconds", "simulated_seconds", "simulated_steps"):
        summary.pop(key)
    summary["set_posterior"] = _untimed(summary["set_posterior"])
    return json.dumps(summary, sort_keys=True)


@pytest.mark.slow
def test_discover_on_a_dask_cluster_gives_the_local_discovery(recording, tmp_path):
    """The whole ``tvcid discover`` at the default search sizes, with and without ``--dask
    local:2``: the same ``discovery.json`` (the ranking, the set, every member's posterior, the
    combination), but for the wall and CPU times and the simulated seconds and steps summed in
    threads' order."""
    pytest.importorskip("distributed")
    runs = {}
    for where in ("here", "there"):
        extra = ["--dask", "local:2"] if where == "there" else []
        assert main(["discover", recording, *RUN, *extra, "--out", str(tmp_path / where)]) == 0
        runs[where] = json.loads((tmp_path / where / "discovery.json").read_text())
    assert _without_timings(runs["there"]) == _without_timings(runs["here"])
    for key in ("simulated_seconds", "simulated_steps"):
        for stage, seconds in runs["here"][key].items():
            assert runs["there"][key][stage] == pytest.approx(seconds, rel=1e-12)
    assert len(runs["here"]["structures"]) == 4 and runs["here"]["set_posterior"]["members"]
