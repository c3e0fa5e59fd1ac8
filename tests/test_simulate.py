"""Tests of sklearn_psf.simulate: random fields, reference basis, simulated PSF fields."""

import warnings

import numpy as np
import pytest
from astropy.stats import sigma_clipped_stats
from scipy.spatial import cKDTree

from sklearn_psf.measure import adaptive_moments
from sklearn_psf.preprocessing import StampNormalizer, fourier_shift
from sklearn_psf.preprocessing._pca import _stamp_pca_on_basis
from sklearn_psf.simulate import (
    ContaminantSettings,
    DetectorSettings,
    PSFField,
    RandomFieldSampler,
    ReferenceBasis,
    gaussian_random_field,
    make_psf_field,
    realistic_snr,
)

SMALL = (1500, 2000)


def _radial_slope(fields, kmin=0.01, kmax=0.2):
    """Slope of the radially averaged power spectrum (Hann-windowed), averaged over fields."""
    ny, nx = fields[0].shape
    win = np.hanning(ny)[:, None] * np.hanning(nx)[None, :]
    power = np.mean([np.abs(np.fft.fft2((f - f.mean()) * win)) ** 2 for f in fields], axis=0)
    k = np.hypot(np.fft.fftfreq(ny)[:, None], np.fft.fftfreq(nx)[None, :]).ravel()
    bins = np.logspace(np.log10(kmin), np.log10(kmax), 12)
    idx = np.digitize(k, bins)
    ks = [k[idx == i].mean() for i in range(1, len(bins))]
    ps = [power.ravel()[idx == i].mean() for i in range(1, len(bins))]
    return -np.polyfit(np.log(ks), np.log(ps), 1)[0]


@pytest.fixture(scope="module")
def field():
    return make_psf_field(n_stars=200, n_galaxies=300, image_shape=SMALL, random_state=7)


@pytest.fixture(scope="module")
def dirty():
    """A field as real data come: contaminants, masks, a bad column, saturation, Poisson."""
    return make_psf_field(
        n_stars=200, n_galaxies=50, image_shape=SMALL, random_state=11, snr=realistic_snr(
            200, random_state=0),
        contaminants=ContaminantSettings(
            {"cosmic_ray": 0.1, "neighbour": 0.1, "galaxy": 0.1, "binary": 0.1},
            n_field_cosmic_rays=8, n_field_galaxies=8),
        detector=DetectorSettings(masked_fraction=2e-3, bad_columns=2, saturation=4000.0,
                                  gain=2.0))


# ----------------------------------------------------------------------------- random fields
@pytest.mark.parametrize("slope", [11 / 4, 2.0])
def test_power_spectrum_slope(slope):
    fields = [gaussian_random_field((256, 320), slope, random_state=s) for s in range(6)]
    assert abs(_radial_slope(fields) - slope) < 0.1


def test_unit_variance_zero_mean_and_expected_variance():
    f = gaussian_random_field((100, 130), random_state=3)
    assert f.shape == (100, 130)
    assert abs(f.mean()) < 1e-12 and abs(f.std() - 1) < 1e-12
    # without per-realisation normalisation the padded field has unit *expected* variance:
    # the full padded grid's variance averaged over realisations is ~1
    v = [gaussian_random_field((64, 64), random_state=s, padding=1.0, normalize=False).var()
         for s in range(40)]
    # a realisation's spatial variance misses the k=0 mode only; expectation is 1 exactly
    assert abs(np.mean(v) - 1) < 0.1


def test_same_seed_same_field_different_seeds_independent():
    a = gaussian_random_field((128, 128), random_state=11)
    b = gaussian_random_field((128, 128), random_state=11)
    np.testing.assert_array_equal(a, b)
    corr = [np.corrcoef(gaussian_random_field((256, 256), random_state=2 * i).ravel(),
                        gaussian_random_field((256, 256), random_state=2 * i + 1).ravel())[0, 1]
            for i in range(10)]
    assert abs(np.mean(corr)) < 0.1
    assert np.sqrt(np.mean(np.square(corr))) < 0.3


def test_seed_sequence_children_give_distinct_reproducible_fields():
    kids = np.random.SeedSequence(5).spawn(3)
    fs = [gaussian_random_field((64, 64), random_state=np.random.default_rng(k)) for k in kids]
    again = gaussian_random_field((64, 64), random_state=np.random.default_rng(
        np.random.SeedSequence(5).spawn(3)[1]))
    np.testing.assert_array_equal(fs[1], again)
    assert not np.allclose(fs[0], fs[1])


