"""Gaussian random fields with a power-law power spectrum.

The PSF of the simulations varies across the field because the weight of every principal
component follows a Gaussian random field with power spectrum P(k) ~ k^-slope (Rowe 2010;
Berge et al. 2012, section 3; slope 11/4 for Kolmogorov-like atmospheric turbulence).
"""

from __future__ import annotations

import numbers
from functools import lru_cache

import numpy as np
from scipy import ndimage

__all__ = ["gaussian_random_field", "RandomFieldSampler", "as_generator"]


def as_generator(random_state) -> np.random.Generator:
    """Return a :class:`numpy.random.Generator` for ``random_state``.

    Parameters
    ----------
    random_state : None, int, numpy.random.SeedSequence, numpy.random.Generator or \
numpy.random.RandomState
        None draws fresh entropy from the operating system; an int or a SeedSequence gives a
        reproducible generator; a Generator is used as is (and advanced); a legacy
        RandomState (what :func:`sklearn.utils.check_random_state` returns) seeds a new
        Generator from one draw of its stream.

    Returns
    -------
    rng : numpy.random.Generator

    Examples
    --------
    >>> from sklearn_psf.simulate import as_generator
    >>> bool(as_generator(0).integers(10) == as_generator(0).integers(10))
    True
    """
    if isinstance(random_state, np.random.Generator):
        return random_state
    if isinstance(random_state, np.random.RandomState):
        return np.random.default_rng(random_state.randint(0, 2**32 - 1, dtype=np.uint64))
    if random_state is None or isinstance(random_state, (numbers.Integral, np.random.SeedSequence)):
        if isinstance(random_state, numbers.Integral) and random_state < 0:
            raise ValueError(f"random_state must be a non-negative integer, got {random_state}.")
        return np.random.default_rng(random_state)
    raise TypeError(
        "random_state must be None, an int, a numpy SeedSequence, Generator or RandomState; "
        f"got {type(random_state).__name__}."
    )


def _check_shape(shape) -> tuple[int, int]:
    try:
        shape = tuple(int(n) for n in shape)
    except TypeError:
        raise TypeError(f"shape must be a pair of integers (ny, nx), got {shape!r}.") from None
    if len(shape) != 2 or min(shape) < 2:
        raise ValueError(f"shape must be a pair (ny, nx) of integers >= 2, got {shape}.")
    return shape


def random_field_power(shape, slope: float = 11 / 4) -> np.ndarray:
    """Power spectrum P(k) ~ k^-slope on the FFT grid of ``shape``, normalised to mean 1.

    P(0) = 0 (zero-mean field). With this normalisation, white noise filtered by sqrt(P) has
    unit expected variance, and ``numpy.fft.ifft2(P).real`` is the field's covariance as a
    function of the (periodic) lag, with C(0) = 1.

    Parameters
    ----------
    shape : tuple of int
        (ny, nx) of the grid (the padded grid of :func:`gaussian_random_field`).
    slope : float
        Minus the logarithmic slope of the spectrum.

    Returns
    -------
    power : ndarray of shape ``shape``
        In numpy's FFT frequency order.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.simulate import random_field_power
    >>> p = random_field_power((32, 48))
    >>> float(p[0, 0]), round(float(p.mean()), 12), round(float(np.fft.ifft2(p).real[0, 0]), 12)
    (0.0, 1.0, 1.0)
    """
    ny, nx = _check_shape(shape)
    k = np.hypot(np.fft.fftfreq(ny)[:, None], np.fft.fftfreq(nx)[None, :])
    power = np.zeros_like(k)
    power[k > 0] = k[k > 0] ** (-float(slope))
    return power / power.mean()


