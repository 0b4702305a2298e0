"""Sphinx configuration of the napari-meris-ortho documentation.

Build: ``bash scripts/build_docs.sh`` (installs the ``docs`` extra, builds with warnings as
errors, checks the CLI page). The getting-started page is executed at build time (myst-nb);
the simulated scene it uses is cached under ``docs/_build/cache``.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import napari_meris_ortho

HERE = Path(__file__).resolve().parent
# the executed pages simulate their sample into the build directory (self-contained builds;
# the kernel that runs them inherits this environment)
os.environ["MERIS_ORTHO_CACHE"] = str(HERE / "_build" / "cache")

project = "napari-meris-ortho"
author = "napari-meris-ortho contributors"
copyright = "napari-meris-ortho contributors"
version = release = napari_meris_ortho.__version__

extensions = [
    "myst_nb",  # Markdown pages (myst-parser) and executed text notebooks
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinxarg.ext",  # the CLI reference, generated from the argparse parser
    "sphinx_copybutton",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "**.ipynb_checkpoints"]
# option names and JSON stay as typed: "--dem", not an en dash; straight quotes
smartquotes = False

# --------------------------------------------------------------------------- MyST
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# --------------------------------------------------------------------------- myst-nb
nb_execution_mode = "cache"  # re-run a page when its code changes (cache in _build)
nb_execution_cache_path = str(HERE / "_build" / ".jupyter_cache")
nb_execution_timeout = 600
nb_execution_raise_on_error = True  # a failing cell fails the build
nb_execution_show_tb = True
nb_merge_streams = True

# --------------------------------------------------------------------------- autodoc
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
# the docstrings are prose with reStructuredText literals, no NumPy or Google sections: no
# napoleon (it would read the "text: text" first line of a property's docstring as a type)
add_module_names = False

# nitpicky: every reference resolves, except to the classes of other projects (the site builds
# offline, without intersphinx inventories)
nitpick_ignore_regex = [
    ("py:(class|obj|data|exc|func)",
     r"(os|pathlib|enum|collections\.abc|typing|numpy|np|pyproj|affine|xarray|dask)\..*"),
    ("py:class", "Path"),  # pathlib.Path named in a string annotation
]


# --------------------------------------------------------------------------- HTML
html_theme = "pydata_sphinx_theme"
html_title = "napari-meris-ortho"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_show_sourcelink = False
html_sidebars = {"index": [], "changelog": []}


# --------------------------------------------------------------------------- hooks


def _no_generated_signature(app, what, name, obj, options, signature, return_annotation):
    """A dataclass or a protocol is shown without its generated constructor: the dataclasses
    of the API are results that the functions return (or built by their ``parse``/``from_*``
    class methods; their fields are listed as attributes), a protocol is never built."""
    if what == "class" and (dataclasses.is_dataclass(obj) or getattr(obj, "_is_protocol", False)):
        return "", None
    return None


def _short_reference(app, env, node, contnode):
    """Resolve a Python reference by its last name (``synthesize``, ``OutputGrid``: a docstring
    or a signature naming an object of another module of the package) when exactly one
    documented object has that name."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip(".~")
    domain = env.get_domain("py")
    found = [name for name in domain.objects
             if name == target or name.endswith("." + target)]
    if len(found) != 1:
        return None
    from sphinx.util.nodes import make_refnode

    entry = domain.objects[found[0]]
    return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode,
                        found[0])


def setup(app):
    app.connect("missing-reference", _short_reference)
    app.connect("autodoc-process-signature", _no_generated_signature)
