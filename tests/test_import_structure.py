"""No circular import anywhere in the installed package.

The package's modules (every ``.py`` file under the folders ``pyproject.toml`` maps to ``tvcid``
and its subpackages) are parsed with :mod:`ast`, nothing is imported, and each import of a
``tvcid`` module becomes an arrow of a graph; the graph must have no cycle.

What counts as an arrow:

* every ``import`` and ``from ... import`` statement, at module level and inside a function or a
  class alike: an import deferred into a function still ties the two modules' code together, and a
  cycle hidden there is one that a later move of the import to the top would break at import time;
* ``from P import N`` is an arrow to the module ``P.N`` where ``P.N`` is a module, else to ``P``
  (a package's ``__init__``, or a module a name is taken from);
* importing ``P.M`` is an arrow to ``P.M`` alone, not to the packages above it: Python runs their
  ``__init__`` first, but a package that imports its own modules is no cycle of the design.

Imports by name at run time (:mod:`importlib`, ``__import__``) are not read.
"""
from __future__ import annotations

import ast
import functools
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def package_modules() -> dict[str, Path]:
    """``{module name: file}`` of every module of the installed package, by pyproject.toml's
    ``package-dir`` and ``packages``."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = config["package-dir"]
    modules = {}
    for package in config["packages"]:
        top = max((p for p in folders if package == p or package.startswith(p + ".")), key=len)
        folder = ROOT / folders[top] / Path(*package[len(top):].split(".")[1:])
        for path in sorted(folder.glob("*.py")):
            name = package if path.stem == "__init__" else f"{package}.{path.stem}"
            modules[name] = path
    return modules


def imported_modules(name: str, path: Path, modules) -> set[str]:
    """The package's modules that module ``name`` (file ``path``) imports anywhere in its code."""
    package = name if path.stem == "__init__" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module
            for alias in node.names:
                child = f"{source}.{alias.name}"
                found.add(child if child in modules else source)
    return {m for m in found if m in modules and m != name}


@functools.lru_cache(maxsize=1)
def import_graph() -> dict[str, set[str]]:
    """``{module: the package's modules it imports}`` (read once per test run)."""
    modules = package_modules()
    return {name: imported_modules(name, path, modules) for name, path in modules.items()}


def cycles(graph) -> list[list[str]]:
    """The strongly connected components of ``graph`` that hold more than one module (Tarjan),
    each sorted."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        # iterative depth-first search: the graph is a few hundred modules deep at most
        work = [(v, iter(sorted(graph[v])))]
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        while work:
            node, successors = work[-1]
            for w in successors:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[node] = min(low[node], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == node:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _loop(graph, component) -> list[str]:
    """One closed path through ``component``: module -> ... -> the same module."""
    members = set(component)
    start = component[0]
    path, seen = [start], {start}
    while True:
        nxt = sorted(w for w in graph[path[-1]] if w in members)
        back = [w for w in nxt if w in seen]
        if back:
            return path[path.index(back[0]):] + [back[0]]
        path.append(nxt[0])
        seen.add(nxt[0])


def test_the_graph_reads_the_whole_package():
    """The graph holds every subpackage and sees imports both at module level and in functions."""
    graph = import_graph()
    assert {"tvcid.pipeline", "tvcid.models.cycle_reading", "tvcid.discovery.members.set_posterior",
            "tvcid.discovery.structure.targets", "tvcid.studies.benchmarks.scenarios"} <= set(graph)
    assert "tvcid.models.cycle_reading" in graph["tvcid.discovery.structure.targets"]
    # imported inside calibrate_set only
    assert "tvcid.discovery.members.set_posterior" in graph["tvcid.set_stage"]


def test_cycles_finds_a_loop():
    """A loop of three modules is one component, and its path closes on its first module."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]
    assert _loop(graph, ["a", "b", "c"]) == ["a", "b", "c", "a"]


def test_no_circular_import():
    """No module of the package reaches itself through its imports."""
    graph = import_graph()
    found = cycles(graph)
    assert not found, "circular imports:\n" + "\n".join(
        " -> ".join(_loop(graph, c)) for c in found)


def subpackage_graph(graph, parent="tvcid.discovery") -> dict[str, set[str]]:
    """``{subpackage: the sibling subpackages its modules import}`` of ``parent``'s subpackages
    (a module directly in ``parent`` is its own node)."""
    def node(module):
        rest = module[len(parent) + 1:].split(".")
        return f"{parent}.{rest[0]}"

    inside = [m for m in graph if m.startswith(parent + ".")]
    out = {node(m): set() for m in inside}
    for m in inside:
        out[node(m)].update(node(w) for w in graph[m] if w.startswith(parent + "."))
    for n, targets in out.items():
        targets.discard(n)
    return out


def test_no_circular_import_between_discovery_stages():
    """The discovery's subpackages import one another in layers: no subpackage reaches itself
    through another's modules (calibration below the structure search, the search below the set's
    members and below prediction, which names the next test)."""
    graph = subpackage_graph(import_graph())
    assert {"tvcid.discovery.structure", "tvcid.discovery.members",
            "tvcid.discovery.prediction"} <= set(graph)
    found = cycles(graph)
    assert not found, "circular imports between subpackages:\n" + "\n".join(
        " -> ".join(_loop(graph, c)) for c in found)