def test_sampler_interpolates_through_grid_nodes_and_is_smooth():
    s = RandomFieldSampler((700, 1000), n_fields=2, grid_size=50, random_state=0)
    gy, gx = s.grids.shape[1:]
    jj, ii = np.meshgrid(np.arange(gx), np.arange(gy))
    pos = np.column_stack([jj.ravel() * s.cell, ii.ravel() * s.cell])
    inside = (pos[:, 0] <= 999) & (pos[:, 1] <= 699)
    vals = s(pos[inside])
    np.testing.assert_allclose(vals[:, 0], s.grids[0].ravel()[inside], atol=1e-10)
    np.testing.assert_allclose(vals[:, 1], s.grids[1].ravel()[inside], atol=1e-10)
    # midpoints lie between the neighbouring node values up to the cubic overshoot
    mid = s(np.array([[0.5 * s.cell, 0.0]]))[0, 0]
    g = s.grids[0, 0]
    assert min(g[0], g[1]) - 0.5 < mid < max(g[0], g[1]) + 0.5


def test_bad_random_field_input():
    with pytest.raises(ValueError, match="slope"):
        gaussian_random_field((10, 10), slope=-1)
    with pytest.raises(ValueError, match="shape"):
        gaussian_random_field((1, 10))
    with pytest.raises(TypeError, match="random_state"):
        gaussian_random_field((10, 10), random_state="seed")


# ----------------------------------------------------------------------------- PSF fields
def test_default_ellipticity_distribution():
    """Paper: mean |e| ~ 0.05, std ~ 0.02. Tolerances: mean within 0.01, std within 0.007."""
    means, stds = [], []
    for seed in range(3):
        f = make_psf_field(n_stars=200, n_galaxies=600, image_shape=SMALL, random_state=seed)
        e = np.hypot(np.concatenate([f.stars["e1"], f.galaxies["e1"]]),
                     np.concatenate([f.stars["e2"], f.galaxies["e2"]]))
        means.append(e.mean())
        stds.append(e.std())
    assert abs(np.mean(means) - 0.05) < 0.01
    assert abs(np.mean(stds) - 0.02) < 0.007


def test_true_ellipticities_match_galsim(field):
    galsim = pytest.importorskip("galsim")
    s = field.stamp_size
    for row in field.stars[:5]:
        img = galsim.Image(np.asarray(row["stamp"]).reshape(s, s), scale=1.0)
        res = galsim.hsm.FindAdaptiveMom(img)
        assert abs(res.observed_shape.e1 - row["e1"]) < 1e-4
        assert abs(res.observed_shape.e2 - row["e2"]) < 1e-4
        assert abs(res.moments_sigma - row["sigma"]) < 1e-3


def test_true_stamps_normalised_and_in_basis(field):
    stamps = np.asarray(field.stars["stamp"])
    np.testing.assert_allclose(stamps.sum(axis=1), 1.0, atol=1e-10)
    assert np.all(field.stars["moments_flag"] == 0)
    rebuilt = field.reference.synthesize(np.asarray(field.stars["coeffs"]))
    assert np.max(np.abs(rebuilt - stamps)) < 1e-3 * stamps.max()


def test_measured_snr_matches_requested():
    snr = realistic_snr(150, random_state=1)
    f = make_psf_field(n_stars=150, n_galaxies=100, image_shape=SMALL, snr=snr, random_state=2,
                       subpixel=False)
    _, _, rms = sigma_clipped_stats(f.image[::2, ::2], sigma=3)
    assert abs(rms / f.noise_rms - 1) < 0.01
    s = f.stamp_size
    h = s // 2
    for row, want in zip(f.stars, snr):
        x, y = int(row["x"]), int(row["y"])
        data = f.image[y - h:y + h + 1, x - h:x + h + 1].ravel()
        true = np.asarray(row["stamp"])
        core = true >= 0.5 * true.max()
        assert abs(data[core].mean() / rms / want - 1) < 0.1
    m = f.measure_stars()  # the data-only estimate of measure_stars
    assert abs(np.median(m["snr"] / snr) - 1) < 0.1


def test_image_is_psfs_plus_noise(field):
    """Each star is its truth stamp shifted by its sub-pixel offset (independent check with
    scipy.ndimage.fourier_shift), plus noise of the given rms."""
    from scipy import ndimage

    s, h = field.stamp_size, field.stamp_size // 2
    res = []
    for row in field.stars:
        x, y = int(np.floor(row["x"] + 0.5)), int(np.floor(row["y"] + 0.5))
        data = field.image[y - h:y + h + 1, x - h:x + h + 1].ravel()
        spec = ndimage.fourier_shift(np.fft.fft2(np.asarray(row["stamp"]).reshape(s, s)),
                                     (row["y"] - y, row["x"] - x))
        res.append(data - row["flux"] * np.fft.ifft2(spec).real.ravel())
    assert abs(np.std(res) / field.noise_rms - 1) < 0.02
    assert abs(np.mean(res)) < 0.01 * field.noise_rms
    assert field.image.dtype == np.float32


