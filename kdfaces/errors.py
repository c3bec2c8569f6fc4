"""The exceptions users see: one base class, :class:`KDError`, with a subclass per kind of failure.

- :class:`KDInputError` — bad input (a file, a field, an argument): names it and says what was expected;
- :class:`KDNumericalError` — a computation failed (:class:`SimulationBlowUpError`: a simulation ran away);
- :class:`KDIOError` — a file could not be read or written for reasons outside the input's content.

``except KDError`` catches everything the toolkit raises on purpose; the command-line tools turn it into one line
on stderr and exit status 2.
"""

from __future__ import annotations

__all__ = ["KDError", "KDInputError", "KDNumericalError", "SimulationBlowUpError", "KDIOError", "check_finite",
           "check_count"]


class KDError(Exception):
    """Base class of every error the toolkit raises on purpose."""


class KDInputError(KDError, ValueError):
    """Bad user input: names the file or field and what was expected."""


class KDNumericalError(KDError, RuntimeError):
    """A numerical computation failed (no convergence, a singular system, a simulation that ran away)."""


class SimulationBlowUpError(KDNumericalError):
    """A simulation produced NaN/inf or ran away; names the system, frame and quantity."""


class KDIOError(KDError, OSError):
    """A file could not be read or written (permissions, a full disk, a missing folder)."""


def check_finite(array, what: str) -> None:
    """Raise :class:`KDInputError` naming ``what`` if ``array`` holds NaN or inf."""
    import numpy as np  # here, not at the top: the command-line tools import this module before taking over Ctrl-C

    a = np.asarray(array)
    if a.dtype.kind in "fc" and not np.isfinite(a).all():
        bad = np.argwhere(~np.isfinite(a))[0]
        where = tuple(int(i) for i in bad)
        raise KDInputError(f"{what}: expected finite numbers, found {a[where]} at index {where}")


def check_count(value, what: str, *, minimum: int = 1) -> int:
    """``value`` as an int when it is a whole number ≥ ``minimum`` (a count: threads, modes, a stride), else
    :class:`KDInputError` naming ``what``. A bool, a fraction, NaN or a string is refused, never rounded."""
    import numbers

    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if not ok and isinstance(value, numbers.Real) and not isinstance(value, bool):
        ok = float(value).is_integer()
    if not ok or int(value) < minimum:
        raise KDInputError(f"{what}: expected a whole number ≥ {minimum}, got {value!r}")
    return int(value)
