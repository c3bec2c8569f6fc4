"""Looking at results: off-screen renders and filmstrips, deviation heat maps, constraint markers, movies, the
scrubbing viewer, and the KD (Fig. 10) and IKD (Fig. 8, 9) report figures. pyvista and matplotlib are imported
only when a figure is drawn."""

from .figures import FaceRenderer, filmstrip, image_grid, save_figure
from .heatmap import deviation_mm, heatmap_strip
from .ikd_report import convergence_plot, offset_grid, offset_grid_plot
from .kd_report import KDErrorReport, kd_error_report, write_kd_report
from .markers import constraint_markers, constraint_panel
from .movie import render_movie, write_movie
from .viewer import ShotViewer

__all__ = [
    "FaceRenderer", "filmstrip", "image_grid", "save_figure", "deviation_mm", "heatmap_strip", "convergence_plot",
    "offset_grid", "offset_grid_plot", "KDErrorReport", "kd_error_report", "write_kd_report", "constraint_markers",
    "constraint_panel", "render_movie", "write_movie", "ShotViewer",
]
