"""Catalogues as Source Extractor writes them, read as PSFEx reads them.

A GalSim image of stars is catalogued by Source Extractor itself with 1 and 12
``PHOT_APERTURES``, 1 and 3 ``PHOT_FLUXFRAC`` and ``VIGNET``, as ``FITS_LDAC``, ``FITS_1.0``
and ``ASCII_HEAD``: every one is read to the same single columns (PSFEx's ``FLUX_APER(1)``,
the first ``FLUX_RADIUS``) and gives the same stars. ``write_ldac``'s files are read by PSFEx
3.21, and PSFEx's constant models (``PSFVAR_DEGREES 0``) by ``load_psf_model``. Tests skip
where ``source-extractor`` or ``psfex`` is not installed (Debian: ``apt-get install
source-extractor psfex``) or without ``../shared/realdata``.
"""

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

from sklearn_psf.cli import main
from sklearn_psf.io import find_program, read_catalog, run_psfex, run_sextractor, write_ldac
from sklearn_psf.exposure import extract_vignettes, select_stars

galsim = pytest.importorskip("galsim")
SEX = find_program("source-extractor")
PSFEX = find_program("psfex")
needs_sex = pytest.mark.skipif(SEX is None, reason="Source Extractor (source-extractor) is "
                               "not installed")
needs_psfex = pytest.mark.skipif(SEX is None or PSFEX is None,
                                 reason="Source Extractor or PSFEx is not installed")

#: The true PSF (pixel scale 1): a sheared Moffat.
PSF = galsim.Moffat(beta=3.0, fwhm=3.0).shear(e1=0.03, e2=-0.02)
APERTURES = {1: "5", 12: "5,3,4,6,7,8,10,12,14,16,18,20"}  # PSFEx's FLUX_APER(1) first
FRACTIONS = {1: "0.5", 3: "0.5,0.3,0.8"}
PARAMS = ("NUMBER", "X_IMAGE", "Y_IMAGE", "XWIN_IMAGE", "YWIN_IMAGE", "FLUX_APER({k})",
          "FLUXERR_APER({k})", "MAG_APER({k})", "FLUX_RADIUS({f})", "FLUX_MAX", "SNR_WIN",
          "FLAGS", "ELONGATION", "VIGNET({v},{v})")


@pytest.fixture(scope="module")
def image(tmp_path_factory):
    """A 320x320 GalSim image: 45 stars of S/N ~40-600 on a noisy background."""
    rng = np.random.default_rng(7)
    img = galsim.ImageF(320, 320, scale=1.0)
    for x, y in rng.uniform(20, 300, (45, 2)):
        PSF.withFlux(10 ** rng.uniform(3.3, 4.8)).drawImage(image=img, center=(x, y),
                                                           add_to_image=True)
    img.array[:] += 100.0 + rng.normal(0.0, 5.0, img.array.shape)
    img.header = galsim.FitsHeader({"SATURATE": 60000.0, "GAIN": 4.0})
    path = tmp_path_factory.mktemp("sex") / "stars.fits"
    img.write(str(path))
    return path


def _sextractor(image, kind, k=1, f=1, v=15):
    """Source Extractor's catalogue of ``image``: k apertures, f flux fractions, VIGNET(v, v)."""
    out = image.parent / f"{kind.replace('.', '')}_{k}_{f}_{v}.cat"
    return run_sextractor(image, out, params=[p.format(k=k, f=f, v=v) for p in PARAMS],
                          config={"PHOT_APERTURES": APERTURES[k],
                                  "PHOT_FLUXFRAC": FRACTIONS[f], "SATUR_LEVEL": 60000.0,
                                  "VERBOSE_TYPE": "QUIET"},
                          catalog_type=kind, overwrite=True)


def _selected(cat):
    keep, _ = select_stars(cat, min_stars=0, saturation=60000.0)
    return set(np.asarray(cat["NUMBER"])[keep].tolist())


@needs_sex
def test_vector_columns_read_as_psfex_reads_them(image):
    """12 apertures and 3 flux fractions, in each catalogue type: the first element of each,
    the same VIGNETs, the same stars as the 1-aperture, 1-fraction FITS_LDAC catalogue."""
    ref_path = _sextractor(image, "FITS_LDAC")
    ref = read_catalog(ref_path)
    raw = Table.read(ref_path, hdu="LDAC_OBJECTS")
    assert np.allclose(ref["flux"], raw["FLUX_APER"].ravel())
    assert "vector_elements" not in ref.meta          # nothing to reduce
    stars = _selected(ref)
    assert len(stars) >= 25
    for kind in ("FITS_LDAC", "FITS_1.0", "ASCII_HEAD"):
        path = _sextractor(image, kind, k=12, f=3)
        cat = read_catalog(path)
        assert cat.meta["vector_elements"] == {"FLUX_APER": 1, "FLUXERR_APER": 1,
                                               "MAG_APER": 1, "FLUX_RADIUS": 1}
        assert cat["flux"].ndim == 1 and cat["flux_radius"].ndim == 1
        np.testing.assert_allclose(cat["flux"], ref["flux"], rtol=1e-5)
        np.testing.assert_allclose(cat["flux_radius"], ref["flux_radius"], atol=6e-4)  # ASCII
        np.testing.assert_allclose(cat["VIGNET"], ref["VIGNET"], rtol=1e-5, atol=1e-3)
        assert len(_selected(cat) ^ stars) <= 1, kind
        cut = extract_vignettes(cat[[n in stars for n in cat["NUMBER"]]])
        assert cut.stamps.shape[1] == 15 * 15
        if kind == "FITS_1.0":  # the other apertures and fractions on request
            raw = Table.read(path, hdu=1)
            third = read_catalog(path, aperture=3, flux_fraction=3)
            assert np.array_equal(third["flux"], raw["FLUX_APER"][:, 2])
            assert np.array_equal(third["flux_radius"], raw["FLUX_RADIUS"][:, 2])
            assert third.meta["vector_elements"]["FLUX_RADIUS"] == 3


