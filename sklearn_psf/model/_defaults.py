"""The default parts of a PSF model (noise-aware) and the paper's (noise-blind) ones."""

from __future__ import annotations

from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler

from ..interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    IsotropicScaler,
    KrigingRegressor,
    PolynomialRegressor,
    RBFRegressor,
    ShepardRegressor,
)
from ..preprocessing import StampNormalizer, StampPCA

__all__ = ["make_default_basis", "make_default_interpolator", "make_paper_basis",
           "make_paper_interpolator", "make_interpolator", "INTERPOLATORS"]


def make_default_basis():
    """The default stamp basis: :class:`~sklearn_psf.preprocessing.StampPCA`.

    Weighted PCA of the raw star stamps with as many components as stand above the noise,
    and weighted-least-squares coefficients with their noise variance (masked pixels
    excluded). See :func:`make_paper_basis` for the paper's noise-blind basis.

    Returns
    -------
    basis : StampPCA

    Examples
    --------
    >>> from sklearn_psf.model import make_default_basis
    >>> make_default_basis()
    StampPCA()
    """
    return StampPCA()


def make_paper_basis():
    """The paper's basis: ``make_pipeline(StampNormalizer(), PCA(n_components=0.9))``.

    PCA keeps 90% of the variance (Berge et al. 2012) with ``svd_solver="full"``
    (deterministic). On noisy stars the noise holds most of the variance, and this basis then
    keeps hundreds of components: use it for the paper's study, not for real data.

    Returns
    -------
    basis : sklearn.pipeline.Pipeline

    Examples
    --------
    >>> from sklearn_psf.model import make_paper_basis
    >>> list(make_paper_basis().named_steps)
    ['stampnormalizer', 'pca']
    """
    from sklearn.decomposition import PCA  # (here: its import costs a fit command ~0.04 s)

    return make_pipeline(StampNormalizer(), PCA(n_components=0.9, svd_solver="full"))


def make_default_interpolator():
    """The default interpolator: positions scaled by the field's longer side, then Kriging whose
    range and sills are fitted to the data, with each star's coefficient noise.

    ``make_pipeline(IsotropicScaler(n_positions=2), KrigingRegressor(range="auto",
    drift="auto", n_neighbors="auto", extra_scaling="auto", extra_drift="linear"))``:
    the same factor on x and y (:class:`~sklearn_psf.interpolate.IsotropicScaler`), so that
    the isotropic variogram sees the field's own distances (``MinMaxScaler`` stretches the
    shorter side of a rectangular field to the longer one's length: on the package's default
    field, 10,032 x 7,769 pixels, the ellipticity error at the galaxies was then larger, see
    ``benchmarks/README.md``); exact Kriging up to 1000 stars, local Kriging from each
    query's 30 nearest stars beyond (hyperparameters by Vecchia's nearest-neighbour
    likelihood there), so that a focal plane of 10^4-10^5 stars is one model; the range and the
    coefficients' signal covariance by maximum likelihood over all coefficients at once, on
    all the stars; each star's coefficient noise covariance (propagated from its pixel weights
    by the basis and passed by :class:`~sklearn_psf.model.PSFModel` as ``noise_cov``: the
    coefficients are co-Kriged) enters the Kriging system as a measurement error, so that
    faint stars count less than bright ones and the model does not pass through noisy
    stars. The nugget stays 0 and the noise is taken as propagated (``noise_scale=1``):
    fitting them as well (``nugget="auto", noise_scale="auto"``) gave larger ellipticity
    errors at the galaxies on the package's simulations (``benchmarks/README.md``); both
    remain available. The mean over the field (the drift) is constant, linear or quadratic in
    the positions, whichever the likelihood's Bayesian information criterion prefers
    (``drift="auto"``): a smooth variation over the field, such as a CCD's optics give, is
    then a quadratic mean, and the Kriging only models what is left (with a constant mean the
    likelihood stretches the range far beyond the field to follow the trend, and the
    predicted PSF size follows the stars' noise: measured by ``benchmarks/bench_psfex.py``);
    on stationary fields (the package's simulations) it keeps the constant mean. Pass the
    pipeline explicitly to
    ``PSFModel(interpolator=...)`` to tune nested parameters
    (``interpolator__krigingregressor__range``).

    Columns of ``X`` beyond (x, y) (a colour, a magnitude, a flux: the model's extra
    dimensions) are each scaled by their own span (``IsotropicScaler(n_positions=2)``), get
    one correlation length each by maximum likelihood (``extra_scaling="auto"``: a dimension
    with no effect gets a length far beyond its span and changes nothing) and a linear trend
    (``extra_drift="linear"``: universal Kriging's drift, so that a galaxy bluer or fainter
    than every star gets the trend extrapolated, not the mean). On (x, y) alone these
    settings change nothing: the model is the position-only one.

    Returns
    -------
    interpolator : sklearn.pipeline.Pipeline

    Examples
    --------
    >>> from sklearn_psf.model import make_default_interpolator
    >>> make_default_interpolator()[-1]
    KrigingRegressor(drift='auto', extra_drift='linear', extra_scaling='auto',
                     n_neighbors='auto', range='auto')
    """
    return make_pipeline(IsotropicScaler(n_positions=2),
                         KrigingRegressor(range="auto", drift="auto", n_neighbors="auto",
                                          extra_scaling="auto", extra_drift="linear"))


