"""Gaussian random fields with a power-law power spectrum.

The PSF of the simulations varies across the field because the weight of every principal
component follows a Gaussian random field with power spectrum P(k) ~ k^-slope (Rowe 2010;
Berge et al. 2012, section 3; slope 11/4 for Kolmogorov-like atmospheric turbulence).
"""

from __future__ import annotations

import numbers

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
    grid of ``grid_size`` cells along the longer side of the image (square cells, the other
    side in proportion; the nodes span the image from pixel 0 to pixel n-1) and evaluated at
    arbitrary positions by cubic-spline interpolation. The cell size sets the smallest scale
    of variation of the field: for the paper's 10,032 x 7,769 pixel image and the default
    256 cells, a cell is 39.3 pixels (7.9 arcsec at 0.2 arcsec/pixel), far below the typical
    distance between stars (~60 arcsec at 1 star/arcmin^2).

    Parameters
    ----------
    image_shape : tuple of two ints
        (ny, nx) of the image in pixels.
    n_fields : int, default=1
        Number of independent fields (one per PCA component).
    slope : float, default=11/4
        Minus the power-spectrum slope.
    grid_size : int, default=256
        Number of grid nodes along the longer side of the image.
    random_state : None, int, SeedSequence or Generator, default=None
        Seed; the fields are drawn one after the other from this generator.

    Attributes
    ----------
    grids : ndarray of shape (n_fields, gy, gx)
        The fields on the grid, each with zero mean and unit variance over the grid.
    cell : float
        Grid spacing in pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.simulate import RandomFieldSampler
    >>> s = RandomFieldSampler((1500, 2000), n_fields=3, random_state=1)
    >>> s.grids.shape
    (3, 193, 256)
    >>> s(np.array([[0.0, 0.0], [1999.0, 1499.0]])).shape
    (2, 3)
    """

    def __init__(self, image_shape, n_fields=1, slope=11 / 4, grid_size=256, random_state=None):
        ny, nx = _check_shape(image_shape)
        if int(n_fields) < 0:
            raise ValueError(f"n_fields must be >= 0, got {n_fields}.")
        if int(grid_size) < 4:
            raise ValueError(f"grid_size must be >= 4, got {grid_size}.")
        self.image_shape = (ny, nx)
        longest = max(ny, nx)
        self.cell = max((longest - 1) / (int(grid_size) - 1), 1e-12)
        gy = int(np.ceil((ny - 1) / self.cell)) + 1
        gx = int(np.ceil((nx - 1) / self.cell)) + 1
        gy, gx = max(gy, 4), max(gx, 4)
        rng = as_generator(random_state)
        self.grids = np.stack(
            [gaussian_random_field((gy, gx), slope, rng) for _ in range(int(n_fields))]
        ) if int(n_fields) > 0 else np.zeros((0, gy, gx))
        # spline coefficients once, evaluation without prefiltering afterwards
        self._coeffs = [ndimage.spline_filter(g, order=3, mode="nearest") for g in self.grids]

    def __call__(self, positions) -> np.ndarray:
        """Values of every field at ``positions`` (n, 2) of (x, y) pixels: shape (n, n_fields)."""
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise ValueError(f"positions must have shape (n, 2), got {pos.shape}.")
        coords = np.stack([pos[:, 1] / self.cell, pos[:, 0] / self.cell])
        out = np.empty((pos.shape[0], len(self._coeffs)))
        for i, c in enumerate(self._coeffs):
            out[:, i] = ndimage.map_coordinates(c, coords, order=3, mode="nearest", prefilter=False)
        return out
