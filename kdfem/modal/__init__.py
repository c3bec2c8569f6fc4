"""Modal analysis of an attached object and its KD window (paper §5.3): modes, Γ activation, the window,
brute-force verification and the modal window report."""

from .adaptive import modal_adaptive_windows
from .analysis import (
    ModalAnalysis,
    ModalBasis,
    ModalWindow,
    analyse_model,
    gamma_matrix,
    modal_activation,
    modal_basis,
    modal_window,
)
from .window import WindowRun, window_report

__all__ = ["ModalAnalysis", "ModalBasis", "ModalWindow", "analyse_model", "gamma_matrix", "modal_activation",
           "modal_basis", "modal_window", "WindowRun", "window_report", "modal_adaptive_windows"]
