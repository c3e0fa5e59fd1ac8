"""Sphinx configuration for sklearn_psf."""

import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
import warnings

# The examples solve many small linear systems: one BLAS/OpenMP thread per process avoids
# oversubscribing the CI's few cores (a multi-threaded BLAS on a busy 2-core machine made the
# Kriging grid search of an example ~10x slower). Set before numpy is imported.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sklearn_psf  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "_ext"))
from apidoc import constant_doc, is_constant  # noqa: E402

project = "sklearn_psf"
author = "sklearn_psf developers"
copyright = "sklearn_psf developers"
release = sklearn_psf.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.intersphinx",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "myst_parser",  # CHANGELOG.md and CONTRIBUTING.md are included as they are
]

# Math: MathJax 3 shipped inside the ``sphinx-mathjax-offline`` wheel is copied into the site,
# so formulas render without network (offline readers, CI). Without that package, MathJax is
# loaded from its CDN.
# (Its importable name has hyphens: "sphinx-mathjax-offline".)
if importlib.util.find_spec("sphinx-mathjax-offline") is not None:
    extensions.append("sphinx-mathjax-offline")

autosummary_generate = True
# A summary line is the docstring's first sentence: do not end it inside a reference such as
# "(Berge et al. 2012, sect. 3)".
import sphinx.ext.autosummary  # noqa: E402

sphinx.ext.autosummary.WELL_KNOWN_ABBREVIATIONS += ("sect.", "sects.", "eq.", "eqs.", "fig.",
                                                    "figs.", "Sect.", "Eq.", "Fig.")
