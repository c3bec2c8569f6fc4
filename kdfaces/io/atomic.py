"""Atomic outputs: a file appears complete under its name, or not at all; a run's output folder appears with every
file in it, or not at all.

Files are created with the permissions of an ordinary ``open`` (0666 less the process umask — 0644 under the usual
022), not the 0600 of a raw temporary file.
"""

from __future__ import annotations

import glob
import os
import shutil
import tempfile
from pathlib import Path

from ..errors import KDInputError, KDIOError

__all__ = ["atomic_path", "write_bytes_atomic", "OutputFolder", "check_output_folder", "remove_stale_siblings",
           "tagged_sibling_prefix", "current_umask", "MANIFEST_NAME"]


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


#: The file that marks a folder as a finished output of the toolkit and lists what it wrote (paths relative to the
#: folder, "/"-separated). Only such a folder is ever replaced by a later run, and only while it holds nothing else.
MANIFEST_NAME = ".kdfaces-output.json"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def tagged_sibling_prefix(path: Path, kind: str) -> str:
    """Name prefix of a temporary sibling of ``path`` of ``kind`` (``partial``, ``old``, ...) made by this process:
    ``.NAME.KIND-PID-``. The process id lets a later run tell a killed run's leftovers from a live run's."""
    return f".{path.name}.{kind}-{os.getpid()}-"


def remove_stale_siblings(path: Path, kinds=("partial", "old")) -> list[Path]:
    """Remove the temporary siblings of ``path`` (see :func:`tagged_sibling_prefix`) left by processes that no
    longer run (a SIGKILL, a power cut); a live run's are kept. Returns what was removed."""
    removed = []
    parent = path.parent
    if not parent.is_dir():
        return removed
    for kind in kinds:
        for p in parent.glob(f".{glob.escape(path.name)}.{kind}-*-*"):
            pid = p.name[len(f".{path.name}.{kind}-"):].split("-", 1)[0]
            if pid.isdigit() and not _pid_alive(int(pid)) and p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
                removed.append(p)
    return removed


def _files_under(folder: Path) -> list[str]:
    """Every file and link under ``folder``, relative, "/"-separated, sorted (folders themselves are not listed)."""
    out = []
    for root, dirs, files in os.walk(folder):
        rel = Path(root).relative_to(folder)
        for name in files + [d for d in dirs if (Path(root) / d).is_symlink()]:
            out.append((rel / name).as_posix())
    return sorted(out)


def check_output_folder(out) -> Path:
    """``out`` as an absolute path when a run may write its output folder there, else :class:`KDInputError`
    saying why and what to give instead. Allowed: a path that does not exist yet, an empty folder, or a folder an
    earlier run wrote (it holds :data:`MANIFEST_NAME`) that still holds only what that run wrote. Refused, so that
    no run ever deletes what it did not write: a file, a link, the working folder or a folder above it, and any
    other folder (a user's)."""
    out = Path(out)
    final = Path(os.path.abspath(out))
    if out.is_symlink():
        raise KDInputError(f"{out}: is a symbolic link; expected a new output folder (a link is never replaced)")
    if final.exists() and not final.is_dir():
        raise KDInputError(f"{out}: exists and is not a folder; expected a new output folder (the file is kept)")
    cwd = Path(os.path.abspath(os.getcwd()))
    if final == cwd or final in cwd.parents:
        raise KDInputError(f"{out}: is the working folder{'' if final == cwd else ' or holds it'}; expected a new "
                           f"output folder, such as {Path(out) / 'kd-out'}")
    if not final.is_dir():
        return final
    try:
        present = _files_under(final)
    except OSError as e:
        raise KDIOError(f"{out}: cannot read the existing folder ({e.strerror})") from None
    if not present and not any(final.iterdir()):
        return final
    written = _manifest(final)
    if written is None:
        first = present[0] if present else next(iter(sorted(p.name for p in final.iterdir())), "")
        raise KDInputError(f"{out}: is an existing folder that this toolkit did not write (it holds {first!r}); "
                           "expected a new or empty output folder, or an earlier run's (nothing in it is changed)")
    extra = [p for p in present if p != MANIFEST_NAME and p not in written]
    if extra:
        raise KDInputError(f"{out}: an earlier run's output folder that now also holds {extra[0]!r}"
                           f"{f' and {len(extra) - 1} more' if len(extra) > 1 else ''}, which that run did not "
                           "write; move it out or give another --out (nothing in it is changed)")
    return final


