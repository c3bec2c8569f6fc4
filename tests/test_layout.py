"""The package layout: no import cycle among project modules, few modules per top level, public names import.

The import graph comes from ``ast`` (every ``import``/``from … import`` anywhere in a module, function-level ones
included, since a lazy import that closes a cycle is still a cycle in the design). An edge goes to the module that
is imported; ``from pkg import name`` goes to ``pkg.name`` when that is a module, else to ``pkg`` (its
``__init__``). Parent packages a module lives in are not edges (Python imports them first, they do not import back
through their children unless their ``__init__`` says so, which is an edge of its own).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("kdfaces", "kdfem")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def import_graph() -> dict[str, set[str]]:
    """Module → project modules it imports."""
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        package = mod if is_pkg else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - (node.level - 1)]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                for a in node.names:
                    sub = f"{source}.{a.name}"
                    targets.append(sub if sub in mods else source)
            for t in targets:
                while t and t not in mods:  # `import kdfaces.x.y` names a module; attributes fall back to it
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    graph[mod].add(t)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle as a list of modules (first = last), or None."""
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
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " → ".join(cycle)


def test_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.parametrize("pkg, limit", [("kdfaces", 8), ("kdfem", 4)])
def test_few_modules_at_the_top(pkg, limit):
    top = sorted(p.name for p in (ROOT / pkg).glob("*.py") if p.name != "__init__.py")
    assert len(top) <= limit, f"{pkg}/ has {len(top)} modules at its top level: {top}"


@pytest.mark.parametrize("pkg", ["kdfaces", "kdfaces.rig", "kdfaces.motion", "kdfaces.dynamics", "kdfaces.ikd",
                                 "kdfaces.bake", "kdfaces.articulated", "kdfaces.io", "kdfaces.viz", "kdfaces.shots",
                                 "kdfem", "kdfem.geometry", "kdfem.fem", "kdfem.modal", "kdfem.scenes"])
def test_public_names_import(pkg):
    import importlib

    module = importlib.import_module(pkg)
    assert module.__all__, f"{pkg} exports nothing"
    missing = [n for n in module.__all__ if not hasattr(module, n)]
    assert not missing, f"{pkg}.__all__ names that do not import: {missing}"


#: (importer prefix, imported prefix): imports that would run up the layers (the lower layer never knows the upper)
FORBIDDEN_IMPORTS = [("kdfaces.viz", "kdfaces.shots")]


@pytest.mark.parametrize("low, high", FORBIDDEN_IMPORTS, ids=[f"{a}->{b}" for a, b in FORBIDDEN_IMPORTS])
def test_imports_flow_one_way(low, high):
    graph = import_graph()

    def within(mod, prefix):
        return mod == prefix or mod.startswith(prefix + ".")

    bad = sorted(f"{m} → {t}" for m, ts in graph.items() if within(m, low) for t in ts if within(t, high))
    assert not bad, "imports up the layers: " + ", ".join(bad)
