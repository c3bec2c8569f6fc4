"""Atomic outputs: a file appears complete under its name, or not at all; a run's output folder appears with every
file in it, or not at all.

Files are created with the permissions of an ordinary ``open`` (0666 less the process umask — 0644 under the usual
022), not the 0600 of a raw temporary file.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from ..errors import KDInputError, KDIOError

__all__ = ["atomic_path", "write_bytes_atomic", "OutputFolder", "current_umask"]


def current_umask() -> int:
    """The process umask (read without changing it for longer than the call)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


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
            raise KDIOError(f"{self.path}: cannot write here ({e.strerror})") from None
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                if self.tmp.exists():
                    os.chmod(self.tmp, 0o666 & ~current_umask())
                os.replace(self.tmp, self.path)
            except OSError as e:
                self.tmp.unlink(missing_ok=True)
                raise KDIOError(f"{self.path}: cannot write here ({e.strerror})") from None
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
            raise KDIOError(f"{p}: write failed ({e.strerror or e})") from None
    return p


class OutputFolder:
    """A run's output folder, all or nothing.

    ``with OutputFolder(out) as tmp:`` checks first that ``out`` can be created (before any computation), then
    everything is written into ``tmp``, a hidden sibling of ``out``; on success the sibling is renamed into place
    (replacing an earlier run's folder), on an exception or an interrupt it is removed. Readers therefore see the
    complete set of outputs or none.
    """

    def __init__(self, out):
        self.final = Path(out)
        self.tmp: Path | None = None

    def __enter__(self) -> Path:
        out = self.final
        if out.exists() and not out.is_dir():
            raise KDInputError(f"{out}: exists and is not a folder; expected an output folder")
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise KDIOError(f"{out}: cannot create the output folder ({e.strerror})") from None
        if not os.access(out.parent, os.W_OK | os.X_OK) or (out.exists() and not os.access(out, os.W_OK)):
            raise KDIOError(f"{out}: the output folder is not writable")
        try:
            self.tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
        except OSError as e:
            raise KDIOError(f"{out}: cannot create the output folder ({e.strerror})") from None
        os.chmod(self.tmp, 0o777 & ~current_umask())
        return self.tmp

    def publish(self) -> Path:
        """Rename the finished temporary folder onto ``out`` (an earlier folder there is replaced)."""
        old = None
        if self.final.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.old-", dir=self.final.parent))
            os.rmdir(old)
            os.replace(self.final, old)
        os.replace(self.tmp, self.final)
        self.tmp = None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.final

    def abandon(self) -> None:
        """Remove the temporary folder and everything in it."""
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            self.tmp = None

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.publish()
        else:
            self.abandon()
        return False
