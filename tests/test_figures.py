"""``fit``'s figures read as they should: the wings of the stamps, a colour scale per residual,
colour bars of the variation, error bars inside their log axes, panels of the field's shape."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from astropy.table import Table  # noqa: E402

from sklearn_psf.validation import (  # noqa: E402
    plot_psf_maps,
    plot_rho_statistics,
    plot_stamp_residuals,
    plot_whiskers,
)


def _gaussian(sigma, side=31, e1=0.0):
    yy, xx = np.mgrid[0:side, 0:side] - side // 2
    g = np.exp(-0.5 * ((1 - e1) * xx**2 + (1 + e1) * yy**2) / sigma**2)
    return (g / g.sum()).ravel()


def test_stamps_relative_to_each_peak_with_a_residual_scale_each():
    """A faint star (2% residuals) beside a bright one (0.01%): each residual keeps its own
    colour limits; stars and models are drawn over their model's peak on an asinh stretch."""
    rng = np.random.default_rng(0)
    model = _gaussian(2.0)
    noisy = model + rng.normal(0, 0.02 * model.max(), model.size)
    clean = model + rng.normal(0, 1e-4 * model.max(), model.size)
    t = Table({"x": [10.0, 20.0], "y": [5.0, 8.0], "stamp_star": [noisy, clean],
               "stamp_model": [model, model]})
    fig = plot_stamp_residuals(t)
    images = [ax.get_images()[0] for ax in fig.axes[:6]]  # rows of 2 (star, model, resid)
    star_img = images[0].get_array()
    assert star_img.max() == pytest.approx(noisy.max() / model.max())
    assert type(images[0].norm).__name__ == "AsinhNorm"
    limits = [images[4 + j].get_clim()[1] for j in range(2)]
    # in % of the peak: the noisy star's 99.5th percentile, about 2.8 x 2%; the clean one's
    assert 3.0 < limits[0] < 8.0 and 0.01 < limits[1] < 0.05
    plt.close(fig)


def test_maps_colour_bar_shows_the_size_variation():
    """A size varying by 5e-4 px around 1.85 px: the colour bar is the variation in % of the
    median (ticks of order 0.01, no offset), not the size around a '+1.85' offset."""
    class Model:
        X_fit_ = np.array([[100.0, 100.0], [1900.0, 3900.0]])

        def predict(self, X):
            sig = 1.85 + 5e-4 * (np.asarray(X)[:, 0] / 2048 - 0.5)
            return np.array([_gaussian(s, 25) for s in sig])

    fig = plot_psf_maps(Model(), (4096, 2048), n_grid=8)
    fig.canvas.draw()
    image = fig.axes[1].get_images()[0].get_array()
    assert 0.005 < np.nanmax(np.abs(image)) < 0.05      # in %: +-2.5e-4 / 1.85 = 0.0135%
    bar = fig.axes[2]
    assert bar.yaxis.get_offset_text().get_text() == ""
    assert "median 1.850 px" in bar.get_ylabel()
    plt.close(fig)


def test_rho_error_bars_stay_inside_the_log_axes():
    """A value whose error bar crosses 0: its lower bar ends at the axis' bottom, which is
    set by the values (not by a bar going to -infinity)."""
    r = {"theta": [10.0, 30.0, 100.0], "xi": [2e-5, -1e-6, 4e-7], "sigma_xi": [1e-6, 5e-6,
                                                                                1e-7]}
    fig = plot_rho_statistics({f"rho{k}": r for k in range(1, 6)})
    ax = fig.axes[0]
    bottom, top = ax.get_ylim()
    assert bottom == pytest.approx(4e-7 / 4) and top == pytest.approx((2e-5 + 1e-6) * 1.5)
    for line in ax.collections:  # the error bars
        for segment in line.get_segments():
            assert segment[:, 1].min() >= bottom * 0.999
    plt.close(fig)


@pytest.mark.parametrize("shape", [(4096, 2048), (1000, 3000)])
def test_whisker_panels_have_the_fields_shape(shape):
    """Tall or wide fields: the three panels sit close together (no wide gaps)."""
    rng = np.random.default_rng(1)
    n = 40
    t = Table({"x": rng.uniform(0, shape[1], n), "y": rng.uniform(0, shape[0], n),
               "e1_star": rng.normal(0, 0.03, n), "e2_star": rng.normal(0, 0.03, n),
               "e1_model": rng.normal(0, 0.03, n), "e2_model": rng.normal(0, 0.03, n),
               "flag": np.zeros(n, int)})
    fig = plot_whiskers(t)
    fig.canvas.draw()
    boxes = [ax.get_position() for ax in fig.axes[:3]]
    gaps = [boxes[k + 1].x0 - boxes[k].x1 for k in range(2)]
    assert max(gaps) < 0.06, gaps
    plt.close(fig)