def gaussian_random_field(
    shape,
    slope: float = 11 / 4,
    random_state=None,
    *,
    padding: float = 2.0,
    normalize: bool = True,
) -> np.ndarray:
    """Draw a 2-D Gaussian random field with power spectrum P(k) ~ k^-slope.

    White Gaussian noise on a grid ``padding`` times larger than ``shape`` (in each
    direction) is Fourier transformed, multiplied by ``k^(-slope/2)`` (the k = 0 mode is set
    to zero) and transformed back; the ``shape`` corner of the result is returned. Because the
    FFT makes the padded field periodic, cropping it removes the periodic artefacts (the
    field's opposite edges are not forced to match).

    Parameters
    ----------
    shape : tuple of two ints
        (ny, nx) of the returned grid.
    slope : float, default=11/4
        Minus the logarithmic slope of the power spectrum. Must be >= 0.
    random_state : None, int, SeedSequence or Generator, default=None
        Seed of the draw; the same seed gives the same field. See :func:`as_generator`.
    padding : float, default=2.0
        Size of the generation grid relative to ``shape`` (>= 1).
    normalize : bool, default=True
        Subtract the mean and divide by the standard deviation of the returned grid so that
        the realisation has exactly zero mean and unit variance. Without it the field has
        zero expected mean and unit expected variance over the padded grid, but a single
        realisation of a red spectrum fluctuates a lot (the largest modes dominate).

    Returns
    -------
    field : ndarray of shape ``shape``, float64

    Examples
    --------
    >>> from sklearn_psf.simulate import gaussian_random_field
    >>> f = gaussian_random_field((64, 80), random_state=0)
    >>> f.shape, round(float(f.mean()), 6), round(float(f.std()), 6)
    ((64, 80), 0.0, 1.0)
    """
    ny, nx = _check_shape(shape)
    slope = float(slope)
    if not np.isfinite(slope) or slope < 0:
        raise ValueError(f"slope must be a finite number >= 0, got {slope}.")
    if not padding >= 1:
        raise ValueError(f"padding must be >= 1, got {padding}.")
    rng = as_generator(random_state)
    py, px = int(np.ceil(ny * padding)), int(np.ceil(nx * padding))
    white = rng.standard_normal((py, px))
    # the rfft half-plane of the full spectrum: same |k| on the first px // 2 + 1 columns
    amplitude = np.sqrt(random_field_power((py, px), slope)[:, : px // 2 + 1])
    field = np.fft.irfft2(np.fft.rfft2(white) * amplitude, s=(py, px))[:ny, :nx]
    if normalize:
        field = field - field.mean()
        std = field.std()
        if std > 0:
            field /= std
    return np.ascontiguousarray(field)


class RandomFieldSampler:
    """Gaussian random fields on a coarse grid covering an image, evaluated anywhere.

    One independent field with power spectrum P(k) ~ k^-slope is drawn per component on a
    grid of square cells of side ``cell`` pixels (default: ``grid_size`` nodes along the longer
    side of the image; the nodes span the image from pixel 0 to pixel n-1) and evaluated at
    arbitrary positions by cubic-spline interpolation. The cell sets the smallest scale of
    variation of the field (no power at wavelengths below two cells).
    :func:`~sklearn_psf.simulate.make_psf_field` sets the cell from a physical scale
    (``smallest_scale``, 8 arcsec by default).

    Parameters
    ----------
    image_shape : tuple of two ints
        (ny, nx) of the image in pixels.
    n_fields : int, default=1
        Number of independent fields (one per PCA component).
    slope : float, default=11/4
        Minus the power-spectrum slope.
    grid_size : int, default=256
        Number of grid nodes along the longer side of the image (ignored when ``cell`` is
        given).
    random_state : None, int, SeedSequence or Generator, default=None
        Seed; the fields are drawn one after the other from this generator.
    cell : float, optional
        Grid spacing in pixels (> 0).

    Attributes
    ----------
    grids : ndarray of shape (n_fields, gy, gx)
        The fields on the grid, each with zero mean and unit variance over the grid.
    scales : ndarray of shape (n_fields,)
        Standard deviation of each drawn field over the grid before that normalisation.
    cell : float
        Grid spacing in pixels.
    slope : float

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.simulate import RandomFieldSampler
    >>> s = RandomFieldSampler((1500, 2000), n_fields=3, random_state=1)
    >>> s.grids.shape
    (3, 193, 256)
    >>> s(np.array([[0.0, 0.0], [1999.0, 1499.0]])).shape
    (2, 3)
    >>> k = s.covariance(np.array([[100.0, 100.0], [1000.0, 700.0]]))
    >>> k.shape, bool(k[0, 0] > k[0, 1])
    ((2, 2), True)
    """

    def __init__(self, image_shape, n_fields=1, slope=11 / 4, grid_size=256, random_state=None,
                 *, cell=None):
        ny, nx = _check_shape(image_shape)
        if int(n_fields) < 0:
            raise ValueError(f"n_fields must be >= 0, got {n_fields}.")
        self.image_shape = (ny, nx)
        self.slope = float(slope)
        if cell is None:
            if int(grid_size) < 4:
                raise ValueError(f"grid_size must be >= 4, got {grid_size}.")
            cell = (max(ny, nx) - 1) / (int(grid_size) - 1)
        elif not (np.isfinite(cell) and cell > 0):
            raise ValueError(f"cell must be a positive number of pixels, got {cell}.")
        self.cell = max(float(cell), 1e-12)
        gy = max(int(np.ceil((ny - 1) / self.cell)) + 1, 4)
        gx = max(int(np.ceil((nx - 1) / self.cell)) + 1, 4)
        rng = as_generator(random_state)
        raw = [gaussian_random_field((gy, gx), slope, rng, normalize=False)
               for _ in range(int(n_fields))]
        # normalised as gaussian_random_field(normalize=True) does; the scales are kept
        self.scales = np.array([(g - g.mean()).std() for g in raw])
        self.grids = np.stack([(g - g.mean()) / s for g, s in zip(raw, self.scales)]
                              ) if raw else np.zeros((0, gy, gx))
        # spline coefficients once, evaluation without prefiltering afterwards
        self._coeffs = [ndimage.spline_filter(g, order=3, mode="nearest") for g in self.grids]
        self._cov = None

    def __call__(self, positions) -> np.ndarray:
        """Values of every field at ``positions`` (n, 2) of (x, y) pixels: shape (n, n_fields)."""
        coords = self._node_coords(positions)
        out = np.empty((coords.shape[1], len(self._coeffs)))
        for i, c in enumerate(self._coeffs):
            out[:, i] = ndimage.map_coordinates(c, coords, order=3, mode="nearest", prefilter=False)
        return out

    def _node_coords(self, positions):
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise ValueError(f"positions must have shape (n, 2), got {pos.shape}.")
        if not np.all(np.isfinite(pos)):
            raise ValueError("positions hold NaN or infinite values.")
        return np.stack([pos[:, 1] / self.cell, pos[:, 0] / self.cell])

    def covariance(self, positions_a, positions_b=None, *, field=None) -> np.ndarray:
        """Covariance of the fields between positions (the truth for an oracle).

        With ``field=None``, the ensemble covariance, the same for every field: the one
        implied by the power spectrum, the grid and the cubic-spline interpolation, over
        realisations, after the per-realisation normalisation of the grid (zero mean, unit
        variance):

        ``K(a, b) = (T(b - a) - c(a) - c(b) + v) / (1 - v)``

        where T is the covariance of the interpolated field at lag b - a (the spline's
        transfer function applied to the padded grid's spectrum, averaged over the position
        within a cell), c(a) the covariance of the field at a with the grid mean (exact:
        spline interpolation of the node values) and v the variance of the grid mean.
        Approximations: T ignores the spline's boundary handling (within ~2 cells of the
        image edges) and the division by the realised standard deviation is replaced by the
        division by its expectation; both are tested to a few per cent against the empirical
        covariance of many seeds.

        With ``field=i``, the covariance given the normalisation of the drawn field i (its
        grid mean and its scale ``scales[i]``, which this draw fixed):
        ``(T(b - a) - c(a) c(b) / v) / scales[i]^2``. This is the covariance a best linear
        predictor of this realisation should use: the ensemble one misjudges the amplitude
        of the small scales of one draw (by 1 / scale^2, a factor ~0.5-2 from draw to draw).

        Parameters
        ----------
        positions_a : array-like of shape (n_a, 2)
            (x, y) pixel positions.
        positions_b : array-like of shape (n_b, 2), optional
            Default ``positions_a``.
        field : int, optional
            Index of a drawn field (see above).

        Returns
        -------
        cov : ndarray of shape (n_a, n_b)
        """
        if field is not None and not 0 <= int(field) < len(self.scales):
            raise ValueError(f"field must be the index of one of the {len(self.scales)} drawn "
                             f"fields, got {field!r}.")
        ca = self._node_coords(positions_a)
        cb = ca if positions_b is None else self._node_coords(positions_b)
        if self._cov is None:
            self._cov = _interpolated_covariance(tuple(self.grids.shape[1:]), float(self.slope))
        table, q, mean_cov, var_mean = self._cov
        gy, gx = self.grids.shape[1:]
        ma = ndimage.map_coordinates(mean_cov, ca, order=3, mode="nearest", prefilter=False)
        mb = ma if positions_b is None else ndimage.map_coordinates(
            mean_cov, cb, order=3, mode="nearest", prefilter=False)
        out = np.empty((ca.shape[1], cb.shape[1]))
        for start in range(0, ca.shape[1], 256):  # rows in blocks: bounded memory
            sl = slice(start, start + 256)
            dy = (cb[0][None, :] - ca[0][sl, None] + gy - 1) * q
            dx = (cb[1][None, :] - ca[1][sl, None] + gx - 1) * q
            lag = ndimage.map_coordinates(table, np.stack([dy.ravel(), dx.ravel()]), order=1,
                                          mode="nearest").reshape(dy.shape)
            if field is None:
                out[sl] = lag - ma[sl, None] - mb[None, :] + var_mean
            else:
                out[sl] = lag - ma[sl, None] * mb[None, :] / var_mean
        if field is None:
            return out / (1.0 - var_mean)
        return out / self.scales[field] ** 2


def _beta7(t):
    """Degree-7 central B-spline (the autocorrelation of the cubic one)."""
    from scipy.interpolate import BSpline

    return np.nan_to_num(BSpline.basis_element(np.arange(9) - 4.0, extrapolate=False)(t))


@lru_cache(maxsize=4)  # the same for every field of a grid shape: computed once per process
def _interpolated_covariance(grid_shape, slope, q=4):
    """Lag table of the interpolated field's covariance, grid-mean terms (see covariance)."""
    gy, gx = grid_shape
    py, px = int(np.ceil(gy * 2.0)), int(np.ceil(gx * 2.0))  # gaussian_random_field's padding
    power = random_field_power((py, px), slope)
    cov_grid = np.fft.ifft2(power).real
    prefilter = [1.0 / (2.0 / 3.0 + np.cos(2 * np.pi * np.fft.fftfreq(n)) / 3.0) for n in (py, px)]
    cov_coef = np.fft.ifft2(power * (prefilter[0][:, None] * prefilter[1][None, :]) ** 2).real
    mats = []
    for g, p in ((gy, py), (gx, px)):
        lags = np.arange(-(g - 1) * q, (g - 1) * q + 1) / q
        ints = np.arange(-(g + 3), g + 4)
        mats.append((_beta7(lags[:, None] - ints[None, :]), ints % p))
    (by, iy), (bx, ix) = mats
    table = by @ cov_coef[np.ix_(iy, ix)] @ bx.T
    # covariance of each node with the grid mean (circular: exact on the periodic padded grid)
    ones = np.zeros((py, px))
    ones[:gy, :gx] = 1.0 / (gy * gx)
    mean_nodes = np.fft.ifft2(np.fft.fft2(cov_grid) * np.fft.fft2(ones)).real[:gy, :gx]
    mean_cov = ndimage.spline_filter(mean_nodes, order=3, mode="nearest")
    table.flags.writeable = mean_cov.flags.writeable = False  # shared by the cache
    return table, q, mean_cov, float(mean_nodes.mean())