def test_positions_subpixel_inside_no_overlap(field):
    s, h = field.stamp_size, field.stamp_size // 2
    exact = np.vstack([np.column_stack([t["x"], t["y"]]) for t in (field.stars, field.galaxies)])
    assert len(exact) == 500
    frac = exact - np.floor(exact + 0.5)  # uniform in [-0.5, 0.5): mean 0, variance 1/12
    assert np.all(np.abs(frac) <= 0.5) and abs(frac.mean()) < 0.03
    assert abs(frac.var() - 1 / 12) < 0.01
    pos = np.floor(exact + 0.5)
    ny, nx = field.image.shape
    assert pos[:, 0].min() >= h and pos[:, 0].max() <= nx - 1 - h
    assert pos[:, 1].min() >= h and pos[:, 1].max() <= ny - 1 - h
    d, _ = cKDTree(pos).query(pos, k=2, p=np.inf)
    assert d[:, 1].min() >= s


def test_integer_positions_option():
    f = make_psf_field(n_stars=30, n_galaxies=20, image_shape=(600, 800), random_state=1,
                       subpixel=False)
    for t in (f.stars, f.galaxies):
        np.testing.assert_array_equal(t["x"], np.round(t["x"]))
        np.testing.assert_array_equal(t["y"], np.round(t["y"]))
    # the same seed draws the same pixels with and without the sub-pixel offsets
    g = make_psf_field(n_stars=30, n_galaxies=20, image_shape=(600, 800), random_state=1)
    np.testing.assert_array_equal(np.floor(np.asarray(g.stars["x"]) + 0.5), f.stars["x"])


def test_grid_layout():
    f = make_psf_field(n_stars=100, n_galaxies=400, galaxy_layout="grid", image_shape=SMALL,
                       random_state=0, subpixel=False)
    xs, ys = np.unique(f.galaxies["x"]), np.unique(f.galaxies["y"])
    assert len(xs) * len(ys) == len(f.galaxies)
    assert abs(len(f.galaxies) - 400) <= 40
    assert np.ptp(np.diff(xs)) <= 1 and np.ptp(np.diff(ys)) <= 1


def test_reproducible_and_seed_dependent():
    kw = dict(n_stars=30, n_galaxies=20, image_shape=(600, 800))
    a, b = make_psf_field(random_state=3, **kw), make_psf_field(random_state=3, **kw)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.stars["coeffs"], b.stars["coeffs"])
    c = make_psf_field(random_state=4, **kw)
    assert not np.array_equal(a.image, c.image)
    # the PSF pattern of a seed does not depend on the S/N
    d = make_psf_field(random_state=3, snr=700.0, **kw)
    np.testing.assert_array_equal(a.stars["coeffs"], d.stars["coeffs"])


def test_given_star_positions_and_reference_positions():
    ref = ReferenceBasis.load(__import__("sklearn_psf.datasets", fromlist=["x"])
                              .default_reference_path())
    pos = np.array([[100.2, 50.7], [400.0, 300.0], [700.6, 500.4]])
    pos0 = pos.copy()
    f = make_psf_field(ref, star_positions=pos, n_galaxies=5, image_shape=(600, 800),
                       random_state=0)
    np.testing.assert_array_equal(pos, pos0)
    np.testing.assert_array_equal(np.column_stack([f.stars["x"], f.stars["y"]]), pos)
    f = make_psf_field(ref, star_positions=pos, n_galaxies=5, image_shape=(600, 800),
                       random_state=0, subpixel=False)
    np.testing.assert_array_equal(np.column_stack([f.stars["x"], f.stars["y"]]),
                                  np.floor(pos + 0.5))
    g = make_psf_field(ref, star_positions=ref.positions, n_galaxies=50,
                       image_shape=ref.image_shape, random_state=0)
    assert len(g.stars) == len(ref.positions)


def test_measure_stars_recovers_coefficients():
    f = make_psf_field(n_stars=60, n_galaxies=0, image_shape=(900, 1200), snr=700.0,
                       random_state=5)
    m = f.measure_stars()
    assert np.all(m["cut_flag"] == 0) and np.all(m["moments_flag"] == 0)
    err = np.asarray(m["coeffs"]) - np.asarray(f.stars["coeffs"])
    assert np.all(np.std(err, axis=0) < 0.2 * f.reference.coeff_std)
    assert np.std(m["e1"] - f.stars["e1"]) < 0.01
    stamps, flags = f.star_stamps()
    np.testing.assert_allclose(stamps, np.asarray(m["stamp"]))


