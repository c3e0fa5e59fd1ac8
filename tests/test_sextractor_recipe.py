"""The user guide's Source Extractor recipe, run as printed.

The bash block of "From Source Extractor to a .psf that Source Extractor uses"
(``docs/user_guide.rst``) is read from the guide and run command by command in a folder
holding a GalSim-rendered ``ccd.fits`` and ``ccd.weight.fits``: the configuration the package
writes, Source Extractor's catalogue, ``sklearn-psf fit --psfex``, then Source Extractor's
model fitting with that ``.psf``, whose ``SPREAD_MODEL`` must tell the stars from the
galaxies. Skipped where Source Extractor is not installed (Debian: ``apt-get install
source-extractor``).
"""

import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from astropy.table import Table
from scipy.spatial import cKDTree

from sklearn_psf.io import find_program, read_catalog

ROOT = Path(__file__).resolve().parents[1]
SEX = find_program("source-extractor")
pytest.importorskip("galsim")
pytestmark = pytest.mark.skipif(SEX is None, reason="Source Extractor (source-extractor) is "
                                "not installed")


def recipe_commands():
    """The commands of the guide's bash block that starts with the configuration step,
    continuation lines joined, comments left out."""
    text = (ROOT / "docs" / "user_guide.rst").read_text()
    start = text.rindex("\n", 0, text.index("# 0. Source Extractor's configuration")) + 1
    block = []
    for line in text[start:].splitlines():
        if line.strip() and not line.startswith("    "):
            break
        block.append(line.strip())
    commands, current = [], ""
    for line in block:
        if not line or line.startswith("#"):
            continue
        current += line[:-1] + " " if line.endswith("\\") else line
        if not line.endswith("\\"):
            commands.append(shlex.split(current))
            current = ""
    return commands


def _program(argv):
    """The command as run here: this interpreter for python and sklearn-psf."""
    head = {"source-extractor": [SEX], "python": [sys.executable],
            "sklearn-psf": [sys.executable, "-m", "sklearn_psf"]}[argv[0]]
    return head + argv[1:]


def test_the_guides_recipe_runs_as_printed(tmp_path):
    from sklearn_psf.simulate import render_galsim_ccd

    commands = recipe_commands()
    assert [c[0] for c in commands] == ["python", "source-extractor", "sklearn-psf",
                                        "source-extractor"]
    ccd = render_galsim_ccd(shape=(512, 512), n_stars=80, n_galaxies=100, n_saturated=1,
                            random_state=5)
    ccd.write(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    for argv in commands:
        proc = subprocess.run(_program(argv), cwd=tmp_path, env=env, capture_output=True,
                              text=True)
        assert proc.returncode == 0, (argv, proc.stdout[-2000:], proc.stderr[-2000:])
        if argv[0] == "sklearn-psf":
            assert "PSFEx file: polynomial of degree" in proc.stdout
    for name in ("prepsfex.sex", "prepsfex.param", "prepsfex.conv", "spread.param",
                 "ccd.ldac", "ccd_psf.fits", "ccd.psf", "ccd_spread.cat"):
        assert (tmp_path / name).exists(), name
    assert "VIGNET" in read_catalog(tmp_path / "ccd.ldac").colnames
    # Source Extractor's SPREAD_MODEL with the written .psf: stars at 0, galaxies above it
    # (measured: 65 stars, median |SPREAD_MODEL| 0.0005; 55 galaxies, median 0.0084)
    spread = Table.read(tmp_path / "ccd_spread.cat")
    xy = np.column_stack([spread["XWIN_IMAGE"] - 1, spread["YWIN_IMAGE"] - 1])
    truth = ccd.stars[~ccd.stars["saturated"]]
    d_star, _ = cKDTree(np.column_stack([truth["x"], truth["y"]])).query(xy)
    d_gal, _ = cKDTree(np.column_stack([ccd.galaxies["x"], ccd.galaxies["y"]])).query(xy)
    ok = spread["FLAGS"] == 0
    stars, galaxies = ok & (d_star < 1.0), ok & (d_gal < 1.0) & (d_star > 5.0)
    assert stars.sum() > 40 and galaxies.sum() > 40
    assert np.median(np.abs(spread["SPREAD_MODEL"][stars])) < 0.002
    assert np.median(spread["SPREAD_MODEL"][galaxies]) > 0.003
