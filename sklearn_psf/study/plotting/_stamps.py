"""Example PSF stamps of a simulation (the paper's fig_sim)."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from ._common import MissingDataError, _new_figure


def plot_psf_examples(stamps, positions=None, pixel_scale: float = 0.2, ncols: int | None = None,
                      floor: float = 1e-4, cmap: str = "magma") -> Figure:
    """Example PSF stamps with a logarithmic colour scale (paper's fig_sim).

    Parameters
    ----------
    stamps : array-like of shape (n, s, s) or (n, s*s)
        PSF stamps (e.g. 9 stars spread over the image).
    positions : array-like of shape (n, 2), optional
        (x, y) pixel positions of the stamps in the image, shown in the panel titles.
    pixel_scale : float
        Arcsec per pixel: the axes are in arcsec from the stamp centre.
    ncols : int, optional
        Panels per row (default: about the square root of n).
    floor : float
        Lower end of the colour scale as a fraction of the brightest pixel; pixels below it
        (including zero or negative noise) are shown at the floor colour.
    cmap : str
        Colour map.

    Returns
    -------
    fig : matplotlib.figure.Figure
        One panel per stamp, sharing one logarithmic colour scale.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.study.plotting import plot_psf_examples
    >>> yy, xx = np.mgrid[-3:4, -3:4]
    >>> stamps = np.array([np.exp(-(xx**2 + yy**2) / w) for w in (2.0, 3.0)])
    >>> fig = plot_psf_examples(stamps, positions=[[10, 20], [500, 300]])
    >>> len(fig.axes) - 1  # panels, plus one colour bar
    2
    """
    from ..._validation import as_stamps

    cube = as_stamps(stamps)
    n, size = cube.shape[0], cube.shape[1]
    if n == 0:
        raise MissingDataError("no stamps to plot: pass at least one PSF stamp.")
    if positions is not None:
        positions = np.asarray(positions, dtype=float)
        if positions.shape != (n, 2):
            raise ValueError(f"positions must have shape ({n}, 2) like the stamps, "
                             f"got {positions.shape}.")
    if not pixel_scale > 0:
        raise ValueError(f"pixel_scale must be positive (arcsec per pixel), got {pixel_scale}.")
    peak = float(np.max(cube))
    if not peak > 0:
        raise ValueError("the stamps have no positive pixel: a log colour scale needs flux.")
    ncols = int(ncols) if ncols else int(np.ceil(np.sqrt(n)))
    nrows = int(np.ceil(n / ncols))
    fig, axes = _new_figure(nrows, ncols, panel=(2.4, 2.4))
    norm = LogNorm(vmin=peak * floor, vmax=peak)
    half = size * pixel_scale / 2.0
    image, kept = None, []
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.remove()
            continue
        kept.append(ax)
        image = ax.imshow(np.clip(cube[i], peak * floor, None), origin="lower", norm=norm,
                          cmap=cmap, extent=(-half, half, -half, half), interpolation="nearest")
        if positions is not None:
            ax.set_title(f"(x, y) = ({positions[i, 0]:.0f}, {positions[i, 1]:.0f}) px",
                         fontsize=8)
        ax.set_xlabel("arcsec", fontsize=8)
        ax.set_ylabel("arcsec", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.colorbar(image, ax=kept, label="flux (log scale)")
    fig.suptitle(f"Example PSFs ({pixel_scale:g} arcsec/pixel)")
    return fig


# ----------------------------------------------------------------------------- fig_ell
