"""The set's combined posterior first: ``DiscoveryResult.set_posterior`` and ``.interval``, and
what ``tvcid discover`` prints and says it does (a result built from a summary, no run)."""
import json
import math

import numpy as np
import pytest

from tvcid.discovery.members.set_posterior import MemberPosterior, combine
from tvcid.models.quantities import member_quantities
from tvcid.models import hypothesis
from tvcid.models.structures import Structure, shared_choices
from tvcid.pipeline import DiscoveryResult

#: Two members of M000's structure differing in the delay's position, and where they put it (s).
MEMBERS = (("before_first_integrator", 1.7e-3), ("before_integrator", 2.4e-3))


def _quantiles(x):
    q05, q50, q95 = np.quantile(x, [0.05, 0.5, 0.95])
    return {"q05": float(q05), "q50": float(q50), "q95": float(q95)}


@pytest.fixture(scope="module")
def summary():
    """A two-member set's summary as :func:`tvcid.pipeline.discover` writes it: the ranking's
    rows, the winner's posterior alone and the set's combined one (seeded draws)."""
    rng = np.random.default_rng(11)
    rows, members = [], []
    for i, (position, delay) in enumerate(MEMBERS):
        params = hypothesis("M000", delay_position=position).to_dict()
        draws = {"dead_zone": 8.3e-3 + 2e-4 * rng.standard_normal(4000),
                 "delay": delay + 5e-5 * rng.standard_normal(4000)}
        structure = Structure.of_params(hypothesis("M000", delay_position=position))
        post = {"parameters": {n: _quantiles(v) for n, v in draws.items()}, "converged": True,
                "iterations": 2000, "n_over_tau": 80.0, "acceptance": 0.3, "at_prior_bound": [],
                "laplace_move": None, "interval_drift": None, "not_pinned": [],
                "structure": structure.name, "chain": f"chain-{i}.h5"}
        rows.append({"structure": structure.name, "components": structure.to_dict(),
                     "params": params, "score": 1.0 + 0.1 * i, "criterion": "held-out cost",
                     "cost": 1.0, "margin": 0.5, "indistinguishable_from_best": True,
                     "merged_into": None, "coordinate_sd": {}})
        members.append(MemberPosterior(structure.name, member_quantities(params, draws), post,
                                       0.2 * i))
    combined = combine(members, seed=0).to_dict()
    combined["not_calibrated"] = []
    return {"structures": rows, "indistinguishable": [r["structure"] for r in rows],
            "decided": shared_choices([Structure.parse(r["structure"]) for r in rows]),
            "next_test": None, "posterior": members[0].summary, "set_posterior": combined}


def test_the_set_posterior_and_its_intervals_are_read_by_name(summary, tmp_path):
    """``set_posterior`` is the summary's; ``interval(name)`` its combined (q05, q95), the same
    after the JSON round trip; the set's delay interval holds both members' delays, where the
    winner's alone holds only its own."""
    result = DiscoveryResult.from_dict(summary)
    assert result.set_posterior is summary["set_posterior"]
    combined = summary["set_posterior"]["quantities"]
    for name in ("delay", "dead_zone[velocity]", "dc_gain"):
        assert result.interval(name) == (combined[name]["q05"], combined[name]["q95"])
    low, high = result.interval("delay", level=0.9)
    assert low < MEMBERS[0][1] and MEMBERS[1][1] < high
    assert result.posterior["parameters"]["delay"]["q95"] < MEMBERS[1][1]
    (tmp_path / "discovery.json").write_text(json.dumps(result.to_dict()))
    loaded = DiscoveryResult.load(tmp_path)
    assert loaded.interval("delay") == (low, high)
    loaded.summary["set_posterior"]["quantities"]["delay"]["q95"] = None  # a non-finite end
    assert math.isnan(loaded.interval("delay")[1])


@pytest.mark.parametrize("case, message", [
    ("unknown", r"^unknown quantity 'dead_zone'; the set's posterior has dead_zone\[velocity\], "),
    ("no set", r"^no set posterior: the run stopped after the ranking"),
    ("level", r"^interval level 0\.5: the summary stores the 90 % interval \(q05, q95\) only$"),
    ("left open", r"^backlash: the set leaves its component open and no member with it could be "),
])
def test_a_bad_interval_request_is_a_one_line_error(summary, case, message):
    """An unknown quantity names those there are; a run without MCMC has no set posterior
    (``set_posterior`` is ``None``); a component left open that no calibrated member holds has
    no interval; only the 90 % interval is stored."""
    result = DiscoveryResult.from_dict(summary)
    if case == "no set":
        result = DiscoveryResult.from_dict({k: v for k, v in summary.items()
                                  if k not in ("posterior", "set_posterior")})
        assert result.set_posterior is None
    if case == "left open":  # a copy: the summary is the module's
        result = DiscoveryResult.from_dict({**summary, "set_posterior": {
            **summary["set_posterior"], "left_open_uncalibrated": ["backlash"]}})
    with pytest.raises(ValueError, match=message) as err:
        result.interval({"unknown": "dead_zone", "left open": "backlash"}.get(case, "delay"),
                        level=0.5 if case == "level" else 0.90)
    assert "\n" not in str(err.value)
    if case == "unknown":
        assert all(n in str(err.value) for n in summary["set_posterior"]["quantities"])


def test_discover_prints_the_sets_quantities_and_points_to_the_winners_posterior(
        summary, tmp_path, monkeypatch, capsys):
    """``tvcid discover``'s console: the report's summary (its lines, in order: the set's
    combined quantities with median, 90 % interval, unit and verdict), the winner's posterior as
    one line pointing to report.md, never its intervals, then the files written."""
    import tvcid.pipeline
    from tvcid.cli import main
    from tvcid.report import summary_lines

    result = DiscoveryResult.from_dict(summary, tmp_path)
    monkeypatch.setattr(tvcid.pipeline, "discover", lambda *a, **k: result)
    assert main(["discover", "cycle.csv", "--no-progress", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out.splitlines()
    shown = [li for li in summary_lines(result.to_dict()) if li.strip() and not li.startswith("#")]
    at = [0]  # each line found after the one before it (two tables share a header rule)
    for li in shown:
        at.append(printed.index(li, at[-1] + (len(at) > 1)))
    assert at[1] == 0
    delay = summary["set_posterior"]["quantities"]["delay"]
    row = next(li for li in printed if li.startswith("| delay |"))
    assert all(f"{delay[k]:.4g}" in row for k in ("q50", "q05", "q95")) and "| s |" in row
    winner = summary["posterior"]["parameters"]["delay"]
    assert not any(f"{winner['q05']:.4g}" in li or f"{winner['q95']:.4g}" in li for li in printed)
    pointer = [li for li in printed if "own posterior" in li]
    assert len(pointer) == 1 and summary["structures"][0]["structure"] in pointer[0]
    assert str(tmp_path / "report.md") in pointer[0]
    assert printed[-1] == f"wrote {tmp_path / 'discovery.json'}, {tmp_path / 'report.md'}"


def test_discover_help_describes_the_sets_posterior():
    """The help says the set is calibrated and combined, and what is printed; not that the
    winner alone is calibrated."""
    from tvcid.cli import build_parser
    from tvcid.cli_docs import command_paths

    text = dict(command_paths(build_parser()))[("discover",)].format_help()
    flat = " ".join(text.split())
    assert "calibrate the winner" not in flat
    assert "calibrate each distinct member of that set with MCMC" in flat
    assert "combine their posteriors" in flat and "each physical quantity over the set" in flat
