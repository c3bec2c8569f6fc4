"""kdfem: passive deformable objects (tetrahedral FEM) driven by an animated head, and their KD windows.

- :mod:`kdfem.geometry` — the hat surface, tetrahedralisation, embedding;
- :mod:`kdfem.fem` — materials, Warp kernels, implicit Euler, attachment, the hat's KD system;
- :mod:`kdfem.modal` — modes, Γ, the modal window and its report.

Its names are imported on first use (PEP 562), as in :mod:`kdfaces`, so ``import kdfem.cli`` starts fast and the
``kdfem`` command takes over Ctrl-C before any heavy library loads.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "run_hat_demo": "demo",
    "FEMModel": "fem",
    "HatSystem": "fem",
    "Material": "fem",
    "default_hat_system": "fem",
    "TetMesh": "geometry",
    "christmas_hat": "geometry",
    "tetrahedralize": "geometry",
    "analyse_model": "modal",
    "window_report": "modal",
}

__all__ = ["run_hat_demo", "FEMModel", "HatSystem", "Material", "default_hat_system", "TetMesh", "christmas_hat",
           "tetrahedralize", "analyse_model", "window_report"]


def __getattr__(name: str):
    if name == "__version__":  # from the installed package's metadata (kdfaces and kdfem are one distribution)
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("kdfaces")
        except PackageNotFoundError:  # pragma: no cover - a source tree that was never installed
            value = "0+unknown"
        globals()["__version__"] = value
        return value
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'kdfem' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    """The public names only (``__all__`` and ``__version__``), not the module's own imports."""
    return sorted([*__all__, "__version__"])
