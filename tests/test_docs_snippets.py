"""The code of README.md and docs/ that shows what it prints: run, and its output compared.

A Python code block directly followed by a text block (Markdown ```` ```text ````, reST
``.. code-block:: text``) shows its output: the block is run and must print exactly that
text, and warn nothing (a newcomer copying it sees what the page shows). A figure that
changes (components kept, stars kept, an error to the fourth decimal) fails here: update the
page with what the code now prints.
"""

import contextlib
import io
import re
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.rst"))]


def _markdown_blocks(text):
    """(language, code, line) of each fenced block."""
    for match in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
        yield match.group(1), match.group(2), text.count("\n", 0, match.start()) + 1


def _rst_blocks(text):
    """(language, code, line) of each ``.. code-block::`` (its indented body, dedented)."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        found = re.match(r"^(\s*)\.\. code-block::\s*(\w+)", line)
        if not found:
            continue
        indent, body, j = len(found.group(1)), [], i + 1
        while j < len(lines) and (not lines[j].strip()
                                  or len(lines[j]) - len(lines[j].lstrip()) > indent):
            body.append(lines[j])
            j += 1
        width = min(len(b) - len(b.lstrip()) for b in body if b.strip())
        yield found.group(2), "\n".join(b[width:] for b in body).strip("\n") + "\n", i + 1


def snippets():
    """(page, line, code, expected output) of every Python block followed by its output."""
    found = []
    for page in PAGES:
        text = page.read_text()
        blocks = list((_markdown_blocks if page.suffix == ".md" else _rst_blocks)(text))
        for (lang, code, line), (next_lang, output, _) in zip(blocks, blocks[1:]):
            if lang == "python" and next_lang == "text":
                found.append((page, line, code, output))
    return found


SNIPPETS = snippets()


def test_the_pages_that_print_are_found():
    """README's "Fit a PSF model" and the documentation's quick start show their output."""
    pages = {(page.name, code.count("print(")) for page, _, code, _ in SNIPPETS}
    assert {("README.md", 2), ("index.rst", 2)} <= pages


@pytest.mark.parametrize("page, line, code, expected", SNIPPETS,
                         ids=[f"{p.name}:{n}" for p, n, _, _ in SNIPPETS])
def test_snippet_prints_what_its_page_shows(page, line, code, expected):
    out = io.StringIO()
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(out):
        warnings.simplefilter("always")
        exec(compile(code, f"{page.name}:{line}", "exec"), {"__name__": "__snippet__"})
    printed = [s.rstrip() for s in out.getvalue().strip().splitlines()]
    shown = [s.rstrip() for s in expected.strip().splitlines()]
    assert printed == shown, (f"{page.name} line {line} prints {printed}; the page shows "
                              f"{shown}: update the page")
    assert not [str(w.message) for w in caught]


def test_tutorial_prose_quotes_what_fit_prints(tmp_path):
    """The user guide's tutorial shows ``fit``'s output as generated at build time; the
    figures its prose quotes from it (the stars' ellipticity noise, the model's own error,
    the warning) are those of the same fit."""
    from sklearn_psf.simulate import write_example_exposure
    from sklearn_psf.validation import PSFQualityWarning
    from sklearn_psf.exposure import fit_exposure

    text = " ".join((ROOT / "docs" / "user_guide.rst").read_text().split())
    noise = re.search(r"their ellipticity noise is about ([0-9.]+)\)", text).group(1)
    error = re.search(r"the model's own ellipticity error, about ([0-9.]+),", text).group(1)
    twice = "is near twice the noise, and ``fit`` says so in a warning" in text
    write_example_exposure(tmp_path, compress=True)
    with pytest.warns(PSFQualityWarning, match="exceed their measurement noise"):
        fit = fit_exposure(tmp_path / "exposure.fits.fz", hdu="SCI", weight_hdu="WGT")
    summary = fit.summary

    def shown(value, quoted):
        return f"{value:.{len(quoted.split('.')[1])}f}" == quoted

    assert shown(summary["e_noise"], noise), (summary["e_noise"], noise)
    assert shown(summary["e_model_error"], error), (summary["e_model_error"], error)
    assert twice and 1.5 < summary["e_resid_over_noise"] < 2.5
