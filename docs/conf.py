"""Sphinx configuration of raykernel's documentation site: `make docs` builds it into docs/_build/html.

The gallery (sphinx-gallery) runs every examples/gallery/plot_*.py at build time, so its images,
and the guide's and the newsletter page's figures taken from it, are made by the build.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")   # the gallery's figures, with no display

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(DOCS / "_ext"))

import raykernel  # noqa: E402

project = "raykernel"
author = "the raykernel developers"
release = version = raykernel.__version__
copyright = "raykernel developers"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "**.ipynb_checkpoints", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.zip", "auto_examples/*.md5", "auto_examples/*.json"]
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autosummary_generate = False
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_ivar = True      # a dataclass's Attributes section as fields: autodoc lists the members too

sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples" / "gallery"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "gallery_order.GalleryOrder",
    "image_srcset": [],
    "abort_on_example_error": True,
    "show_memory": False,
    "write_computation_times": False,   # its page loads scripts from a CDN
    # the examples run in the build's process: one numba cache, kernels compiled once
    "reset_modules": ("matplotlib",),
}

html_theme = "furo"
html_title = f"raykernel {release}"
html_static_path = ["_static"]
html_favicon = "_static/favicon.png"   # Heckbert's business-card scene, 48 pixels
html_show_sourcelink = False

# the benchmark pages hold wide tables; Sphinx must not guess a lexer for the commands' text
highlight_language = "none"
