"""Sphinx configuration for sklearn_psf."""

import os
import warnings

# The examples solve many small linear systems: one BLAS/OpenMP thread per process avoids
# oversubscribing the CI's few cores (a multi-threaded BLAS on a busy 2-core machine made the
# Kriging grid search of an example ~10x slower). Set before numpy is imported.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sklearn_psf  # noqa: E402

project = "sklearn_psf"
author = "sklearn_psf developers"
copyright = "2024, sklearn_psf developers"
release = sklearn_psf.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.intersphinx",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
]

autosummary_generate = True
autodoc_default_options = {"members": True, "inherited-members": False}
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks = set()  # validation off (the docstrings are checked by doctests)
templates_path = ["_templates"]
exclude_patterns = [
    "_build",
    "auto_examples/*.ipynb",
    "auto_examples/*.py",
    "auto_examples/*.zip",
    "auto_examples/*.md5",
    "auto_examples/*.codeobj.json",
]
html_theme = "alabaster"
html_theme_options = {"page_width": "1100px", "sidebar_width": "230px"}
nitpicky = False
default_role = "literal"

# Examples run at documentation build time, at the small size CI uses.
os.environ.setdefault("SKLEARN_PSF_EXAMPLE_SIZE", "small")
os.environ.setdefault("MPLBACKEND", "agg")
# Examples must not emit warnings into the build log: matplotlib's non-GUI backend notice is
# the only expected one.
warnings.filterwarnings("ignore", message="Matplotlib is currently using agg")
warnings.filterwarnings("ignore", message="FigureCanvasAgg is non-interactive")

sphinx_gallery_conf = {
    "examples_dirs": "../examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "doc_module": ("sklearn_psf",),
    "backreferences_dir": os.path.join("gen_modules", "backreferences"),
    "reference_url": {"sklearn_psf": None},
    "plot_gallery": "True",
    "show_memory": False,
    "min_reported_time": 1,
}

intersphinx_mapping = {}


# --- docstring rendering --------------------------------------------------------------------
# The docstrings are written for the terminal (``help()``) as much as for the web: they use
# |x| for absolute values and name fitted attributes like ``n_components_``. In reST, |x| is a
# substitution reference and a trailing underscore a hyperlink reference. After numpydoc has
# turned a docstring into reST, escape those characters outside literals, roles and math.
import re  # noqa: E402

_PROTECTED = re.compile(r"(``.+?``|:[\w:.+-]+:`[^`]*`|`[^`]*`_{0,2})")
_TRAILING_UNDERSCORE = re.compile(r"(?<=[\w)\]])_(?=[\s,;:.)\]]|$)")


def _escape_prose(text):
    parts = _PROTECTED.split(text)
    for i in range(0, len(parts), 2):  # even indices: outside literals and roles
        parts[i] = _TRAILING_UNDERSCORE.sub(r"\\_", parts[i].replace("|", r"\|"))
    return "".join(parts)


def _escape_docstring(app, what, name, obj, options, lines):
    block_indent = None  # indentation of the line opening a literal block, math or doctest
    for i, line in enumerate(lines):
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if block_indent is not None:
            if not stripped:
                if block_indent == "doctest":
                    block_indent = None
                continue
            if block_indent == "doctest" or indent > block_indent:
                continue
            block_indent = None
        if stripped.startswith(">>>"):
            block_indent = "doctest"
            continue
        if stripped.startswith(".. "):
            if stripped.startswith((".. math::", ".. code", ".. plot")):
                block_indent = indent
            continue
        lines[i] = _escape_prose(line)
        if line.rstrip().endswith("::"):
            block_indent = indent


def _skip_member(app, what, name, obj, skip, options):
    # scikit-learn's metadata-routing helpers are generated on every estimator class; their
    # docstrings point into scikit-learn's own documentation.
    if re.fullmatch(r"set_\w+_request", name) or name == "get_metadata_routing":
        return True
    return None


def _write_cli_help(app):
    """The --help text of every ``sklearn-psf`` subcommand, for cli.rst (always current)."""
    import argparse

    from sklearn_psf.cli import build_parser

    folder = os.path.join(app.srcdir, "generated")
    os.makedirs(folder, exist_ok=True)
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "92"
    try:
        parser = build_parser()
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    with open(os.path.join(folder, f"cli_{name}.txt"), "w") as f:
                        f.write(sub.format_help())
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns


def setup(app):
    app.connect("builder-inited", _write_cli_help)
    app.connect("autodoc-process-docstring", _escape_docstring, priority=600)  # after numpydoc
    app.connect("autodoc-skip-member", _skip_member)
