"""The package layout: no import cycle among project modules, imports flow one way (kdfem is built on kdfaces, so no
kdfaces module imports kdfem), few modules per top level, public names import.

The import graph comes from ``ast`` (every ``import``/``from … import`` anywhere in a module, function-level ones
included, since a lazy import that closes a cycle is still a cycle in the design). An edge goes to the module that
is imported; ``from pkg import name`` goes to ``pkg.name`` when that is a module, else to ``pkg`` (its
``__init__``). Parent packages a module lives in are not edges (Python imports them first, they do not import back
through their children unless their ``__init__`` says so, which is an edge of its own). A call of
``importlib.import_module("…")`` or ``__import__("…")`` with a literal name is an import too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("kdfaces", "kdfem")


def _modules(root: Path = ROOT) -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for p in (root / pkg).rglob("*.py"):
            parts = list(p.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def _dynamic_import(node) -> str | None:
    """The literal module name of ``importlib.import_module("name")`` / ``import_module("name")`` /
    ``__import__("name")``, else None."""
    if not isinstance(node, ast.Call) or not node.args:
        return None
    f = node.func
    name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None
    arg = node.args[0]
    if name in ("import_module", "__import__") and isinstance(arg, ast.Constant) and isinstance(arg.value, str):
        return arg.value
    return None


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module → project modules it imports (the packages under ``root``)."""
    mods = _modules(root)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        package = mod if is_pkg else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            dynamic = _dynamic_import(node)
            if dynamic is not None and not dynamic.startswith("."):
                targets = [dynamic]
            elif isinstance(node, ast.Import):
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


def upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """(kdfaces module, kdfem module) for every import from kdfaces into kdfem (kdfem is built on kdfaces)."""
    return sorted((m, t) for m, targets in graph.items() if m.split(".")[0] == "kdfaces"
                  for t in targets if t.split(".")[0] == "kdfem")


def test_kdfaces_never_imports_kdfem():
    bad = upward_imports(import_graph())
    assert not bad, "kdfaces imports kdfem (kdfem is built on kdfaces): " + ", ".join(f"{a} → {b}" for a, b in bad)


@pytest.mark.parametrize("source", [
    "from kdfem import default_hat_system\n",
    "def f():\n    from kdfem.fem import HatSystem\n",  # a lazy import inside a function
    "import kdfem.scenes.offset_grid\n",
    "import importlib\nm = importlib.import_module('kdfem.demo')\n",
])
def test_the_layering_check_sees_an_upward_import(tmp_path, source):
    """The check itself: a kdfaces module that imports kdfem, in any of these forms, is found."""
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    for mod in ("demo", "fem", "scenes/offset_grid"):
        path = tmp_path / "kdfem" / f"{mod}.py"
        path.parent.mkdir(parents=True, exist_ok=True)
        (path.parent / "__init__.py").touch()
        path.write_text("")
    (tmp_path / "kdfaces" / "shots.py").write_text(source)
    (tmp_path / "kdfem" / "demo.py").write_text("from kdfaces import shots\n")  # downward: allowed
    bad = upward_imports(import_graph(tmp_path))
    assert len(bad) == 1 and bad[0][0] == "kdfaces.shots" and bad[0][1].startswith("kdfem"), bad


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