def test_save_load_roundtrip(tmp_path, field, dirty):
    path = tmp_path / "sim.fits"
    dirty.save(path)
    back = PSFField.load(path)
    np.testing.assert_array_equal(back.image, dirty.image)
    np.testing.assert_array_equal(back.weight, dirty.weight)
    for name in ("stars", "galaxies", "contaminants"):
        t0, t1 = getattr(dirty, name), getattr(back, name)
        for col in t0.colnames:
            np.testing.assert_array_equal(np.asarray(t1[col]), np.asarray(t0[col]))
    assert back.meta["cell"] == dirty.meta["cell"] and back.meta["gain"] == dirty.meta["gain"]
    np.testing.assert_allclose(back.meta["field_scales"], dirty.meta["field_scales"])
    field.save(path, overwrite=True)
    back = PSFField.load(path)
    np.testing.assert_array_equal(back.image, field.image)
    for name in ("stars", "galaxies"):
        t0, t1 = getattr(field, name), getattr(back, name)
        for col in t0.colnames:
            np.testing.assert_array_equal(np.asarray(t1[col]), np.asarray(t0[col]))
    assert back.meta["seed"] == 7 and back.noise_rms == field.noise_rms
    np.testing.assert_array_equal(back.reference.components, field.reference.components)
    from astropy.io import fits

    h = fits.getheader(path)
    assert h["PIXSCALE"] == 0.2 and h["SEED"] == 7 and "SKPSFVER" in h
    # a file of the former format (GRIDSIZE instead of CELL) still loads
    with fits.open(path, mode="update") as hdul:
        del hdul[0].header["CELL"]
        hdul[0].header["GRIDSIZE"] = 256
    assert PSFField.load(path).meta["cell"] == pytest.approx(1999 / 255)


def test_realistic_snr_distribution():
    s = realistic_snr(20000, random_state=0)
    assert s.min() >= 20 and s.max() <= 1000
    hist, edges = np.histogram(s, bins=np.arange(20, 1001, 20))
    assert 60 <= edges[np.argmax(hist)] <= 120


