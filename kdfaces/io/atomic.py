"""Atomic file writes: a file appears complete under its name, or not at all."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import KDInputError

__all__ = ["atomic_path", "write_bytes_atomic"]


class atomic_path:
    """Context manager yielding a temporary path next to ``path``; renamed onto ``path`` only on success."""

    def __init__(self, path, suffix: str | None = None):
        self.path = Path(path)
        self.suffix = suffix if suffix is not None else self.path.suffix

    def __enter__(self) -> Path:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.suffix, dir=self.path.parent)
        except OSError as e:
            raise KDInputError(f"{self.path}: cannot write here ({e.strerror})") from None
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return False


def write_bytes_atomic(path, payload: bytes) -> Path:
    """Write ``payload`` to ``path`` via a temporary file; any failure leaves no file and raises one error."""
    p = Path(path)
    with atomic_path(p) as tmp:
        try:
            tmp.write_bytes(payload)
        except OSError as e:
            raise KDInputError(f"{p}: write failed ({e.strerror or e})") from None
    return p
