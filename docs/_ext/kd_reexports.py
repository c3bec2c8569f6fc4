"""How the API pages treat the names a package re-exports in its ``__init__.py`` (``__all__``).

- ``.. reexports:: kdfaces`` — the top-level packages re-export names their subpackages already export.
  Documenting them a second time would register each class twice (autodoc gives it a canonical name) and split every
  name over two entries, so the top-level page lists its ``__all__`` as a summary table whose rows link to the
  subpackage entry (the first module in ``reexport_homes`` whose ``__all__`` holds the same object); names that no
  such module exports are documented in full right there.
- ``.. exported-data:: kdfaces.rig`` — ``automodule`` with ``:members:`` documents the classes and functions of
  ``__all__`` but drops constants (autodoc documents module data only when the module itself has a ``#:`` comment
  for it); this adds an ``autodata`` entry for each of the other constants of ``__all__``.
- A constant with no docstring of its own takes the ``#:`` comment written above its definition in the submodule
  that defines it, and an undocumented function of ``__all__`` is still listed.

Everything follows ``__all__``, so a name added to or renamed in a package shows up without editing the pages.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import sys
from pathlib import PurePath

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.pycode import ModuleAnalyzer
from sphinx.util.docutils import SphinxDirective


def home_of(name: str, obj, homes: list[str]) -> str | None:
    """The first module in ``homes`` whose ``__all__`` exports ``obj`` under ``name``."""
    for home in homes:
        mod = importlib.import_module(home)
        if name in getattr(mod, "__all__", ()) and getattr(mod, name, None) is obj:
            return home
    return None


def is_data(obj) -> bool:
    return not (inspect.isclass(obj) or callable(obj) or inspect.ismodule(obj))


def autodata(qualname: str, obj) -> list[str]:
    # a path's value is where this checkout happens to be: leave it out
    return ["", f".. autodata:: {qualname}", *(["   :no-value:"] if isinstance(obj, PurePath) else [])]


class _RstDirective(SphinxDirective):
    required_arguments = 1

    def emit(self, lines: list[str]) -> list[nodes.Node]:
        container = nodes.container()
        source = f"<{self.name} {self.arguments[0]}>"
        self.state.nested_parse(StringList(lines, source=source), self.content_offset, container)
        return container.children


class Reexports(_RstDirective):
    def run(self) -> list[nodes.Node]:
        package = self.arguments[0]
        mod = importlib.import_module(package)
        homes = [h for h in self.config.reexport_homes if h != package]
        table, own = [], []
        for name in mod.__all__:
            obj = getattr(mod, name)
            home = home_of(name, obj, homes)
            # relative to the page's current module (the automodule above), as autosummary wants it
            table.append(f"   ~{home.removeprefix(package + '.')}.{name}" if home else f"   {name}")
            if home is None:
                kind = "class" if inspect.isclass(obj) else "function" if callable(obj) else None
                own += ["", f".. auto{kind}:: {package}.{name}"] if kind else autodata(f"{package}.{name}", obj)
        return self.emit([".. autosummary::", "", *table, *own])


class ExportedData(_RstDirective):
    def run(self) -> list[nodes.Node]:
        package = self.arguments[0]
        mod = importlib.import_module(package)
        lines = []
        for name in mod.__all__:
            # a constant with a #: comment in the module itself is already documented by automodule
            if is_data(obj := getattr(mod, name)) and not attr_comment(package, name):
                lines += autodata(f"{package}.{name}", obj)
        return self.emit(lines)


def keep_exported(app, what, name, obj, skip, options):
    """Keep every name a module's ``__all__`` lists (Sphinx >= 9 asks only about those), docstring or not.

    As a guard against a documented module without ``__all__`` (where autodoc asks about every name, ``np``
    included), only names that some module of ``reexport_homes`` exports are kept this way.
    """
    if what == "module" and skip and name in exported_names(tuple(app.config.reexport_homes)):
        return False
    return None


@functools.cache
def exported_names(homes: tuple[str, ...]) -> frozenset[str]:
    return frozenset(n for home in homes for n in getattr(importlib.import_module(home), "__all__", ()))


def source_comment(app, what, name, obj, options, lines):
    """A constant takes the ``#:`` comment above its definition in a submodule of its package.

    Without a ``#:`` comment in the documented module itself, autodoc falls back on the docstring of the value's
    type (``dict``, ``tuple``, ``Material``), which says nothing about the constant: that is replaced by the comment
    in the defining module, or dropped. This runs after napoleon, which would read "text: more" as "type: text".
    """
    if what != "data":
        return
    package, _, attr = name.rpartition(".")
    if attr_comment(package, attr):
        return  # autodoc used it
    lines[:] = []
    for modname, mod in sorted(sys.modules.items()):
        if modname.startswith(package + ".") and getattr(mod, attr, None) is obj:
            if doc := attr_comment(modname, attr):
                lines[:] = [*doc, ""]
                return


def attr_comment(modname: str, attr: str) -> list[str] | None:
    try:
        return ModuleAnalyzer.for_module(modname).find_attr_docs().get(("", attr))
    except Exception:  # no source to read: no comment
        return None


def setup(app):
    app.add_config_value("reexport_homes", [], "env")
    app.add_directive("reexports", Reexports)
    app.add_directive("exported-data", ExportedData)
    app.connect("autodoc-skip-member", keep_exported)
    app.connect("autodoc-process-docstring", source_comment, priority=600)  # after napoleon
    return {"parallel_read_safe": True, "parallel_write_safe": True}
