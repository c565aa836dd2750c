"""tvcid installs as one package, ``tvcid``: the folders ``models/``, ``discovery/``, ``studies/``
and ``data/`` install as ``tvcid.models``, ``tvcid.discovery``, ``tvcid.studies`` and ``tvcid.data``
(pyproject.toml's ``package-dir``), and the wheel, installed outside the checkout, runs its
commands on the recordings it bundles."""
import json
import os
import re
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Checkout folder -> the package it installs as.
FOLDERS = {"tvcid": "tvcid", "models": "tvcid.models", "discovery": "tvcid.discovery",
           "studies": "tvcid.studies", "data": "tvcid.data"}
#: The bundled files the package code reads.
BUNDLED = ("m000_closed_A.csv", "m000_closed_A.json", "m000_closed_B.csv", "m000_closed_B.json",
           "m000_open_square.csv", "m000_open_square.json", "m000_open_sine.csv",
           "m000_open_sine.json", "papers.json")
#: What setuptools' build_py copies into a wheel, run from pyproject.toml's configuration.
BUILD_PY = """
import sys
from setuptools.config.pyprojecttoml import apply_configuration
from setuptools.dist import Distribution

dist = apply_configuration(Distribution(), "pyproject.toml")
dist.script_name = "setup.py"  # none: setuptools wants a name
dist.get_command_obj("egg_info").egg_base = sys.argv[1]
build_py = dist.get_command_obj("build_py")
build_py.build_lib = sys.argv[2]
build_py.compile = build_py.optimize = 0
dist.run_command("build_py")
"""
#: An import of a folder by its own name, or a module named by it after ``-m`` or in a string.
OLD_NAME = re.compile(r"^\s*(?:from|import)\s+(?:models|discovery|studies|data)\b"
                      r"|(?<![\w./-])(?:-m |[\"'])(?:models|discovery|studies)\.(?!json\b|md\b)\w",
                      re.M)


def _sources():
    for folder in (*FOLDERS, "tests"):
        yield from sorted((ROOT / folder).rglob("*.py"))


def _files_under(directory):
    return {p.relative_to(directory).as_posix() for p in directory.rglob("*") if p.is_file()}


def test_the_package_list_installs_every_module_under_tvcid_alone(tmp_path):
    """build_py (the wheel's contents, without building the wheel) puts ``tvcid`` alone at the
    top level, every module of the four folders under its ``tvcid.*`` name, and the bundled files
    in ``tvcid/data``; the tests' fixtures (``data/bench/``) stay out."""
    build = tmp_path / "lib"
    subprocess.run([sys.executable, "-c", BUILD_PY, str(tmp_path), str(build)], cwd=ROOT,
                   check=True, capture_output=True, text=True)
    built = _files_under(build)
    assert {name.split("/")[0] for name in built} == {"tvcid"}
    for folder, package in FOLDERS.items():
        target = package.replace(".", "/")
        modules = {f"{target}/{p.relative_to(ROOT / folder).as_posix()}"
                   for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts}
        assert modules <= built, f"{folder}/ modules not installed: {sorted(modules - built)[:5]}"
    assert {f"tvcid/data/{name}" for name in BUNDLED} <= built
    assert not any(name.startswith("tvcid/data/bench/") for name in built)


def test_no_source_names_a_folder_as_a_top_level_module():
    """Run from the checkout, ``import models`` would still find ``./models`` (a second copy of
    every module beside ``tvcid.models``): every import and module name is ``tvcid.*``."""
    found = [f"{p.relative_to(ROOT)}:{p.read_text()[:m.start()].count(chr(10)) + 1}"
             for p in _sources() for m in OLD_NAME.finditer(p.read_text())]
    assert found == []


def test_the_study_command_is_the_entry_point_of_tvcid_studies():
    from importlib.metadata import entry_points

    (study,) = [ep for ep in entry_points(group="tvcid.commands") if ep.name == "study"]
    assert study.value == "tvcid.studies.command"


def _run(args, cwd, env, timeout=600):
    """Run ``args``; the test fails with its output unless it exits 0."""
    proc = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"{args[0]} {args[1:3]} exited {proc.returncode}: " \
                                 f"{proc.stdout[-1500:]}\n{proc.stderr[-1500:]}"
    return proc.stdout


@pytest.mark.slow
def test_the_wheel_installed_outside_the_checkout_runs_its_commands(tmp_path):
    """``pip wheel`` on a copy of the checkout; the wheel in a fresh virtual environment (its
    dependencies those of this interpreter, through a ``.pth`` file); from a directory outside the
    checkout, ``tvcid --help``, ``tvcid simulate``, a quick study and a quick ``tvcid discover`` on
    the recording the wheel bundles each exit 0 and write their outputs (about 2.5 minutes on 2
    busy cores, most of it the discovery)."""
    start = time.monotonic()
    source = tmp_path / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache", "results",
        "*.nbi", "*.nbc"))
    wheels = tmp_path / "wheels"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", wheels, source],
         tmp_path, env)
    (wheel,) = wheels.glob("tvcid-*.whl")
    with zipfile.ZipFile(wheel) as whl:
        names = whl.namelist()
    assert {n.split("/")[0] for n in names if ".dist-info/" not in n} == {"tvcid"}
    assert "tvcid/data/m000_open_square.csv" in names and "tvcid/studies/command.py" in names

    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", venv], tmp_path, env)
    python, tvcid = venv / "bin" / "python", venv / "bin" / "tvcid"
    _run([python, "-m", "pip", "install", "--no-deps", "--no-index", "-q", wheel], tmp_path, env)
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     tmp_path, env).strip())
    deps = sorted({p for p in sys.path if Path(p).name in ("site-packages", "dist-packages")})
    (site / "tvcid_test_dependencies.pth").write_text("\n".join(deps) + "\n")

    work = tmp_path / "work"
    work.mkdir()
    where = json.loads(_run([python, "-c", (
        "import importlib.util, json, tvcid, tvcid.models, tvcid.studies.command\n"
        "from tvcid.data import path\n"
        "print(json.dumps({'tvcid': tvcid.__file__, 'models': tvcid.models.__file__,\n"
        "    'square': str(path('m000_open_square.csv')),\n"
        "    'old': [n for n in ('models', 'discovery', 'studies') if importlib.util.find_spec(n)]}))")],
        work, env))
    for key in ("tvcid", "models", "square"):
        assert Path(where[key]).is_relative_to(site), (key, where[key])
    assert where["old"] == []

    assert "discover" in _run([tvcid, "--help"], work, env)
    _run([tvcid, "simulate", "M000", "--t-end", "5", "--out", "sim.csv"], work, env)
    assert (work / "sim.csv").stat().st_size > 0 and (work / "sim.json").is_file()
    _run([tvcid, "study", "h4_delay_position", "--quick", "--results", "results"], work, env)
    assert any((work / "results" / "h4_delay_position").glob("*.png"))
    assert any((work / "results" / "h4_delay_position").glob("*.json"))
    _run([tvcid, "discover", where["square"], "--quick", "--no-mcmc", "--no-progress",
          "--out", "run"], work, env, timeout=1800)
    assert (work / "run" / "report.md").is_file() and (work / "run" / "discovery.json").is_file()
    print(f"wheel built, installed and run in {time.monotonic() - start:.0f} s")