def _manifest(folder: Path) -> set[str] | None:
    """The files an earlier run wrote into ``folder`` (from its :data:`MANIFEST_NAME`), or None if it has none."""
    import json

    p = folder / MANIFEST_NAME
    if not p.is_file() or p.is_symlink():
        return None
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
        files = doc["files"]
        if doc.get("written_by") != "kdfaces" or not isinstance(files, list):
            return None
        return {str(f) for f in files}
    except (OSError, ValueError, KeyError, TypeError):
        return None


class OutputFolder:
    """A run's output folder, all or nothing, and never in place of anything the toolkit did not write.

    ``with OutputFolder(out) as tmp:`` checks first (before any computation) that ``out`` may be written
    (:func:`check_output_folder`: a new path, an empty folder, or an earlier run's output folder holding only what
    that run wrote) and that it can be created; then everything is written into ``tmp``, a hidden sibling of
    ``out``. On success the sibling gets a manifest of its files (:data:`MANIFEST_NAME`) and is renamed into place
    (replacing the earlier run's folder, checked again just before); on an exception or an interrupt it is removed.
    Readers therefore see the complete set of outputs or none. Siblings left by a killed run are removed when the
    next run on the same ``out`` starts.
    """

    def __init__(self, out):
        self.given = Path(out)  # as the caller wrote it (what publish returns)
        self.final = Path(out)
        self.tmp: Path | None = None
        self.created: list[Path] = []  # parent folders this run made (removed again, if empty, when abandoned)

    def __enter__(self) -> Path:
        out = self.given
        self.final = check_output_folder(out)
        try:
            missing = [p for p in (self.final.parent, *self.final.parent.parents) if not p.exists()]
            self.final.parent.mkdir(parents=True, exist_ok=True)
            self.created = missing  # deepest first
        except OSError as e:
            raise KDIOError(f"{out}: cannot create the output folder ({e.strerror})") from None
        if not os.access(self.final.parent, os.W_OK | os.X_OK) or (
                self.final.exists() and not os.access(self.final, os.W_OK)):
            raise KDIOError(f"{out}: the output folder is not writable")
        remove_stale_siblings(self.final)
        try:
            self.tmp = Path(tempfile.mkdtemp(prefix=tagged_sibling_prefix(self.final, "partial"),
                                             dir=self.final.parent))
        except OSError as e:
            raise KDIOError(f"{out}: cannot create the output folder ({e.strerror})") from None
        os.chmod(self.tmp, 0o777 & ~current_umask())
        return self.tmp

    def publish(self) -> Path:
        """Write the manifest, then rename the finished temporary folder onto ``out`` (an earlier run's folder there
        is replaced, after :func:`check_output_folder` has passed once more)."""
        import json

        files = [p for p in _files_under(self.tmp) if p != MANIFEST_NAME]
        write_bytes_atomic(self.tmp / MANIFEST_NAME, (json.dumps(
            {"written_by": "kdfaces", "files": files}, indent=1) + "\n").encode())
        check_output_folder(self.final)
        old = None
        if self.final.exists():
            old = Path(tempfile.mkdtemp(prefix=tagged_sibling_prefix(self.final, "old"), dir=self.final.parent))
            os.rmdir(old)
            os.replace(self.final, old)
        os.replace(self.tmp, self.final)
        self.tmp = None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.given

    def abandon(self) -> None:
        """Remove the temporary folder and everything in it, and the parent folders this run created for it
        (``kd-out/`` of a default ``--out``) while they are empty: a failed run leaves nothing behind."""
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            self.tmp = None
        for p in self.created:
            try:
                p.rmdir()  # only an empty folder; one that something else wrote into meanwhile stays
            except OSError:
                break
        self.created = []

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.publish()
        else:
            self.abandon()
        return False
