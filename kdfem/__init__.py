"""kdfem: passive deformable objects (tetrahedral FEM) driven by an animated head, and their KD windows.

- :mod:`kdfem.geometry` — the hat surface, tetrahedralisation, embedding;
- :mod:`kdfem.fem` — materials, Warp kernels, implicit Euler, attachment, the hat's KD system;
- :mod:`kdfem.modal` — modes, Γ, the modal window and its report.

Its names are imported on first use (PEP 562), as in :mod:`kdfaces`, so ``import kdfem.cli`` starts fast and the
``kdfem`` command takes over Ctrl-C before any heavy library loads.
"""

from __future__ import annotations

from kdfaces import lazy_exports

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


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, __all__)
