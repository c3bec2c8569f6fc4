"""``.. kd-defaults::`` — a table of every constant in :mod:`kdfaces.defaults` (its ``__all__``): name, value and
the ``#:`` comment above it (meaning and unit). A comment covers the names assigned right after it without one of
their own. Rendered from the module at build time, so the Defaults page cannot go stale."""

from __future__ import annotations

import ast
import importlib
import inspect

from docutils import nodes
from sphinx.util.docutils import SphinxDirective


def default_entries(module: str = "kdfaces.defaults") -> list[tuple[str, object, str]]:
    """(name, value, comment) of each data name of ``module.__all__``, in ``__all__`` order."""
    mod = importlib.import_module(module)
    lines = inspect.getsource(mod).splitlines()
    docs, comment, last_end = {}, "", 0
    for node in ast.parse("\n".join(lines)).body:
        if not isinstance(node, ast.Assign | ast.AnnAssign):
            comment, last_end = "", node.end_lineno
            continue
        above, i = [], node.lineno - 2
        while i >= last_end and lines[i].lstrip().startswith("#:"):
            above.insert(0, lines[i].lstrip()[2:].strip())
            i -= 1
        if above:
            comment = " ".join(above)
        elif node.lineno - 1 > last_end and any(not lines[j].strip() for j in range(last_end, node.lineno - 1)):
            comment = ""  # a blank line ends a comment's group
        targets = node.targets if isinstance(node, ast.Assign) else [node.target]
        for t in targets:
            for n in ast.walk(t):
                if isinstance(n, ast.Name):
                    docs[n.id] = comment
        last_end = node.end_lineno
    return [(n, getattr(mod, n), docs.get(n, "")) for n in mod.__all__ if not callable(getattr(mod, n))]


class DefaultsTable(SphinxDirective):
    """The table of :func:`default_entries`."""

    has_content = False

    def run(self):
        table = nodes.table()
        group = nodes.tgroup(cols=3)
        table += group
        for width in (22, 14, 64):
            group += nodes.colspec(colwidth=width)
        head = nodes.thead()
        body = nodes.tbody()
        group += head
        group += body

        def row(cells, parent):
            r = nodes.row()
            for c in cells:
                entry = nodes.entry()
                entry += c
                r += entry
            parent += r

        row([nodes.paragraph(text=t) for t in ("name", "value", "meaning and unit")], head)
        for name, value, doc in default_entries():
            target = nodes.target("", "", ids=[f"default-{name.lower()}"])
            cell = nodes.paragraph()
            cell += target
            cell += nodes.literal(text=name)
            parsed, _ = self.state.inline_text(doc, self.lineno)
            text = nodes.paragraph()
            text += parsed
            row([cell, nodes.paragraph("", "", nodes.literal(text=repr(value))), text], body)
        return [table]


def setup(app):
    app.add_directive("kd-defaults", DefaultsTable)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
