"""The user guide's pages (docs/*.md): every Python block runs as written, each in a scratch folder of its own,
every page is in the docs' toctree, and the commands they name are the documented verbs and flags.

A block whose first line is ``# illustrative only`` is shown, not run; keep such blocks rare (none today)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from test_readme import ILLUSTRATIVE, run_snippet

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGES = sorted(p for p in DOCS.glob("*.md") if p.name != "readme.md")  # readme.md includes README.md


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


BLOCKS = [(page.name, i, code) for page in PAGES for i, code in enumerate(python_blocks(page.read_text()))]


def test_the_guide_has_its_pages():
    names = {p.stem for p in PAGES}
    assert {"shots", "rigs", "windows", "ikd", "hat", "skeletal", "bake", "exports", "viewer"} <= names
    toctree = (DOCS / "index.rst").read_text()
    for name in names:
        assert re.search(rf"^   {re.escape(name)}$", toctree, flags=re.M), f"docs/{name}.md is not in index.rst"


def test_illustrative_blocks_are_rare():
    shown = [(page, i) for page, i, code in BLOCKS if code.startswith(ILLUSTRATIVE)]
    assert len(shown) <= 2, f"blocks shown but not run: {shown}"


@pytest.mark.parametrize("page, index, code", [b for b in BLOCKS if not b[2].startswith(ILLUSTRATIVE)],
                         ids=[f"{p}-{i}" for p, i, c in BLOCKS if not c.startswith(ILLUSTRATIVE)])
def test_page_snippet_runs(page, index, code, tmp_path):
    run_snippet(code, f"docs/{page} python block {index}", tmp_path)


def test_pages_name_existing_verbs():
    from kdfaces.cli import build_parser as faces_parser
    from kdfem.cli import build_parser as fem_parser

    text = "\n".join(p.read_text() for p in PAGES)
    for prog, parser in (("kdfaces", faces_parser()), ("kdfem", fem_parser())):
        verbs = parser._subparsers._group_actions[0].choices
        used = set(re.findall(rf"`{prog} ([a-z-]+)", text))
        unknown = sorted(used - set(verbs))
        assert used and not unknown, f"the guide names {prog} verbs {unknown} that do not exist"
        for verb, flags in re.findall(rf"`{prog} ([a-z-]+)([^`]*)`", text):
            known = {s for a in verbs[verb]._actions for s in a.option_strings}
            named = set(re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", flags))
            assert named <= known, f"`{prog} {verb}` in the guide names flags {sorted(named - known)} it does not have"
