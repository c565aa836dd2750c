"""``results/report.md``: every study's figures and every number the papers print beside tvcid's.

The paper numbers come from ``data/papers.json``. A number a study reproduces is listed in that
study's ``summary.json`` under ``paper_numbers`` (``{id: {"value", "how"}}``); a parameter tvcid
takes from the papers carries a ``tvcid_field`` in ``papers.json`` and the table shows the value the
model actually uses. Anything else is reported as not reproduced, never left out.

Each study's section is its docstring (after the first paragraph), its config, the lines of its
``report_lines(summary)`` when the module has one (a study's own numbers), and every figure it
wrote.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from tvcid.data import path as bundled_path
from tvcid.models import CONTROLLER_A, CONTROLLER_B, hypothesis

from .registry import STUDIES

PAPERS_JSON = bundled_path("papers.json")
_CONTROLLERS = {"A": CONTROLLER_A, "B": CONTROLLER_B}


def load_papers(path=PAPERS_JSON) -> dict:
    return json.loads(Path(path).read_text())


def _field_value(spec):
    if spec["kind"] == "hypothesis":
        return getattr(hypothesis(spec["name"]), spec["field"]), f"{spec['name']}.{spec['field']}"
    if spec["kind"] == "controller":
        return getattr(_CONTROLLERS[spec["name"]], spec["field"]), f"controller {spec['name']} {spec['field']}"
    raise ValueError(f"unknown tvcid_field kind {spec['kind']!r}")


def paper_number_rows(papers: dict, summaries: dict) -> list:
    """One row per entry of ``papers.json``: printed, reproduced, difference, how."""
    reproduced = {}
    for name, summary in summaries.items():
        for key, item in summary.get("paper_numbers", {}).items():
            reproduced.setdefault(key, {**item, "study": name})
    rows = []
    for entry in papers["numbers"]:
        value, how = None, "not reproduced by the studies run"
        if entry["id"] in reproduced:
            item = reproduced[entry["id"]]
            value, how = item["value"], f"{item['how']} ({item['study']})"
        elif "tvcid_field" in entry:
            value, where = _field_value(entry["tvcid_field"])
            how = f"parameter used: {where}"
        diff = rel = None
        if value is not None and isinstance(value, (int, float)):
            diff = value - entry["value"]
            rel = 100 * diff / entry["value"] if entry["value"] else None
        rows.append({**entry, "reproduced": value, "difference": diff, "relative_pct": rel, "how": how})
    return rows


def _fmt(value):
    if value is None:
        return "—"
    if isinstance(value, float):
        if value == 0 or (1e-3 <= abs(value) < 1e7):
            return f"{value:.6g}"
        return f"{value:.4e}"
    return str(value)


def write_report(results_dir, papers_path=PAPERS_JSON) -> Path:
    """Write ``results_dir/report.md`` from the study outputs found under ``results_dir``."""
    results_dir = Path(results_dir)
    summaries = {}
    for name in STUDIES:
        path = results_dir / name / "summary.json"
        if path.exists():
            summaries[name] = json.loads(path.read_text())
    rows = paper_number_rows(load_papers(papers_path), summaries)
    lines = ["# tvcid report", ""]
    lines.append(
        "The papers' HWIL recordings are not public: the bundled data are **synthetic** "
        "(paper 000's final model, see `data/README.md`)."
    )
    lines.append("")
    lines.append("## Every number the papers print")
    lines.append("")
    lines.append("| id | quantity | paper, section | printed | unit | tvcid | difference | % | how |")
    lines.append("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        rel = "—" if r["relative_pct"] is None or not math.isfinite(r["relative_pct"]) else f"{r['relative_pct']:+.2f}"
        lines.append(
            f"| {r['id']} | {r['quantity']} | {r['paper'][:3]}, {r['section']} | {_fmt(r['value'])} | "
            f"{r['unit']} | {_fmt(r['reproduced'])} | {_fmt(r['difference'])} | {rel} | {r['how']} |"
        )
    for name, summary in summaries.items():
        module = STUDIES[name]
        lines += ["", f"## {name}", "", module.__doc__.split("\n\n", 1)[1].strip(), ""]
        if "config" in summary:
            lines += [f"Config: `{json.dumps(summary['config'])}`, seed {summary.get('seed')}.", ""]
        if hasattr(module, "report_lines"):  # a study's own numbers, before its figures
            lines += module.report_lines(summary)
        for png in sorted((results_dir / name).rglob("*.png")):
            rel = png.relative_to(results_dir).as_posix()
            lines.append(f"![{name}: {png.relative_to(results_dir / name).with_suffix('').as_posix()}]({rel})")
            lines.append("")
    path = results_dir / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