# ----------------------------------------------------------------------------- sub-pixel truth
def test_subpixel_stamps_recover_truth():
    """Noise-free sub-pixel field: cut_stamps + StampNormalizer give back the truth stamps
    (e1/e2 within 1e-4, PCA coefficients within 1e-4 of their spread)."""
    f = make_psf_field(n_stars=80, n_galaxies=0, image_shape=(900, 1200), snr=1e8,
                       random_state=4)
    stamps, flags = f.star_stamps()
    assert np.all(flags == 0)
    mom = adaptive_moments(stamps)
    assert np.max(np.abs(mom["e1"] - f.stars["e1"])) < 1e-4
    assert np.max(np.abs(mom["e2"] - f.stars["e2"])) < 1e-4
    coeffs = f.reference.as_transformer(normalize=False).transform(stamps)
    err = np.abs(coeffs - np.asarray(f.stars["coeffs"])) / f.reference.coeff_std
    assert err.max() < 1e-3
    # a real sub-pixel offset was undone: the raw stamps are not centred
    raw, _ = f.star_stamps(normalize=False)
    off = np.abs(np.asarray(adaptive_moments(raw)["x0"]) - f.stamp_size // 2)
    assert np.median(off) > 0.1


# ----------------------------------------------------------------------------- weights and masks
def test_weight_map_masks_saturation_and_poisson(dirty):
    w, img = dirty.weight, dirty.image
    assert w.shape == img.shape and w.dtype == np.float32
    cols = np.flatnonzero((w == 0).all(axis=0))
    assert len(cols) == 2 and np.all(img[:, cols] == 0.0)
    sat = img == np.float32(4000.0)
    assert sat.any() and np.all(w[sat] == 0)
    assert np.all(img <= 4000.0)
    frac = np.mean(w[:, np.setdiff1d(np.arange(img.shape[1]), cols)] == 0)
    assert 1.5e-3 < frac < 3e-3
    # away from sources the weight is the background's; on a star it is lower (Poisson)
    assert np.median(w) == pytest.approx(1 / dirty.noise_rms**2, rel=1e-6)
    # the weights are the inverse variance: chi = (data - model) sqrt(w) has unit spread
    clean = np.flatnonzero(dirty.stars["contaminant"] == "")
    s = dirty.stamp_size
    raw, wst, flags = dirty.star_stamps(return_weights=True)
    truth = fourier_shift(np.asarray(dirty.stars["stamp"]).reshape(-1, s, s),
                          dirty.stars["x"] - np.floor(dirty.stars["x"] + 0.5),
                          dirty.stars["y"] - np.floor(dirty.stars["y"] + 0.5)).reshape(len(raw), -1)
    model = truth * np.asarray(dirty.stars["flux"])[:, None]
    chi = ((raw - model) * np.sqrt(wst))[clean]
    good = wst[clean] > 0
    core = model[clean] > 5 * dirty.noise_rms  # pixels where the Poisson term matters
    assert abs(np.std(chi[good & core]) - 1) < 0.05
    assert abs(np.std(chi[good & ~core]) - 1) < 0.05
    assert np.std(((raw - model) / dirty.noise_rms)[clean][good & core]) > 1.2


def test_star_stamps_weights_and_existing_return(dirty):
    stamps, flags = dirty.star_stamps()  # the existing call
    assert stamps.shape == (200, dirty.stamp_size**2) and flags.shape == (200,)
    raw, w, flags2 = dirty.star_stamps(return_weights=True)
    np.testing.assert_array_equal(flags, flags2)
    assert np.all(w >= 0) and np.all(w[~np.isfinite(raw)] == 0)
    assert (w == 0).any(axis=1).sum() >= 5  # masked pixels and columns hit some stars
    np.testing.assert_array_equal(dirty.stars["n_masked"], (w == 0).sum(axis=1))
    sat = np.any(raw == np.float32(4000.0), axis=1)
    assert sat.any()
    np.testing.assert_array_equal(dirty.stars["saturated"], sat)
    with pytest.raises(ValueError, match="normalize=False"):
        dirty.star_stamps(normalize=True, return_weights=True)
    nan = make_psf_field(n_stars=10, n_galaxies=0, image_shape=(300, 400), random_state=0,
                         detector=DetectorSettings(bad_columns=3, mask_value=np.nan))
    cols = np.flatnonzero((nan.weight == 0).all(axis=0))
    assert np.all(np.isnan(nan.image[:, cols]))


# ----------------------------------------------------------------------------- contaminants
def test_contaminant_truth_and_counts(dirty):
    kinds = np.asarray(dirty.stars["contaminant"])
    for kind in ("cosmic_ray", "neighbour", "galaxy", "binary"):
        assert np.count_nonzero(kinds == kind) == 20
    assert np.count_nonzero(kinds == "") == 120
    c = dirty.contaminants
    on = c[c["star"] >= 0]
    np.testing.assert_array_equal(np.sort(on["star"]), np.flatnonzero(kinds != ""))
    assert np.all(on["snr"] > 0)  # natural strength: not raised (tests/test_contaminants.py)
    np.testing.assert_array_equal(dirty.stars["contaminant_snr"][on["star"]], on["snr"])
    assert np.all(dirty.stars["contaminant_snr"][kinds == ""] == 0)
    nb = on[on["kind"] == "neighbour"]
    d = np.hypot(nb["x"] - dirty.stars["x"][nb["star"]], nb["y"] - dirty.stars["y"][nb["star"]])
    assert np.all((d >= 3) & (d <= 8 + 1e-9))
    assert np.all(nb["flux"] <= dirty.stars["flux"][nb["star"]] + 1e-6)
    b = on[on["kind"] == "binary"]
    assert np.all((b["size"] >= 0.5) & (b["size"] <= 4))
    # field contaminants lie away from every star's stamp
    away = c[c["star"] < 0]
    assert sorted(set(away["kind"])) == ["field_cosmic_ray", "field_galaxy"] and len(away) == 16
    dd, _ = cKDTree(np.column_stack([dirty.stars["x"], dirty.stars["y"]])).query(
        np.column_stack([away["x"], away["y"]]), p=np.inf)
    assert dd.min() >= dirty.stamp_size - 1
    # default: clean
    clean = make_psf_field(n_stars=20, n_galaxies=0, image_shape=(400, 500), random_state=0)
    assert set(clean.stars["contaminant"]) == {""} and len(clean.contaminants) == 0


def test_galaxy_contaminants_are_extended(dirty):
    sel = dirty.stars["contaminant"] == "galaxy"
    stamps, flags = dirty.star_stamps()
    ok = sel & (flags == 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sig = np.asarray(adaptive_moments(stamps[ok])["sigma"])
    assert np.median(sig / np.asarray(dirty.stars["sigma"][ok])) > 1.3


@pytest.mark.parametrize("snr", [20.0, 1000.0])
def test_contaminants_detectable_with_the_true_psf(snr):
    """Contaminants raised to 20 sigma (ContaminantSettings.min_snr): with the true PSF, a
    chi^2 cut keeping 98% of the clean stars catches >= 90% of the contaminated ones, at the
    faint and the bright end: the strengthening makes them detectable (a model-based detector's
    target)."""
    f = make_psf_field(n_stars=240, n_galaxies=0, image_shape=SMALL, snr=snr, random_state=5,
                       contaminants=ContaminantSettings(
                           {"cosmic_ray": 0.1, "neighbour": 0.1, "galaxy": 0.1, "binary": 0.1},
                           min_snr=20.0))
    s = f.stamp_size
    chi2 = _true_psf_chi2(f)
    clean = np.asarray(f.stars["contaminant"]) == ""
    cut = np.quantile(chi2[clean], 0.98)
    assert np.mean(chi2[~clean] > cut) >= 0.9
    assert np.median(chi2[clean]) == pytest.approx(s * s, rel=0.1)


def _true_psf_chi2(f):
    raw, w, _ = f.star_stamps(return_weights=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        norm = StampNormalizer().fit_transform(raw)
    resid = (norm - np.asarray(f.stars["stamp"])) * raw.sum(axis=1, keepdims=True)
    return np.sum(resid**2 * w, axis=1)


def test_clean_stars_stay_clean_next_to_contaminants():
    """A dense bright field, half the stars with a neighbour or a galaxy: no contaminant's
    light reaches a clean star's stamp (its chi^2 with the true PSF is that of pure noise;
    without the wider spacing the worst reach chi^2 ~2500)."""
    f = make_psf_field(n_stars=300, n_galaxies=0, image_shape=(900, 900), snr=1000.0,
                       random_state=1, contaminants={"neighbour": 0.25, "galaxy": 0.25})
    chi2 = _true_psf_chi2(f)
    clean = np.asarray(f.stars["contaminant"]) == ""
    s2 = f.stamp_size ** 2
    assert chi2[clean].max() < s2 + 6 * np.sqrt(2 * s2)


# ----------------------------------------------------------------------------- smallest scale
def test_smallest_scale_and_deprecated_grid_size():
    kw = dict(n_stars=20, n_galaxies=0, image_shape=(600, 800), random_state=0)
    f = make_psf_field(**kw)
    assert f.meta["smallest_scale"] == 8.0 and f.meta["cell"] == pytest.approx(40.0)
    g = make_psf_field(smallest_scale=30.0, **kw)
    assert g.meta["cell"] == pytest.approx(150.0)
    # a larger scale gives a smoother PSF pattern: smaller differences between neighbours
    with pytest.warns(DeprecationWarning, match="smallest_scale"):
        old = make_psf_field(grid_size=64, **kw)
    assert old.meta["cell"] == pytest.approx(799 / 63)
    with pytest.raises(ValueError, match="smallest_scale"):
        make_psf_field(smallest_scale=-1.0, **kw)


def test_random_field_covariance_matches_many_seeds():
    """RandomFieldSampler.covariance against the empirical covariance of 600 seeds."""
    shape = (700, 1000)
    pos = np.array([[500, 350], [520, 350], [560, 380], [700, 500], [5, 5], [990, 690],
                    [100, 600], [500.5, 351.3]], dtype=float)
    vals = np.array([RandomFieldSampler(shape, 1, grid_size=40, random_state=s)(pos)[:, 0]
                     for s in range(600)])
    emp = np.cov(vals.T)
    model = RandomFieldSampler(shape, 0, grid_size=40).covariance(pos)
    scale = np.sqrt(np.outer(np.diag(emp), np.diag(emp)))
    assert np.max(np.abs(model - emp) / scale) < 0.15  # statistical error ~0.06
    np.testing.assert_allclose(model, model.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(model) > -1e-8)
    # cross-covariance between two sets = the block of the joint one
    np.testing.assert_allclose(RandomFieldSampler(shape, 0, grid_size=40).covariance(
        pos[:3], pos[3:]), model[:3, 3:], atol=1e-12)


def test_weight_covariance_and_coefficient_noise():
    f = make_psf_field(n_stars=300, n_galaxies=0, image_shape=SMALL, snr=100.0, random_state=8)
    pos = np.column_stack([f.stars["x"], f.stars["y"]])[:4]
    cov = f.weight_covariance(pos, ensemble=True)
    k = RandomFieldSampler(f.image.shape, 0, cell=f.meta["cell"]).covariance(pos)
    np.testing.assert_allclose(cov, f.reference.coeff_std[:, None, None] ** 2 * k[None])
    # given the draw: the same spatial structure per component, scaled by its field's scale
    given = f.weight_covariance(pos)
    scales = np.asarray(f.meta["field_scales"])
    ratio = (given[:, 0, 1] - given[:, 0, 0]) / (given[:, 0, 1] - given[:, 0, 0])[0]
    np.testing.assert_allclose(ratio, (f.reference.coeff_std / scales) ** 2
                               / (f.reference.coeff_std[0] / scales[0]) ** 2, rtol=1e-10)
    # the true coefficient noise against the measured coefficients' scatter about the truth
    m = f.measure_stars()
    err2 = (np.asarray(m["coeffs"]) - np.asarray(f.stars["coeffs"])) ** 2
    ratio = err2.mean(axis=0) / f.coefficient_noise_var().mean(axis=0)
    assert np.all((ratio > 0.8) & (ratio < 1.5)), ratio


@pytest.mark.parametrize("kw", [dict(), dict(detector=DetectorSettings(masked_fraction=0.01,
                                                                        gain=0.5))])
def test_coefficient_noise_cov_matches_noise_draws(kw):
    """The true noise covariance of the weighted least-squares coefficients against 1000
    noise draws of the same stars (S/N 30-300; masked pixels, whose offsets the fit refines,
    and the sources' Poisson noise in the second case)."""
    f = make_psf_field(n_stars=4, n_galaxies=0, image_shape=(300, 300), random_state=1,
                       snr=[30.0, 100.0, 300.0, 100.0], **kw)
    s, k = f.stamp_size, f.reference.n_components
    pos = np.column_stack([f.stars["x"], f.stars["y"]])
    off = pos - np.floor(pos + 0.5)
    clean = fourier_shift(np.asarray(f.stars["stamp"]).reshape(-1, s, s), off[:, 0],
                          off[:, 1]).reshape(4, -1) * np.asarray(f.stars["flux"])[:, None]
    _, w, _ = f.star_stamps(normalize=False, return_weights=True)
    assert (w == 0).any() == bool(kw)
    draws = 1000
    rng = np.random.default_rng(0)
    sd = np.where(w > 0, 1.0 / np.sqrt(np.where(w > 0, w, 1.0)), 0.0)
    noisy = clean[:, None] + rng.standard_normal((4, draws, s * s)) * sd[:, None]
    basis = _stamp_pca_on_basis(f.reference.mean, f.reference.components)
    coef = basis.project(noisy.reshape(4 * draws, -1), np.repeat(w, draws, axis=0))
    coef = coef.coefficients.reshape(4, draws, k)
    true, paper = f.coefficient_noise_cov(), f.coefficient_noise_cov("paper")
    iu = np.triu_indices(k, 1)
    for i in range(4):
        emp = np.cov(coef[i].T)
        ratio = np.diag(emp) / np.diag(true[i])  # standard error of a ratio: 4.5%
        assert np.all((ratio > 0.85) & (ratio < 1.18)), (i, ratio)
        corr = emp / np.sqrt(np.outer(np.diag(emp), np.diag(emp)))
        corr_true = true[i] / np.sqrt(np.outer(np.diag(true[i]), np.diag(true[i])))
        assert np.abs(corr - corr_true)[iu].max() < 0.12  # standard error ~0.03
        # Gauss-Markov: the paper's normalise-and-project is never less noisy, in any
        # direction, than the weighted least-squares fit
        gap = np.linalg.eigvalsh(paper[i] - true[i])
        assert gap.min() > -1e-8 * gap.max() and np.trace(paper[i]) > 1.3 * np.trace(true[i])
    np.testing.assert_allclose(f.coefficient_noise_var(), np.einsum("nkk->nk", paper))
    with pytest.raises(ValueError, match="measurement"):
        f.coefficient_noise_cov("exact")


# ----------------------------------------------------------------------------- reference basis
def _moffat_star_image(n=36, size=700, seed=0):
    galsim = pytest.importorskip("galsim")
    rng = np.random.default_rng(seed)
    g = np.linspace(60, size - 61, int(np.sqrt(n)))
    gx, gy = np.meshgrid(g, g)
    pos = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-5, 5, (n, 2))
    image = galsim.ImageD(size, size, scale=0.2)
    for x, y in pos:
        psf = galsim.Moffat(beta=3.0, fwhm=0.8).shear(
            g1=0.03 * (x / size - 0.5), g2=0.03 * (y / size - 0.5)).withFlux(2e5)
        # galsim pixel (1, 1) is numpy [0, 0]: the profile centre at 0-based (x, y)
        psf.drawImage(image=image, center=galsim.PositionD(x + 1, y + 1), add_to_image=True)
    arr = image.array + rng.normal(0.0, 5.0, (size, size))
    return arr, pos


def test_from_image_recovers_stars_and_basis():
    image, pos = _moffat_star_image()
    image0 = image.copy()
    ref = ReferenceBasis.from_image(image, stamp_size=21)
    np.testing.assert_array_equal(image, image0)
    assert len(ref.positions) == len(pos)
    d, _ = cKDTree(pos).query(ref.positions)
    assert d.max() < 0.1
    # the basis rebuilds the stars: residual small compared with the stamps
    from sklearn_psf.preprocessing import StampNormalizer, cut_stamps

    stamps, _ = cut_stamps(image, ref.positions, 21)
    norm = StampNormalizer().fit_transform(stamps.reshape(len(stamps), -1))
    basis = ref.as_transformer(normalize=False)
    rebuilt = basis.inverse_transform(basis.transform(norm))
    assert np.abs(rebuilt - norm).max() < 0.05 * norm.max()
    assert abs(ref.noise_rms - 5.0) < 0.5
    assert ref.image_shape == image.shape


def test_from_stamps_save_load_and_transformer(tmp_path):
    y, x = np.mgrid[0:15, 0:15] - 7.0
    rng = np.random.default_rng(0)
    q = rng.normal(0.0, 0.2, (40, 1, 1))
    r = rng.normal(0.0, 0.2, (40, 1, 1))
    stars = np.exp(-0.5 * ((2 + q) * x**2 + (2 - q) * y**2 + 2 * r * x * y) / 4.0)
    ref = ReferenceBasis.from_stamps(stars, variance=0.99)
    assert ref.n_components >= 2
    np.testing.assert_allclose(ref.components.reshape(ref.n_components, -1)
                               @ ref.components.reshape(ref.n_components, -1).T,
                               np.eye(ref.n_components), atol=1e-10)
    ref.save(tmp_path / "ref.fits")
    back = ReferenceBasis.load(tmp_path / "ref.fits")
    np.testing.assert_array_equal(back.components, ref.components)
    np.testing.assert_array_equal(back.coeff_std, ref.coeff_std)
    pipe = back.as_transformer()
    coeffs = pipe.transform(stars.reshape(40, -1) * 3.0)  # flux does not matter
    np.testing.assert_allclose(coeffs.std(axis=0, ddof=1), ref.coeff_std, rtol=1e-6)


# ----------------------------------------------------------------------------- bad input
def test_bad_inputs(tmp_path):
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 1, (300, 300))
    with pytest.raises(ValueError, match="stars"):
        ReferenceBasis.from_image(noise)
    nan_img = noise.copy()
    nan_img[5, 5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ReferenceBasis.from_image(nan_img)
    bad = tmp_path / "corrupt.fits"
    bad.write_bytes(b"this is not a FITS file" * 50)
    with pytest.raises(ValueError, match="FITS"):
        ReferenceBasis.from_image(bad)
    with pytest.raises(ValueError, match="FITS"):
        ReferenceBasis.load(bad)
    with pytest.raises(ValueError, match="FITS|field"):
        PSFField.load(bad)
    with pytest.raises(ValueError, match="too large"):
        ReferenceBasis.from_image(noise[:20, :20])
    kw = dict(n_galaxies=0, image_shape=(400, 400))
    with pytest.raises(ValueError, match="off the image"):
        make_psf_field(star_positions=[[5.0, 200.0], [200.0, 200.0]], **kw)
    with pytest.raises(ValueError, match="n_stars"):
        make_psf_field(n_stars=0, **kw)
    with pytest.raises(ValueError, match="snr"):
        make_psf_field(n_stars=3, snr=0.0, **kw)
    with pytest.raises(ValueError, match="snr"):
        make_psf_field(n_stars=3, snr=[10.0, -1.0, 5.0], **kw)
    with pytest.raises(ValueError, match="larger than the image"):
        make_psf_field(n_stars=3, n_galaxies=0, image_shape=(20, 400))
    with pytest.raises(ValueError, match="non-overlapping"):
        make_psf_field(n_stars=1000, **kw)
    with pytest.raises(ValueError, match="galaxy_layout"):
        make_psf_field(n_stars=3, galaxy_layout="hexagonal", **kw)
    with pytest.raises(ValueError, match="Unknown contaminant"):
        make_psf_field(n_stars=3, contaminants={"satellite": 0.1}, **kw)
    with pytest.raises(ValueError, match="add up"):
        make_psf_field(n_stars=3, contaminants={"binary": 0.6, "galaxy": 0.6}, **kw)
    with pytest.raises(TypeError, match="dict"):
        make_psf_field(n_stars=3, contaminants=["binary"], **kw)
    with pytest.raises(ValueError, match="masked_fraction"):
        DetectorSettings(masked_fraction=1.5)
    with pytest.raises(ValueError, match="gain"):
        DetectorSettings(gain=0.0)
    with pytest.raises(ValueError, match="bad_columns"):
        make_psf_field(n_stars=3, detector=DetectorSettings(bad_columns=10**6), **kw)
    with pytest.raises(TypeError, match="DetectorSettings"):
        make_psf_field(n_stars=3, detector={"gain": 2.0}, **kw)
    snr = np.array([50.0, 60.0, 70.0])
    make_psf_field(n_stars=3, snr=snr, random_state=0, **kw)
    np.testing.assert_array_equal(snr, [50.0, 60.0, 70.0])
