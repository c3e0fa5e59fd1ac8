"""Tests of sklearn_psf.datasets: the embedded default reference and the dataset makers."""

import ast
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

import sklearn_psf.simulate as simulate
from sklearn_psf.datasets import ReferenceBasis, default_reference_path, load_default_reference
from sklearn_psf.simulate import make_psf_field


def test_datasets_never_imports_simulate():
    """No import circle: datasets loads data only; simulate re-exports its ReferenceBasis.
    (The regeneration script, never imported by the package, checks its output with
    make_psf_field.)"""
    folder = pathlib.Path(default_reference_path()).parents[1]
    for path in folder.glob("*.py"):
        if path.name == "_make_default_reference.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert "simulate" not in (node.module or ""), path.name
            elif isinstance(node, ast.Import):
                assert not any("simulate" in a.name for a in node.names), path.name
    assert simulate.ReferenceBasis is ReferenceBasis


def test_default_reference_file_and_content():
    path = default_reference_path()
    assert os.path.getsize(path) < 1_000_000
    ref = load_default_reference()
    assert isinstance(ref, ReferenceBasis)
    assert ref.stamp_size == 25 and ref.pixel_scale == 0.2
    assert 3 <= ref.n_components <= 20
    assert abs(ref.mean.sum() - 1) < 1e-8
    c = ref.components.reshape(ref.n_components, -1)
    np.testing.assert_allclose(c @ c.T, np.eye(ref.n_components), atol=1e-8)
    np.testing.assert_allclose(c.sum(axis=1), 0.0, atol=1e-8)  # unit flux is kept
    assert np.all(ref.coeff_std > 0)
    assert ref.explained_variance_ratio.sum() >= 0.9
    assert ref.positions.shape[0] >= 100 and ref.noise_rms > 0


def test_default_reference_mean_psf_is_ground_based_like():
    """Independent check with GalSim HSM: FWHM ~0.7-0.9 arcsec, |e| a few per cent."""
    galsim = pytest.importorskip("galsim")
    ref = load_default_reference()
    res = galsim.hsm.FindAdaptiveMom(galsim.Image(ref.mean, scale=ref.pixel_scale))
    fwhm = 2.3548 * res.moments_sigma * ref.pixel_scale
    assert 0.7 < fwhm < 1.0
    assert 0.02 < np.hypot(res.observed_shape.e1, res.observed_shape.e2) < 0.08


def test_default_reference_loads_without_galsim():
    code = ("import sys; sys.modules['galsim'] = None\n"
            "from sklearn_psf.datasets import load_default_reference\n"
            "r = load_default_reference(); assert r.n_components > 0\n")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_reference_image_script_from_image_recovers_stars():
    """The regeneration script's GalSim image (small) through from_image, as real data."""
    pytest.importorskip("galsim")
    from sklearn_psf.datasets._make_default_reference import render_reference_image

    image, header, true_pos = render_reference_image(seed=1, n_stars=40, size=700)
    ref = ReferenceBasis.from_image(image, stamp_size=25, saturation=header["SATURATE"])
    d, _ = cKDTree(true_pos).query(ref.positions)
    # every selected source is a true star, at its position (coma moves the light centroid
    # of these optical PSFs by ~0.1 pixel from the profile's nominal centre)
    assert d.max() < 0.3
    assert len(ref.positions) >= 35  # (saturated stars and galaxies are rejected)
    assert 1 <= ref.n_components <= 20


def test_thirteen_component_reference():
    """The paper-sized basis: same stars, 13 orthonormal components, the first 5 the default's."""
    ref5, ref13 = load_default_reference(), load_default_reference(n_components=13)
    assert ref13.n_components == 13 and ref13.stamp_size == 25
    c = ref13.components.reshape(13, -1)
    np.testing.assert_allclose(c @ c.T, np.eye(13), atol=1e-8)
    np.testing.assert_allclose(np.abs(np.sum(c[:5] * ref5.components.reshape(5, -1), axis=1)),
                               1.0, atol=1e-6)
    np.testing.assert_allclose(ref13.mean, ref5.mean, atol=1e-12)
    assert np.all(np.diff(ref13.explained_variance_ratio) <= 0)
    assert ref13.explained_variance_ratio.sum() > ref5.explained_variance_ratio.sum()
    with pytest.raises(ValueError, match="13"):
        load_default_reference(n_components=7)
    f = make_psf_field(ref13, n_stars=200, n_galaxies=0, image_shape=(1500, 2000),
                       random_state=0)
    e = np.hypot(f.stars["e1"], f.stars["e2"])
    assert np.all(f.stars["moments_flag"] == 0) and 0.02 < e.mean() < 0.1


def test_default_simulation_uses_default_reference():
    f = make_psf_field(n_stars=10, n_galaxies=5, image_shape=(500, 600), random_state=0)
    ref = load_default_reference()
    np.testing.assert_array_equal(f.reference.components, ref.components)
    assert f.pixel_scale == 0.2 and f.noise_rms == pytest.approx(ref.noise_rms)
