"""Sphinx configuration of the API reference, built from the numpydoc docstrings.

Build (after ``pip install -e ".[docs]"``, from the repository root)::

    sphinx-build -W -b html docs docs/_build

Only ``index.rst`` and ``api/*.rst`` are Sphinx sources; the Markdown guides beside them are read
on GitHub as they are.
"""

from importlib.metadata import version as _version

project = "iwr"
author = "iwr developers"
release = _version("iwr")
version = release

extensions = ["sphinx.ext.autodoc", "numpydoc"]
source_suffix = {".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "study", "figures", "**.md"]

autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the numpydoc sections say the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

html_theme = "alabaster"
html_static_path: list[str] = []
