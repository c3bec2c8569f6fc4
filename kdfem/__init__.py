"""kdfem: passive deformable objects (tetrahedral FEM) driven by an animated head, and their KD windows.

- :mod:`kdfem.geometry` — the hat surface, tetrahedralisation, embedding;
- :mod:`kdfem.fem` — materials, Warp kernels, implicit Euler, attachment, the hat's KD system;
- :mod:`kdfem.modal` — modes, Γ, the modal window and its report.
"""

from .demo import run_hat_demo
from .fem import FEMModel, HatSystem, Material, default_hat_system
from .geometry import TetMesh, christmas_hat, tetrahedralize
from .modal import analyse_model, window_report

__all__ = ["run_hat_demo", "FEMModel", "HatSystem", "Material", "default_hat_system", "TetMesh", "christmas_hat",
           "tetrahedralize", "analyse_model", "window_report"]