@needs_sex
def test_fit_on_ascii_catalogue_with_12_apertures(image, tmp_path, capsys):
    """``fit`` on an ASCII_HEAD catalogue with VIGNET(25,25), 12 apertures and 3 flux
    fractions: the model's PSF has the true shape (GalSim's adaptive moments of the true PSF)."""
    path = _sextractor(image, "ASCII_HEAD", k=12, f=3, v=25)
    out = str(tmp_path / "m.fits")
    assert main(["fit", "--stars", str(path), "-o", out, "--no-plots",
                 "--interpolator", "polynomial"]) == 0
    from sklearn_psf.io import draw_psf
    from sklearn_psf.model import load_model

    model = load_model(out)
    stamp = draw_psf(model, [[160.0, 160.0]])[0]
    truth = PSF.drawImage(nx=25, ny=25, scale=1.0).FindAdaptiveMom()
    mom = galsim.ImageD(stamp.reshape(25, 25), scale=1.0).FindAdaptiveMom()
    assert abs(mom.observed_shape.e1 - truth.observed_shape.e1) < 0.01
    assert abs(mom.observed_shape.e2 - truth.observed_shape.e2) < 0.01
    assert abs(mom.moments_sigma / truth.moments_sigma - 1) < 0.05


def test_decam_psfex_input_with_12_apertures(realdata):
    DECAM = str(realdata("DECam_00241238_01_psfcat.ldac.fits"))
    cat = read_catalog(DECAM)
    raw = Table.read(DECAM, hdu="LDAC_OBJECTS")
    assert raw["FLUX_APER"].shape == (117, 12)
    assert np.array_equal(cat["flux"], raw["FLUX_APER"][:, 0])
    assert np.allclose(cat["FLUX_APER"], raw["FLUX_APER"][:, 0])
    assert cat.meta["vector_elements"]["MAGERR_APER"] == 1
    assert np.array_equal(read_catalog(DECAM, aperture=12)["flux"], raw["FLUX_APER"][:, 11])
    keep, counts = select_stars(cat, min_stars=0, flag_mask=0xFE)
    assert keep.sum() >= 0.9 * 105 and counts["bad_position"] == 0  # PSFEx accepted 105


@needs_psfex
def test_psfex_reads_write_ldac_and_degree_zero_models(image, tmp_path):
    """A catalogue rewritten by write_ldac is read by PSFEx 3.21 (which crashed on NUL-padded
    header cards), and PSFEx's constant model (PSFVAR_DEGREES 0, no POLNAME1) is read back:
    one PSF everywhere, of the true shape."""
    from sklearn_psf.measure import adaptive_moments
    from sklearn_psf.validation import load_psf_model

    source = _sextractor(image, "FITS_LDAC", v=25)
    ours = tmp_path / "ours.cat"
    write_ldac(ours, Table.read(source, hdu="LDAC_OBJECTS"),
               header=read_catalog(source).meta["image_header"])
    psf_file = run_psfex(ours, tmp_path, config={"PSFVAR_DEGREES": 0, "PSF_SIZE": "15,15",
                                                 "NTHREADS": 1})  # ProgramError if it fails
    header = fits.getheader(psf_file, 1)
    assert header["POLNAXIS"] == 0 and header["ACCEPTED"] >= 20
    model = load_psf_model(psf_file)
    assert model.degree_ == 0
    stamps = model.predict([[20.0, 30.0], [290.0, 250.0]])
    np.testing.assert_allclose(stamps[0], stamps[1], atol=1e-12)
    s = model.stamp_size_
    mom = adaptive_moments(stamps[:1].reshape(1, s, s))
    truth = PSF.drawImage(nx=s, ny=s, scale=1.0).FindAdaptiveMom()
    assert abs(float(mom["e1"][0]) - truth.observed_shape.e1) < 0.01
    assert abs(float(mom["e2"][0]) - truth.observed_shape.e2) < 0.01
    assert abs(float(mom["sigma"][0]) / truth.moments_sigma - 1) < 0.08
