"""Real images (``../shared/realdata``): this package's model against PSFEx by 5-fold
cross-validation on the same stars, every star judged once by both (``sklearn-psf
crossval``), and the share of PSFEx's stars the model rests on."""

import numpy as np
import pytest
from astropy.table import Table

from sklearn_psf.io import find_program

# (real images' verdicts: the Kriging finds no spatial correlation at these stars' S/N; a few
# undersampled stars have no centroid on the basis)
pytestmark = [pytest.mark.filterwarnings("ignore::sklearn_psf.interpolate.ShortRangeWarning"),
              pytest.mark.filterwarnings("ignore::sklearn_psf.validation.PSFQualityWarning"),
              pytest.mark.filterwarnings("ignore::sklearn_psf.model.UnusableStarsWarning")]

needs_psfex = pytest.mark.skipif(find_program("psfex") is None,
                                 reason="PSFEx is not installed (apt-get install psfex)")
needs_sextractor = pytest.mark.skipif(find_program("source-extractor") is None,
                                      reason="Source Extractor is not installed "
                                      "(apt-get install source-extractor)")


def _crossval(catalog, folder, *extra):
    from sklearn_psf.cli import main

    assert main(["crossval", "--stars", str(catalog), "-o", str(folder), "--no-plots",
                 *extra]) == 0
    return Table.read(folder / "crossval.csv", format="ascii.csv")


def _check_beats(table, names, at_least, capsys, folds=5):
    """Every star judged once; against each PSFEx model, ours' chi^2 lower on at least
    ``at_least`` of the stars both accept and significantly lower on the mean (the
    bootstrap interval of the mean difference below 0), summed chi^2 below PSFEx's."""
    from sklearn_psf.validation import paired_comparison

    out = capsys.readouterr().out
    assert len(np.unique(table["row"])) == len(table)
    assert set(table["fold"]) == set(range(folds))
    judged = table[np.asarray(table["judged"], dtype=bool)]
    for name in names:
        r = paired_comparison(judged["chi2_sklearn_psf"], judged[f"chi2_{name}"],
                              judged["dof"])
        assert r["n"] >= 0.9 * len(judged), (name, r, out)
        assert r["a_lower"] >= at_least, (name, r, out)
        assert r["mean_diff_ci"][1] < 0 and r["sum_ratio"] < 1, (name, r, out)


@needs_psfex
def test_decam_psfex_input_cross_validated_against_psfex(realdata, tmp_path, capsys):
    """DECam's PSFEx input (104 stars both accept, 63x63 VIGNETs, S/N 36-257): ours lower
    on at least 60% of the stars against PSFEx of degree 2 and 3 (measured 78% / 78%,
    summed chi^2 ratio 0.998 / 0.997, 95% intervals of the mean difference below 0; before
    the radial wings 11% / 14% and 1.018 / 1.017)."""
    cat = realdata("DECam_00241238_01_psfcat.ldac.fits")
    table = _crossval(cat, tmp_path / "cv", "--psfex-degrees", "2", "3")
    _check_beats(table, ["psfex_d2", "psfex_d3"], 0.6, capsys)


@needs_psfex
@needs_sextractor
def test_elongated_star_frame_cross_validated_against_psfex(realdata, tmp_path, capsys):
    """The small telescope's frame (elongated stars in a globular cluster's crowded field,
    no gain): catalogued by Source Extractor with PSFEx's recipe, ours lower on at least
    55% of the stars against PSFEx of degree 2 and 3 (measured 67% / 83%, summed chi^2
    ratio 0.63 / 0.40); before the noise calibration and the population outlier test the
    fit rejected 34 of its 55 stars."""
    from sklearn_psf.io import run_sextractor

    cat = run_sextractor(realdata("YSTAR_SAAO_R_60s.fits"), tmp_path / "ystar.ldac")
    table = _crossval(cat, tmp_path / "cv", "--psfex-degrees", "2", "3")
    _check_beats(table, ["psfex_d2", "psfex_d3"], 0.55, capsys)


@needs_psfex
@needs_sextractor
def test_undersampled_sdss_frame_cross_validated_against_psfex(realdata, tmp_path, capsys):
    """The resampled, undersampled SDSS frame (FWHM ~1.2 px, no gain), catalogued by Source
    Extractor with PSFEx's recipe; 2 folds and stars above S/N 50 to keep the suite short:
    each model drawn at each star's sub-pixel position, ours lower on at least 85% of the
    stars against PSFEx of degree 2 (``SAMPLE_FWHMRANGE 1,10``), summed chi^2 below
    PSFEx's (measured 98% of 131 stars, summed 0.30; all stars in 5 folds,
    ``benchmarks/README.md``: 92%, summed 0.25; with the fine grid of 3 samples per pixel
    the default chose before, 93% and 0.34, and 71% and 0.46 in 5 folds; a Fourier-shift
    judge gave 11%, 1.82)."""
    from sklearn_psf.io import run_sextractor

    cat = run_sextractor(realdata("SDSS_2p5m_reprojected.fits"), tmp_path / "sdss.ldac")
    table = _crossval(cat, tmp_path / "cv", "--folds", "2", "--min-snr", "50",
                      "--psfex-config", "SAMPLE_FWHMRANGE=1,10")
    _check_beats(table, ["psfex_d2"], 0.85, capsys, folds=2)


@needs_psfex
@needs_sextractor
@pytest.mark.parametrize("name, share", [("DECam_00241238_01_psfcat.ldac.fits", 0.9),
                                         ("YSTAR_SAAO_R_60s.fits", 0.9)])
def test_model_rests_on_most_of_psfexs_stars(realdata, tmp_path, name, share):
    """The model, fitted on every star of the catalogue (no reserve), rests on at least
    ``share`` times as many stars as PSFEx accepts from the same catalogue, 0.9: on DECam
    measured 105 of PSFEx's 107; on the crowded small-telescope frame 54 of 56 (before the
    noise calibration and the population outlier test, 21)."""
    import warnings

    from sklearn_psf.io import run_sextractor
    from sklearn_psf.exposure import fit_exposure
    from sklearn_psf.exposure._crossval import _psfex_accepted

    path = realdata(name)
    if name.endswith("ldac.fits"):
        cat = path
    else:
        cat = run_sextractor(path, tmp_path / "cat.ldac")
    accepted = int(_psfex_accepted(cat, {"NTHREADS": 1}, tmp_path / "psfex").sum())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_exposure(catalog=cat, reserve=0.0)
    kept = int(np.sum(fit.model.inlier_mask_))
    assert kept >= share * accepted, (kept, accepted)