def make_paper_interpolator():
    """The paper's interpolator: ``MinMaxScaler`` + exponential Kriging, range 0.5, nugget 0.

    Returns
    -------
    interpolator : sklearn.pipeline.Pipeline

    Examples
    --------
    >>> from sklearn_psf.model import make_paper_interpolator
    >>> make_paper_interpolator()[-1]
    KrigingRegressor()
    """
    return make_pipeline(MinMaxScaler(),
                         KrigingRegressor(variogram="exponential", range=0.5, nugget=0.0))


#: Interpolation schemes by name for real data (:func:`make_interpolator`): Kriging is
#: :func:`make_default_interpolator`; the polynomial with its degree chosen from the data (BIC,
#: at most 8) and Chebyshev polynomials of degree 5 (the paper's best), behind a
#: ``MinMaxScaler`` (their domain is the unit square); Delaunay, Shepard with p = 3 and a
#: thin-plate spline RBF smoothed by each star's noise, which work on distances, behind an
#: :class:`~sklearn_psf.interpolate.IsotropicScaler`.
INTERPOLATORS = ("kriging", "polynomial", "chebyshev", "delaunay", "shepard", "rbf")


def make_interpolator(name: str = "kriging"):
    """An unfitted interpolator for real data, by scheme name.

    The schemes of the paper with settings that suit noisy stars (see :data:`INTERPOLATORS`);
    ``PSFModel(interpolator=make_interpolator(name))`` is what ``sklearn-psf fit
    --interpolator NAME`` fits. The paper's own settings are in
    :func:`sklearn_psf.study.compare.default_schemes`.

    Parameters
    ----------
    name : {"kriging", "polynomial", "chebyshev", "delaunay", "shepard", "rbf"}

    Returns
    -------
    interpolator : sklearn.pipeline.Pipeline

    Examples
    --------
    >>> from sklearn_psf.model import make_interpolator
    >>> make_interpolator("polynomial")[-1]
    PolynomialRegressor(degree='auto')
    """
    makers = {
        "kriging": make_default_interpolator,
        "polynomial": lambda: make_pipeline(MinMaxScaler(), PolynomialRegressor(degree="auto")),
        "chebyshev": lambda: make_pipeline(MinMaxScaler(), ChebyshevRegressor(degree=5)),
        "delaunay": lambda: make_pipeline(IsotropicScaler(n_positions=2), DelaunayRegressor()),
        "shepard": lambda: make_pipeline(IsotropicScaler(n_positions=2),
                                         ShepardRegressor(power=3.0)),
        "rbf": lambda: make_pipeline(IsotropicScaler(n_positions=2),
                                     RBFRegressor(kernel="thin_plate_spline")),
    }
    if name not in makers:
        raise ValueError(f"Unknown interpolator {name!r}: choose one of {list(INTERPOLATORS)}.")
    return makers[name]()


def _constant_interpolator():
    """A PSF constant over the field: the noise-weighted mean of the coefficients (what
    :class:`~sklearn_psf.model.PSFModel` fits when the stars are too few for its
    interpolator)."""
    return make_pipeline(MinMaxScaler(), PolynomialRegressor(degree=0))
