"""The README's Python snippets run as written (in a scratch folder), and its commands are the documented verbs."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_readme_starts_with_the_two_commands():
    first = re.search(r"```sh\n(.*?)```", README.read_text(), flags=re.S).group(1).split("\n")
    assert [line for line in first if line.strip()] == ["make demo", "make test"]


@pytest.mark.parametrize("index", range(len(python_blocks(README.read_text()))))
def test_readme_snippet_runs(index, tmp_path):
    code = python_blocks(README.read_text())[index]
    cwd = os.getcwd()
    os.chdir(tmp_path)  # snippets that write files write them here
    try:
        exec(compile(code, f"README.md python block {index}", "exec"), {"__name__": "__readme__"})
    finally:
        os.chdir(cwd)


def test_readme_verbs_exist():
    from kdfaces.cli import build_parser as faces_parser
    from kdfem.cli import build_parser as fem_parser

    text = README.read_text()
    for prog, parser in (("kdfaces", faces_parser()), ("kdfem", fem_parser())):
        verbs = set(parser._subparsers._group_actions[0].choices)
        used = set(re.findall(rf"`{prog} ([a-z-]+)", text))
        assert used and used <= verbs, f"README names {prog} verbs {sorted(used - verbs)} that do not exist"
