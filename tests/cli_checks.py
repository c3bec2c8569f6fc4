"""What the bad-input tests share: run a command-line entry point in process and check that it ended as every bad
input must — exit status 2, exactly one line on stderr naming the file (or field, or argument) and what was
expected, no traceback, no output folder left behind, and quickly."""

from __future__ import annotations

import time
from pathlib import Path

from kdfaces.cli import main as kdfaces_main


def run_cli(argv, capsys, fn=kdfaces_main):
    """(exit status, stderr, seconds) of ``fn(argv)`` (default ``kdfaces``), stderr read from ``capsys``."""
    t0 = time.perf_counter()
    rc = fn(argv)
    seconds = time.perf_counter() - t0
    return rc, capsys.readouterr().err, seconds


def check_one_line(rc, err, seconds, out: Path | None, *, names: str, field: str, limit_s: float = 30) -> None:
    """Exit 2, one non-empty stderr line holding ``names`` and ``field``, no traceback, nothing at or beside
    ``out`` (None: no output folder to check), within ``limit_s``."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc == 2, err
    assert len(lines) == 1, lines
    assert "Traceback" not in err
    assert names in lines[0], (names, lines[0])
    assert field in lines[0], (field, lines[0])
    if out is not None:
        assert not out.exists() and not list(out.parent.glob(f".{out.name}.*")), "an output folder was left"
    assert seconds < limit_s, seconds
