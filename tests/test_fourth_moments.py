"""Fourth moments (spin 0, 2 and 4) against PIFF's ``piff.util.calculate_moments``."""

import numpy as np
import pytest

from sklearn_psf.measure import FOURTH_MOMENTS, adaptive_moments, fourth_moments

galsim = pytest.importorskip("galsim")
piff = pytest.importorskip("piff")


def _stamps(n=6, s=25, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        psf = galsim.Kolmogorov(fwhm=rng.uniform(0.7, 1.1)).shear(
            g1=rng.uniform(-0.08, 0.08), g2=rng.uniform(-0.08, 0.08)).shift(
            *rng.uniform(-0.08, 0.08, 2))
        img = psf.drawImage(nx=s, ny=s, scale=0.2).array
        out.append(img + rng.normal(0, noise, img.shape))
    return np.array(out)


@pytest.mark.parametrize("noise", [0.0, 2e-4])
def test_fourth_moments_match_piff(noise):
    stamps = _stamps(noise=noise)
    ours = fourth_moments(stamps)
    for i, arr in enumerate(stamps):
        image = galsim.Image(arr, scale=1.0)  # pixel units, as ours
        weight = galsim.Image(np.ones_like(arr), scale=1.0)
        star = piff.Star(piff.StarData(image, image.true_center, weight=weight), None)
        ref = piff.util.calculate_moments(star, fourth_order=True)
        for name in FOURTH_MOMENTS:
            # 1e-4 of the stamp's M22 (the spin-2 and spin-4 moments are smaller): measured
            # ~2e-7, the adaptive weights agreeing to ~1e-8
            assert ours[name][i] == pytest.approx(ref[name], abs=1e-4 * ref["M22"])


def test_fourth_moments_given_adaptive_moments_and_bad_rows():
    stamps = _stamps(n=3)
    stamps[1] = 0.0  # no flux: flagged by adaptive_moments, NaN here
    mom = adaptive_moments(stamps)
    t = fourth_moments(stamps.reshape(3, -1), moments=mom)
    assert np.isnan(t["M22"][1]) and np.isfinite(t["M22"][[0, 2]]).all()
    np.testing.assert_allclose(t["M31"][[0, 2]], fourth_moments(stamps[[0, 2]])["M31"])
    with pytest.raises(ValueError, match="rows"):
        fourth_moments(stamps, moments=mom[:2])


def test_residual_table_holds_fourth_moment_residuals():
    from sklearn_psf.validation import measure_residuals

    stamps = _stamps(n=12, noise=1e-5, seed=1)
    truth = _stamps(n=12, seed=1)
    pred = truth / truth.sum(axis=(1, 2), keepdims=True)
    X = np.random.default_rng(0).uniform(0, 1000, (12, 2))
    table, summary = measure_residuals(X, stamps, pred.reshape(12, -1),
                                       weights=np.full((12, 625), 1e10))
    # the star (noise 1e-5 of a unit-sum... peak ~0.04) against its own noiseless model
    ref = fourth_moments(pred)["M22"]
    assert np.all(np.abs(table["dM22"]) < 1e-2 * ref)
    assert summary["dM22_rms"] < 1e-2 * np.mean(ref)
    assert np.isfinite(summary["dM4_spin2_rms"])
