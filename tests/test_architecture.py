"""The package has no import cycles: the module import graph (every ``import`` / ``from ... import`` in every
module of the installed packages, also those inside functions) is acyclic. A cycle is listed when found."""
from __future__ import annotations

import ast
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SETUP = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
# Import edges allowed to close a cycle (none today). An edge listed here that no longer exists fails the test,
# so the list cannot go stale.
KNOWN_CYCLE_EDGES: set = set()


def modules() -> dict[str, Path]:
    """Module name -> file of every module of the packages pyproject.toml installs."""
    out = {}
    for pkg, folder in SETUP["package-dir"].items():
        for f in (ROOT / folder).glob("*.py"):
            out[pkg if f.name == "__init__.py" else f"{pkg}.{f.stem}"] = f
    return out


def import_graph() -> dict[str, set[str]]:
    mods = modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    parts = parts[:len(parts) - node.level + 1]
                    base = ".".join(parts + ([node.module] if node.module else []))
                subs = [f"{base}.{a.name}" for a in node.names]
                # "from pkg import module": the module; "from pkg import name": the package (its __init__)
                targets = subs if all(t in mods for t in subs) else [base] + subs
            for t in targets:
                if t in mods and t != name:
                    graph[name].add(t)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle (a list of modules, first == last) or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state:
                found = visit(n)
                if found:
                    return found
        state[m] = 2
        stack.pop()
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def test_graph_sees_the_package():
    g = import_graph()
    assert len(g) >= 50 and "etb_gym.rl.train" in g and "etb_gym.envs.env" in g
    assert "etb_gym.rl.config" in g["etb_gym.rl.train"]            # relative imports resolved
    assert "etb_gym.envs.observation" in g["etb_gym.rl.task"]      # "from pkg import module"


def test_no_import_cycles():
    g = import_graph()
    stale = {e for e in KNOWN_CYCLE_EDGES if e[1] not in g.get(e[0], ())}
    assert not stale, f"these known cycle edges are gone: remove them from KNOWN_CYCLE_EDGES: {sorted(stale)}"
    for a, b in KNOWN_CYCLE_EDGES:
        g[a].discard(b)
    cycle = find_cycle(g)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_find_cycle_reports_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_only_the_plant_touches_its_engine():
    """Callers use Plant's public way in (``stepper(path)``, ``state_slices``, ``simulate``): an attribute read
    ``<x>.engine`` outside etb_gym/plant.py (and integrate.py, which builds it) would break on a rename."""
    offenders = []
    for folder in ("etb_gym", "envs", "controllers"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel in ("etb_gym/plant.py", "etb_gym/integrate.py"):
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Attribute) and node.attr == "engine":
                    offenders.append(f"{rel}:{node.lineno}")
    assert not offenders, f"Plant.engine read outside plant.py: {offenders}"
