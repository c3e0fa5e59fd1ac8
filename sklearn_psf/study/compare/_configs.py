"""Simulation configurations of the study: the baseline and the side studies."""

from __future__ import annotations

from dataclasses import dataclass, replace
from numbers import Integral, Real

import numpy as np




@dataclass(frozen=True)
class SimulationConfig:
    """One configuration of the study: how the PSF field is simulated and the stars selected.

    Parameters
    ----------
    label : str
        Name of the configuration in the result tables.
    n_stars, n_galaxies : int
        Stars used to build the model, galaxy-PSFs where it is evaluated [1000, 2000].
    snr : float or "realistic"
        Star S/N (mean of the star's pixels over the background rms) [100]; ``"realistic"``
        draws the paper's distribution from 20 to 1000 peaking near 100.
    min_snr : float, optional
        Drop stars whose S/N is below this before fitting.
    outlier_fraction : float
        Fraction of stars turned into outliers (a blended companion star) before fitting.
    iqr : bool
        Whether the models reject outlying stars with the IQR test.
    galaxy_layout : {"random", "grid"}
        Galaxy-PSFs at random positions (for correlation functions) or on a grid (for maps).
    image_shape : tuple of int
        (ny, nx) of the simulated image [7769, 10032].
    pixel_scale : float
        Arcsec per pixel [0.2].
    smallest_scale : float, optional
        Smallest scale of the PSF variation, arcsec: the cell of the grid on which the
        simulated weight fields are drawn before spline interpolation. Default (None): the
        simulations' default (``make_psf_field``'s ``smallest_scale``, 8 arcsec). The paper
        does not give it; it sets the floor of every scheme (see the ``scale`` study).
    """

    label: str = "default"
    n_stars: int = 1000
    n_galaxies: int = 2000
    snr: float | str = 100.0
    min_snr: float | None = None
    outlier_fraction: float = 0.0
    iqr: bool = True
    galaxy_layout: str = "random"
    image_shape: tuple = (7769, 10032)
    pixel_scale: float = 0.2
    smallest_scale: float | None = None

    def validate(self):
        """Raise ValueError when a setting is out of range."""
        if not isinstance(self.n_stars, Integral) or self.n_stars < 3:
            raise ValueError(f"n_stars must be an integer >= 3, got {self.n_stars!r}.")
        if not isinstance(self.n_galaxies, Integral) or self.n_galaxies < 2:
            raise ValueError(f"n_galaxies must be an integer >= 2, got {self.n_galaxies!r}.")
        if isinstance(self.snr, str):
            if self.snr != "realistic":
                raise ValueError(f"snr must be a positive number or 'realistic', got {self.snr!r}.")
        elif not isinstance(self.snr, Real) or not self.snr > 0:
            raise ValueError(f"snr must be a positive number or 'realistic', got {self.snr!r}.")
        if not 0 <= self.outlier_fraction < 0.5:
            raise ValueError(f"outlier_fraction must be in [0, 0.5), got {self.outlier_fraction}.")
        if self.smallest_scale is not None and not (
                isinstance(self.smallest_scale, Real) and self.smallest_scale > 0):
            raise ValueError(f"smallest_scale must be a positive number of arcsec, got "
                             f"{self.smallest_scale!r}.")
        if self.galaxy_layout not in ("random", "grid"):
            raise ValueError(f"galaxy_layout must be 'random' or 'grid', got {self.galaxy_layout!r}.")
        return self


def snr_study_configs(base: SimulationConfig | None = None) -> list[SimulationConfig]:
    """The paper's S/N study: S/N 100, 700, the realistic distribution, and it without S/N < 100.

    Examples
    --------
    >>> [c.label for c in snr_study_configs()]
    ['snr=100', 'snr=700', 'snr=realistic', 'snr=realistic,min_snr=100']
    """
    base = base or SimulationConfig()
    return [
        replace(base, label="snr=100", snr=100.0),
        replace(base, label="snr=700", snr=700.0),
        replace(base, label="snr=realistic", snr="realistic"),
        replace(base, label="snr=realistic,min_snr=100", snr="realistic", min_snr=100.0),
    ]


def density_study_configs(
    base: SimulationConfig | None = None, n_stars=(250, 500, 1000, 2000, 4000)
) -> list[SimulationConfig]:
    """The paper's global-density study: the same fields sampled by more or fewer stars.

    Examples
    --------
    >>> [c.label for c in density_study_configs(n_stars=(250, 4000))]
    ['n_stars=250', 'n_stars=4000']
    """
    base = base or SimulationConfig()
    return [replace(base, label=f"n_stars={n}", n_stars=int(n)) for n in n_stars]


def outlier_study_configs(
    base: SimulationConfig | None = None, fraction: float = 0.02
) -> list[SimulationConfig]:
    """The paper's outlier study: planted outlying stars, with and without the IQR cut.

    Examples
    --------
    >>> [c.label for c in outlier_study_configs()]
    ['outliers=0.02,iqr=on', 'outliers=0.02,iqr=off']
    """
    base = base or SimulationConfig()
    return [
        replace(base, label=f"outliers={fraction:g},iqr=on", outlier_fraction=fraction, iqr=True),
        replace(base, label=f"outliers={fraction:g},iqr=off", outlier_fraction=fraction, iqr=False),
    ]


def scale_study_configs(base: SimulationConfig | None = None,
                        scales=(4.0, 8.0, 16.0)) -> list[SimulationConfig]:
    """The same fields with finer or coarser PSF variation (``smallest_scale`` in arcsec).

    Examples
    --------
    >>> [c.label for c in scale_study_configs(scales=(4.0, 16.0))]
    ['scale=4"', 'scale=16"']
    """
    base = base or SimulationConfig()
    return [replace(base, label=f'scale={s:g}"', smallest_scale=float(s)) for s in scales]


def field_scale_kwargs(config: SimulationConfig) -> dict:
    """Keyword arguments of ``make_psf_field`` that set the field's smallest scale."""
    return {} if config.smallest_scale is None else {"smallest_scale": config.smallest_scale}


def example_stars(config: SimulationConfig, seed: int, reference=None, n: int = 4):
    """Stamps and positions of ``n`` stars cut from a simulation's image (the paper's fig_sim)."""
    from ...simulate import make_psf_field

    sim = make_psf_field(reference=reference, n_stars=config.n_stars, n_galaxies=2,
                         snr=config.snr if config.snr != "realistic" else 100.0,
                         image_shape=config.image_shape, pixel_scale=config.pixel_scale,
                         random_state=seed, **field_scale_kwargs(config))
    stamps, flags = sim.star_stamps()
    good = np.flatnonzero(np.asarray(flags) == 0)[:n]
    positions = np.column_stack([sim.stars["x"], sim.stars["y"]])[good]
    return stamps[good], positions
