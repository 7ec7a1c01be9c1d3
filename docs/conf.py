"""Sphinx configuration of ringlight's documentation.

Build it with ``sphinx-build -W --keep-going docs docs/_build/html`` (the ``docs`` extra installs
what it needs). The build runs ``examples/`` (sphinx-gallery) and renders the explorer window of
every bundled sample with ``ringlight --screenshot`` (``_ext/screenshots.py``), offscreen.
"""

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))

# The window renders offscreen, and the samples the build writes stay in the build's own cache
# folder (a clean build is the same on every machine; the user's cache is left alone).
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("RINGLIGHT_CACHE_DIR", str(DOCS / "_build" / "ringlight-cache"))

project = "ringlight"
author = "the ringlight authors"
copyright = "2026, the ringlight authors"
release = "0.1.0"

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "screenshots",
    "ringlight_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.zip", "auto_examples/*.json", "auto_examples/*.md5"]
templates_path = ["_templates"]
myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3

autosummary_generate = True
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"  # numpydoc's Parameters say the types; signatures stay short
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

sphinx_gallery_conf = {
    "examples_dirs": str(DOCS.parent / "examples"),
    "gallery_dirs": "auto_examples",
    # Every example runs at build time (plugin_skeleton only checks its classes); their run
    # times are in the gallery's "Computation times" page.
    "filename_pattern": r"/.*\.py$",
    # Names, not objects, so that Sphinx can cache the configuration (_ext/ringlight_gallery.py).
    "image_scrapers": ("ringlight_gallery.scrape_example_files",),
    "reset_modules": ("ringlight_gallery.reset_example_folder",),
    "reset_modules_order": "before",
    "download_all_examples": False,
    "line_numbers": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "min_reported_time": 0,
    "show_memory": False,
    "plot_gallery": "True",
}

html_theme = "alabaster"
html_static_path = []
html_title = "ringlight"
html_theme_options = {"description": "Variable ring light imaging", "page_width": "1100px",
                      "sidebar_width": "240px"}