autodoc_default_options = {"members": True, "inherited-members": False}
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks = set()  # validation off (the docstrings are checked by doctests)
templates_path = ["_templates"]
exclude_patterns = [
    "_build",
    "_ext",
    "auto_examples/*.ipynb",
    "auto_examples/*.py",
    "auto_examples/*.zip",
    "auto_examples/*.md5",
    "auto_examples/*.codeobj.json",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
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

from sphinx_gallery.sorting import ExplicitOrder  # noqa: E402

sphinx_gallery_conf = {
    "examples_dirs": "../examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    # From first steps to the full study; examples not listed come last.
    "within_subsection_order": ExplicitOrder([
        "plot_fit_psf_model.py",
        "plot_real_data_workflow.py",
        "plot_simulation.py",
        "plot_tune_kriging.py",
        "plot_multi_exposure.py",
        "plot_compare_schemes.py",
        "plot_correlation_diagnostics.py",
        "plot_paper_comparison.py",
        "*",
    ]),
    "doc_module": ("sklearn_psf",),
    "backreferences_dir": os.path.join("gen_modules", "backreferences"),
    "reference_url": {"sklearn_psf": None},
    "plot_gallery": "True",
    "show_memory": False,
    "min_reported_time": 1,
    "capture_repr": (),  # show what examples print, not the repr of a cell's last value
}

# Links to the libraries we build on. Their inventories (objects.inv) come from their sites
# and no installed package ships one, so they are fetched only when asked for
# (SKLEARN_PSF_DOCS_INTERSPHINX=1, on a machine with network): an offline build (CI) would
# otherwise fail under -W on the failed download. Offline, those names render as code.
intersphinx_mapping = {}
if os.environ.get("SKLEARN_PSF_DOCS_INTERSPHINX") == "1":
    intersphinx_mapping = {
        "python": ("https://docs.python.org/3", None),
        "numpy": ("https://numpy.org/doc/stable", None),
        "scipy": ("https://docs.scipy.org/doc/scipy", None),
        "sklearn": ("https://scikit-learn.org/stable", None),
        "astropy": ("https://docs.astropy.org/en/stable", None),
        "matplotlib": ("https://matplotlib.org/stable", None),
    }


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


def _constant_docstring(app, what, name, obj, options, lines):
    """A public constant is described by the ``#:`` comment of its assignment (in the
    private module that defines it), not by the docstring of its type; its value is shown
    when short."""
    if what not in ("data", "attribute") or not is_constant(obj):
        return
    module, _, attr = name.rpartition(".")
    try:
        comment = constant_doc(module, attr)
    except (ImportError, AttributeError):  # a class attribute: autodoc found its comment
        return
    if comment is None:
        return
    lines[:] = list(comment)
    value = repr(obj)
    if len(value) <= 120 and " at 0x" not in value and "\n" not in value:
        lines += ["", f"Value: ``{value}``"]


def _skip_member(app, what, name, obj, skip, options):
    # scikit-learn's metadata-routing helpers are generated on every estimator class; their
    # docstrings point into scikit-learn's own documentation.
    if re.fullmatch(r"set_\w+_request", name) or name == "get_metadata_routing":
        return True
    return None


def _fit_width(text, width=84):
    """Wrap the lines of a command's output that would not fit a code block of the page."""
    import textwrap

    lines = []
    for line in text.splitlines():
        indent = " " * (len(line) - len(line.lstrip()) + 2)
        lines += textwrap.wrap(line, width, subsequent_indent=indent, break_long_words=False,
                               break_on_hyphens=False) if len(line) > width else [line]
    return "\n".join(lines) + "\n"


def _write_cli_help(app):
    """The --help text of every ``sklearn-psf`` subcommand, for cli.rst (always current)."""
    import argparse

    from sklearn_psf.cli import build_parser

    folder = os.path.join(app.srcdir, "generated")
    os.makedirs(folder, exist_ok=True)
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "80"  # fits the page without a horizontal scroll bar
    try:
        parser = build_parser()
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    with open(os.path.join(folder, f"cli_{name}.txt"), "w") as f:
                        f.write(_fit_width(sub.format_help()))
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns


def _run_tutorial(app):
    """Run the tutorial's commands on the example exposure; keep their output and figures
    in ``generated/tutorial/`` for user_guide.rst (always current)."""
    folder = os.path.join(app.srcdir, "generated", "tutorial")
    os.makedirs(folder, exist_ok=True)
    work = tempfile.mkdtemp()
    env = dict(os.environ, COLUMNS="80")
    commands = {
        "exposure": [sys.executable, "-c",  # (prints nothing)
                     "from sklearn_psf.simulate import write_example_exposure; "
                     "write_example_exposure('.', compress=True)"],
        "fit": ["sklearn-psf", "fit", "exposure.fits.fz", "--hdu", "SCI", "--weight-hdu", "WGT",
                "-o", "psf.fits"],
        "predict": ["sklearn-psf", "predict", "psf.fits", "--positions", "galaxies.csv",
                    "-o", "galaxy_psfs.fits"],
    }
    try:
        for name, command in commands.items():
            if command[0] == "sklearn-psf":
                command = [sys.executable, "-m", "sklearn_psf", *command[1:]]
            proc = subprocess.run(command, cwd=work, env=env, capture_output=True, text=True,
                                  check=True)
            # the report (stdout) and the verdict's warnings (stderr, after the progress bars)
            out = proc.stdout + "".join(line + "\n" for line in proc.stderr.splitlines()
                                        if line.startswith("sklearn-psf: warning:"))
            with open(os.path.join(folder, f"{name}.txt"), "w") as f:
                f.write(_fit_width(out))
        for png in ("psf_stamps.png", "psf_whiskers.png", "psf_rho.png", "psf_maps.png"):
            shutil.copy(os.path.join(work, png), folder)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def setup(app):
    app.connect("builder-inited", _write_cli_help)
    app.connect("builder-inited", _run_tutorial)
    app.connect("autodoc-process-docstring", _constant_docstring, priority=700)
    app.connect("autodoc-process-docstring", _escape_docstring, priority=600)  # after numpydoc
    app.connect("autodoc-skip-member", _skip_member)
