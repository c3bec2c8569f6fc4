"""Resources: estimate memory before allocating and split work so it stays within a budget; report progress of
long stages.

The default budget is half of the memory the machine has available now (``MemAvailable``), so a bake never
competes with the rest of the machine for the other half; every entry point takes an explicit ``max_memory_bytes``
(the command line's ``--max-memory``).
"""

from __future__ import annotations

import os
import resource
import threading
from contextlib import contextmanager

from .errors import KDInputError

__all__ = ["init_warp", "available_memory_bytes", "memory_budget_bytes", "peak_rss_bytes", "format_bytes",
           "parse_bytes", "progress_bar", "single_threaded_blas", "PROGRESS_DELAY_S"]

#: A stage shows a progress bar once it has run this long [s] (short stages stay quiet); the environment variable
#: ``KDFACES_PROGRESS_DELAY_S`` overrides it (0 shows every bar).
PROGRESS_DELAY_S = float(os.environ.get("KDFACES_PROGRESS_DELAY_S", 2.0))

#: The share of the available memory a computation may plan to use by default.
BUDGET_FRACTION = 0.5


def _warp_initialised(wp) -> bool:
    for name in ("warp._src.context", "warp.context"):
        try:
            import importlib

            return importlib.import_module(name).runtime is not None
        except (ImportError, AttributeError):
            continue
    return False


def init_warp() -> None:
    """Initialise Warp the first time the toolkit needs it, quietly: its start-up banner and kernel-module load
    lines would go to stdout and corrupt a script's own output (e.g. JSON). Warp's log level is set to warnings
    for the process, which is what a quiet start means to Warp. A user who initialised Warp first (``wp.init()``
    with their own settings) keeps them: nothing is changed then. Systems call this before their first array."""
    import warp as wp

    if _warp_initialised(wp):
        return
    wp.config.log_level = wp.LOG_WARNING
    wp.init()


def available_memory_bytes() -> int:
    """Memory the machine can give now [bytes]: ``MemAvailable`` from /proc/meminfo, else physical memory."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - every supported OS has one of the two
        return 8 << 30


def memory_budget_bytes(max_memory_bytes: int | None = None) -> int:
    """``max_memory_bytes`` if given (must be positive), else half the available memory [bytes]."""
    if max_memory_bytes is None:
        return int(BUDGET_FRACTION * available_memory_bytes())
    if isinstance(max_memory_bytes, bool) or not int(max_memory_bytes) > 0:
        raise KDInputError(f"max_memory_bytes: expected a positive number of bytes, got {max_memory_bytes!r}")
    return int(max_memory_bytes)


def format_bytes(n: float) -> str:
    """``n`` bytes as a short human-readable size (1024-based: KiB, MiB, GiB, TiB)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024.0
    return f"{n:.3g} PiB"  # pragma: no cover


def parse_bytes(text: str, *, where: str = "--max-memory") -> int:
    """Bytes from ``"8G"``, ``"512M"``, ``"1.5GiB"`` or a plain number (1024-based suffixes)."""
    s = str(text).strip().lower().removesuffix("ib").removesuffix("b")
    scale = {"k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}.get(s[-1:], 1)
    if scale != 1:
        s = s[:-1]
    try:
        value = float(s) * scale
    except ValueError:
        raise KDInputError(f"{where}: expected a size such as 512M or 8G, got {text!r}") from None
    if not value > 0:
        raise KDInputError(f"{where}: expected a positive size, got {text!r}")
    return int(value)


def progress_bar(desc: str, total: int, enabled: bool):
    """A tqdm bar on stderr for a stage of ``total`` units, shown only once the stage has run
    :data:`PROGRESS_DELAY_S` seconds; a do-nothing stand-in when not ``enabled``. Use as a context manager (or call
    ``close()``) and call ``update(n)``.

    Closing a bar that was drawn always ends its line (on a terminal the bar is erased, elsewhere its last state is
    left on a line of its own), so an error printed after it, when the stage fails, starts a line of its own;
    ``set_postfix_str`` does not draw a bar before its delay.
    """
    if not enabled:
        return _NoBar()
    import sys

    tty = sys.stderr.isatty()
    return _bar_class()(total=int(total), desc=desc, delay=PROGRESS_DELAY_S, leave=not tty, dynamic_ncols=True,
                        mininterval=0.1 if tty else 5.0, file=sys.stderr)


_BAR_CLASS = []


def _bar_class():
    """tqdm with two fixes (made once, on first use: tqdm is imported only when a bar is wanted).

    tqdm's ``close()`` skips ending the line of a bar it believes was never drawn (``last_print_t`` within the
    delay), but ``refresh()`` — from ``set_postfix_str`` or tqdm's monitor thread — draws without updating it: the
    bar stayed unfinished and the error after it landed on its line. The subclass records every draw and ends the
    line of a drawn bar on close; and ``set_postfix_str`` only redraws a bar that is already shown.
    """
    if not _BAR_CLASS:
        from tqdm import tqdm

        class _Bar(tqdm):
            _drawn = False

            def display(self, *args, **kwargs):
                self._drawn = True
                return super().display(*args, **kwargs)

            def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
                super().set_postfix_str(s, refresh=refresh and self._drawn)

            def close(self):
                if not getattr(self, "disable", True) and self._drawn and hasattr(self, "last_print_t"):
                    self.last_print_t = max(self.last_print_t, self.start_t + self.delay)  # drawn: close ends it
                super().close()

        _BAR_CLASS.append(_Bar)
    return _BAR_CLASS[0]


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass

    def set_postfix_str(self, s: str) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

def peak_rss_bytes() -> int:
    """This process's peak resident memory [bytes]: ``VmHWM`` of /proc/self/status where there is one (the peak of
    this program's own address space; ``ru_maxrss`` would carry over the peak of the process that spawned a worker,
    since Linux keeps it across exec), else ``ru_maxrss``."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


_BLAS_LOCK = threading.Lock()
_BLAS_STATE = {"depth": 0, "limiter": None, "controller": None}


@contextmanager
def single_threaded_blas():
    """Hold the BLAS libraries of numpy and scipy (OpenBLAS, MKL …) to one thread inside the block, and restore
    their own settings after.

    The KD loops spread work over the cores themselves (Warp launches and SuperLU solves from worker threads, one
    process per bake worker). A multi-threaded BLAS call in between (blend shapes, skinning, the triangular solves
    inside SuperLU) leaves its threads spinning for a while after it returns, on the very cores the work needs: a
    27k-vertex face state on two threads went from 26 to 14 ms with BLAS held to one thread, and two threads of
    SuperLU solves went from 0.7× to 2× one thread. Nested and concurrent blocks share one limit (the first in sets
    it, the last out restores it); results do not depend on the BLAS thread count then, so they are the same bits
    on any machine.
    """
    with _BLAS_LOCK:
        if _BLAS_STATE["depth"] == 0:
            if _BLAS_STATE["controller"] is None:  # finds the loaded BLAS libraries once (about a millisecond)
                import scipy.linalg  # noqa: F401 - loads scipy's own OpenBLAS (SuperLU, LAPACK), so it is seen too
                from threadpoolctl import ThreadpoolController

                _BLAS_STATE["controller"] = ThreadpoolController()
            _BLAS_STATE["limiter"] = _BLAS_STATE["controller"].limit(limits=1, user_api="blas")
        _BLAS_STATE["depth"] += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS_STATE["depth"] -= 1
            if _BLAS_STATE["depth"] == 0:
                _BLAS_STATE["limiter"].restore_original_limits()
                _BLAS_STATE["limiter"] = None
