"""The README is the landing page: it starts with the two commands, stays short, links the user guide, its Python
snippets run as written (in a scratch folder), and its commands are the documented verbs."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_CHARS = 8000
#: A python block whose first line is this comment is shown, not run (keep them rare).
ILLUSTRATIVE = "# illustrative only"


def python_blocks(text: str) -> list[str]:
    return [b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if not b.startswith(ILLUSTRATIVE)]


def run_snippet(code: str, name: str, folder) -> None:
    """Run a documentation python block as a user would paste it into a script, in ``folder`` (a snippet that
    writes files writes them there)."""
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        exec(compile(code, name, "exec"), {"__name__": "__snippet__"})
    finally:
        os.chdir(cwd)


def test_readme_starts_with_the_two_commands():
    text = README.read_text()
    first = re.search(r"```sh\n(.*?)```", text, flags=re.S)
    assert text.index("```") == first.start(), "the first code block of the README is the sh block"
    assert [line for line in first.group(1).split("\n") if line.strip()] == ["make demo", "make test"]


def test_readme_is_a_landing_page():
    text = README.read_text()
    assert len(text) <= MAX_CHARS, f"README.md has {len(text)} characters; the guide's pages take the rest"
    assert len(python_blocks(text)) == 1 and len(python_blocks(text)[0].strip().splitlines()) <= 10


def test_readme_links_every_guide_page():
    text = README.read_text()
    linked = set(re.findall(r"\]\(docs/([a-z-]+\.md)\)", text))
    assert linked, "the README links the user guide"
    for name in linked:
        assert (ROOT / "docs" / name).is_file(), f"README links docs/{name}, which does not exist"
    pages = {p.name for p in (ROOT / "docs").glob("*.md")} - {"readme.md"}
    assert pages <= linked, f"guide pages the README does not link: {sorted(pages - linked)}"


@pytest.mark.parametrize("index", range(len(python_blocks(README.read_text()))))
def test_readme_snippet_runs(index, tmp_path):
    run_snippet(python_blocks(README.read_text())[index], f"README.md python block {index}", tmp_path)


def test_readme_verbs_exist():
    from kdfaces.cli import build_parser as faces_parser
    from kdfem.cli import build_parser as fem_parser

    text = README.read_text()
    for prog, parser in (("kdfaces", faces_parser()), ("kdfem", fem_parser())):
        verbs = set(parser._subparsers._group_actions[0].choices)
        used = set(re.findall(rf"`{prog} ([a-z-]+)", text))
        assert used and used <= verbs, f"README names {prog} verbs {sorted(used - verbs)} that do not exist"
