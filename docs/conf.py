"""Sphinx configuration for the kdfaces / kdfem API reference (built with ``-W``: warnings are errors)."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the packages import from the checkout even without an editable install
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

project = "kdfaces / kdfem"
author = "kdfaces contributors"
copyright = "kdfaces contributors, Apache-2.0"
release = "0.1.0"

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "myst_parser",
    "kd_reexports",
    "kd_defaults",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build"]
root_doc = "index"

# autodoc: each package page documents the names in its __init__'s __all__ (re-exports included, since autodoc
# follows __all__); signatures stay plain and annotations go into the parameter descriptions.
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented_params"
autodoc_member_order = "bysource"
autodoc_preserve_defaults = False  # defaults render as values (threads=2), not as defaults.THREADS

autosummary_generate = False  # tables only (the top-level pages); no stub pages

# The pages that document each subpackage's __all__; the kdfaces and kdfem pages link their re-exports here.
reexport_homes = [
    "kdfaces.rig", "kdfaces.motion", "kdfaces.dynamics", "kdfaces.kd", "kdfaces.window", "kdfaces.ikd", "kdfaces.io",
    "kdfaces.viz", "kdfaces.shots", "kdfaces.errors", "kdfem.geometry", "kdfem.fem", "kdfem.modal",
]

napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_attr_annotations = True

nitpicky = False

myst_heading_anchors = 3

html_theme = "furo"
html_title = "kdfaces / kdfem"
