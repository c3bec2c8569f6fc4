"""Renamed keyword arguments and attributes keep working for one release, with a :class:`DeprecationWarning`."""

from __future__ import annotations

import functools
import warnings

from .errors import KDInputError

__all__ = ["renamed_kwargs", "renamed_attribute", "warn_renamed"]


def warn_renamed(where: str, old: str, new: str, *, stacklevel: int = 3) -> None:
    """Warn that ``old`` is now called ``new`` in ``where``."""
    warnings.warn(f"{where}: {old!r} is renamed {new!r}; the old name will be removed in the next release",
                  DeprecationWarning, stacklevel=stacklevel)


def renamed_kwargs(**old_to_new: str):
    """Decorator: accept each old keyword name, warn, and pass it on under its new name.

    >>> @renamed_kwargs(h="step_s")
    ... def f(*, step_s=1.0):
    ...     return step_s
    """

    def decorate(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            for old, new in old_to_new.items():
                if old in kwargs:
                    if new in kwargs:
                        raise KDInputError(f"{fn.__qualname__}: got both {old!r} (its old name) and {new!r}")
                    warn_renamed(fn.__qualname__, old, new)
                    kwargs[new] = kwargs.pop(old)
            return fn(*args, **kwargs)

        wrapper.renamed_kwargs = dict(old_to_new)
        return wrapper

    return decorate


class renamed_attribute:
    """A class attribute standing for the old name of attribute ``new``: reading it warns (naming the instance's
    class) and returns ``new``'s value.

    >>> class Material:
    ...     youngs = renamed_attribute("youngs_pa")
    """

    def __init__(self, new: str):
        self.new = new
        self.__doc__ = f"Deprecated name of :attr:`{new}`."

    def __set_name__(self, owner, name: str) -> None:
        self.old = name

    def __get__(self, obj, objtype=None):
        if obj is None:
            return self
        warn_renamed(type(obj).__name__, self.old, self.new)
        return getattr(obj, self.new)
