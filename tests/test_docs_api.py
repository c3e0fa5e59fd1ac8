"""Every public name is in the API reference (docs/api.rst)."""

import importlib
import pathlib
import re

import pytest

MODULES = ["sklearn_psf", "sklearn_psf.interpolate", "sklearn_psf.preprocessing",
           "sklearn_psf.measure", "sklearn_psf.model", "sklearn_psf.simulate",
           "sklearn_psf.datasets", "sklearn_psf.metrics", "sklearn_psf.compare",
           "sklearn_psf.plotting", "sklearn_psf.report", "sklearn_psf.io",
           "sklearn_psf.validation"]
API = pathlib.Path(__file__).parents[1] / "docs" / "api.rst"


@pytest.mark.parametrize("module", MODULES)
def test_public_names_are_documented(module):
    text = API.read_text()
    listed = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text))
    missing = [name for name in importlib.import_module(module).__all__ if name not in listed]
    assert not missing, f"{module}: add {missing} to docs/api.rst"
