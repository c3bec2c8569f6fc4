"""The one exception type users see for bad input and failed simulations."""

from __future__ import annotations

__all__ = ["KDInputError", "SimulationBlowUpError", "check_finite"]


class KDInputError(ValueError):
    """Bad user input: names the file or field and what was expected."""


class SimulationBlowUpError(RuntimeError):
    """A simulation produced NaN/inf or ran away; names the system, frame and quantity."""


def check_finite(array, what: str) -> None:
    """Raise :class:`KDInputError` naming ``what`` if ``array`` holds NaN or inf."""
    import numpy as np

    a = np.asarray(array)
    if a.dtype.kind in "fc" and not np.isfinite(a).all():
        bad = np.argwhere(~np.isfinite(a))[0]
        where = tuple(int(i) for i in bad)
        raise KDInputError(f"{what}: expected finite numbers, found {a[where]} at index {where}")
