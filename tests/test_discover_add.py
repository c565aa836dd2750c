"""``tvcid discover --add``: the experiment loop. Recordings added to an earlier run give the
ranking a fresh run on all of them gives; bad input to ``--add`` is one line and leaves the
directory as it was."""
import hashlib
import json
import shutil

import pytest

from tvcid.cli import main

A, B = "data/m000_closed_A.csv", "data/m000_closed_B.csv"
#: One structure (M000's placement, its backlash and band-pass loop fixed): a discovery of
#: seconds, so that these tests are about the loop, not the search.
FIX = ["--fix", "dead_zone_position=velocity", "--fix", "delay_position=before_first_integrator",
       "--fix", "friction_offset=0", "--fix", "backlash=1.1625e-4", "--fix", "bandpass_gain=72",
       "--fix", "bandpass_saturation=0.01"]
OPTIONS = ["--quick", "--no-mcmc", "--no-progress"]


def _tree(path):
    """Digest of every file under ``path`` (names and bytes)."""
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A run on cycle A, the same with cycle B added, and a fresh run on both."""
    root = tmp_path_factory.mktemp("add")
    assert main(["discover", A, *FIX, *OPTIONS, "--out", str(root / "loop")]) == 0
    earlier = json.loads((root / "loop" / "discovery.json").read_text())
    shutil.copytree(root / "loop", root / "earlier")
    assert main(["discover", "--add", B, *OPTIONS, "--out", str(root / "loop")]) == 0
    assert main(["discover", A, B, *FIX, *OPTIONS, "--out", str(root / "fresh")]) == 0
    read = lambda d: json.loads((root / d / "discovery.json").read_text())  # noqa: E731
    return root, earlier, read("loop"), read("fresh")


def test_added_recording_gives_the_fresh_runs_ranking_and_parameters(runs):
    """After ``--add``: both recordings, the earlier run's set kept for reference, the same
    winner and set as the fresh run on both, with a held-out score within the set's margin floor
    of the fresh run's (the two cycles leave a gain-delay ridge open, along which the two runs'
    parameters may differ); no global stage over every structure."""
    _, earlier, loop, fresh = runs
    assert loop["recordings"] == fresh["recordings"] == [A, B]
    assert loop["added"] == [B] and loop["earlier_set"] == earlier["indistinguishable"]
    best_loop, best_fresh = loop["structures"][0], fresh["structures"][0]
    assert best_loop["structure"] == best_fresh["structure"]
    assert loop["indistinguishable"] == fresh["indistinguishable"]
    assert abs(best_loop["score"] - best_fresh["score"]) <= 0.2  # the margin's floor, two recordings
    assert "refit" in loop["timings"] and "global" not in loop["timings"]
    # the --add's search is its refit and ranking, counted whole in every ledger's entry
    steps = loop["simulated_steps"]
    assert steps["refit"] > 0 and steps["discovery"] == pytest.approx(
        steps["refit"] + steps["ranking"], rel=1e-12)
    # least squares from cycle A's optimum, or, where cycle B pulls the refit out of A's basin
    # (A fits worse than at A's optimum), a global search seeded with the refit
    assert best_loop["origin"].startswith(("least squares from the earlier run's optimum",
                                           "global search (the added recordings fit worse"))


def test_an_earlier_optimum_that_fits_the_added_recording_is_refined_not_searched(runs):
    """``previous`` at the fresh run's optimum of cycles A and B: the refit fits no recording
    worse than its start, so no global search runs and the optimum's cost is kept within a few
    hundredths."""
    from tvcid.discovery.structure import StructureDiscovery
    from tvcid.models.hypotheses import params_from_dict
    from tvcid.models.recording import load_recordings

    _, _, _, fresh = runs
    best = fresh["structures"][0]
    previous = {best["structure"]: params_from_dict("custom", best["params"])}
    disc = StructureDiscovery(fixed=fresh["fixed"], seed=fresh["seed"], search=fresh["search"],
                              use_sindy=False).fit(load_recordings([A, B]), previous=previous)
    assert disc.searches_["global"] == 0, disc.searches_
    assert disc.best_.origin == "least squares from the earlier run's optimum"
    assert disc.best_.cost <= best["cost"] + 0.05, (disc.best_.cost, best["cost"])


@pytest.mark.parametrize("case, expected", [
    ("already", "is already in the run"),
    ("other_fix", "differs from the earlier run's fixed set-up"),
    ("other_version", "another version of tvcid discover"),
    ("no_run", "holds no discovery.json"),
    ("with_files", "--add takes the new recordings"),
])
def test_bad_add_is_one_line_and_leaves_the_directory_unchanged(runs, tmp_path, capsys, case,
                                                                 expected):
    """A recording already in the run, a different --fix, a directory from another version, no
    earlier run, FILE.csv beside --add: exit 2, one line naming the problem, DIR unchanged."""
    root, *_ = runs
    out = tmp_path / "run"
    if case != "no_run":
        shutil.copytree(root / "earlier", out)
    if case == "other_version":
        summary = json.loads((out / "discovery.json").read_text())
        summary.pop("format")
        (out / "discovery.json").write_text(json.dumps(summary))
    before = _tree(out) if out.exists() else None
    args = {"already": ["--add", A], "other_fix": ["--add", B, "--fix", "backlash=2e-4"],
            "other_version": ["--add", B], "no_run": ["--add", B],
            "with_files": [A, "--add", B]}[case]
    assert main(["discover", *args, *OPTIONS, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert (_tree(out) if out.exists() else None) == before
