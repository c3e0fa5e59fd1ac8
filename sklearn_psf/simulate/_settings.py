"""The settings objects of :func:`make_psf_field`: contaminants, detector, source effects.

Each groups the keywords of one concern; each checks its values when made, so a bad value
fails where it is written. Conventions: :mod:`sklearn_psf.simulate`.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from ._contaminants import CONTAMINANT_KINDS, CONTAMINANT_RANGES

__all__ = ["ContaminantSettings", "DetectorSettings", "SourceSettings"]


def _check_int(name, value, minimum):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}.")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}.")
    return int(value)


def _check_fractions(fractions):
    if fractions is None:
        return {}
    if not isinstance(fractions, dict):
        raise TypeError("contaminants must be a dict {kind: fraction of the stars}, e.g. "
                        f"{{'cosmic_ray': 0.05}}; got {type(fractions).__name__}.")
    out = {}
    for kind, frac in fractions.items():
        if kind not in CONTAMINANT_KINDS:
            raise ValueError(f"Unknown contaminant {kind!r}: choose among {CONTAMINANT_KINDS}.")
        frac = float(frac)
        if not 0 <= frac <= 1:
            raise ValueError(f"The fraction of stars with a {kind!r} must be in [0, 1], "
                             f"got {frac}.")
        out[kind] = frac
    if sum(out.values()) > 1:
        raise ValueError(f"The contaminant fractions add up to {sum(out.values()):.3g} > 1.")
    return out


def _check_ranges(ranges):
    if ranges is None:
        return None
    if not isinstance(ranges, dict):
        raise TypeError("ContaminantSettings.ranges must be a dict {kind: {'flux_ratio': "
                        f"(lo, hi), 'separation': (lo, hi)}}}}, got {type(ranges).__name__}.")
    out = {}
    for kind, values in ranges.items():
        if kind not in CONTAMINANT_RANGES:
            raise ValueError(f"There are no contaminant ranges for {kind!r}: give them for "
                             f"{sorted(CONTAMINANT_RANGES)}.")
        for name, (lo, hi) in values.items():
            if name not in CONTAMINANT_RANGES[kind]:
                raise ValueError(f"Unknown range {name!r} for {kind!r}: choose among "
                                 f"{sorted(CONTAMINANT_RANGES[kind])}.")
            if not 0 < float(lo) <= float(hi):
                raise ValueError(f"The {kind} {name} range must be 0 < lo <= hi, got "
                                 f"({lo}, {hi}).")
        out[kind] = {name: (float(lo), float(hi)) for name, (lo, hi) in values.items()}
    return out


@dataclass(frozen=True)
class ContaminantSettings:
    """What spoils the stars of a :func:`make_psf_field` image, and what lies elsewhere.

    The kinds and their natural strengths are documented in :mod:`sklearn_psf.simulate`
    (section *Contaminants*). The default is a clean field, the paper's study.

    Parameters
    ----------
    fractions : dict, optional
        ``{kind: fraction of the stars}``, kinds "cosmic_ray", "neighbour", "galaxy",
        "binary" (exact counts, random stars; fractions adding up to at most 1); default
        none. ``make_psf_field(contaminants={...})`` is short for these fractions alone.
    min_snr : float, default=0
        Least signal of each contaminant (0: their natural strength).
    ranges : dict, optional
        Other flux-ratio and separation ranges of binaries and neighbours, e.g.
        ``{"binary": {"flux_ratio": (0.02, 0.08), "separation": (1, 3)}}``; default the
        natural ranges of :mod:`sklearn_psf.simulate`.
    n_field_cosmic_rays, n_field_galaxies : int, default=0
        Cosmic rays and extended galaxies elsewhere in the image, away from the stars.

    Raises
    ------
    TypeError, ValueError
        For unknown kinds or ranges, fractions outside [0, 1] or adding up to more than 1,
        ranges not ``0 < lo <= hi``, negative or non-integer counts.

    Examples
    --------
    >>> from sklearn_psf.simulate import ContaminantSettings
    >>> c = ContaminantSettings({"binary": 0.1}, n_field_cosmic_rays=5)
    >>> c.fractions, c.min_snr, c.n_field_cosmic_rays
    ({'binary': 0.1}, 0.0, 5)
    """

    fractions: dict | None = None
    min_snr: float = 0.0
    ranges: dict | None = None
    n_field_cosmic_rays: int = 0
    n_field_galaxies: int = 0

    def __post_init__(self):
        object.__setattr__(self, "fractions", _check_fractions(self.fractions))
        object.__setattr__(self, "ranges", _check_ranges(self.ranges))
        for name in ("n_field_cosmic_rays", "n_field_galaxies"):
            object.__setattr__(self, name, _check_int(name, getattr(self, name), 0))


@dataclass(frozen=True)
class DetectorSettings:
    """The background noise and the detector defects of a :func:`make_psf_field` image.

    The defaults give the paper's image: white Gaussian noise, every pixel good, no weight
    map (``field.weight`` is None unless a defect or ``gain`` needs one).

    Parameters
    ----------
    noise_rms : float, optional
        Background rms (> 0); default the reference image's, else 1.
    gain : float, optional
        Electrons per image unit (> 0): adds the sources' Poisson noise; default none.
    saturation : float, optional
        Saturation level (> 0): brighter pixels clipped to it, weight 0; default none.
    masked_fraction : float, default=0
        Fraction of the pixels masked at random, in [0, 1).
    bad_columns : int, default=0
        Number of full bad columns (at most the image's width).
    mask_value : float, default=0.0
        Value written under masked pixels (``numpy.nan`` makes them NaN).

    Raises
    ------
    TypeError, ValueError
        For a non-positive ``noise_rms``, ``gain`` or ``saturation``, ``masked_fraction``
        outside [0, 1), a negative or non-integer ``bad_columns``.

    Examples
    --------
    >>> from sklearn_psf.simulate import DetectorSettings
    >>> d = DetectorSettings(gain=2.0, bad_columns=1)
    >>> d.gain, d.bad_columns, d.noise_rms is None
    (2.0, 1, True)
    """

    noise_rms: float | None = None
    gain: float | None = None
    saturation: float | None = None
    masked_fraction: float = 0.0
    bad_columns: int = 0
    mask_value: float = 0.0

    def __post_init__(self):
        if self.noise_rms is not None:
            rms = float(self.noise_rms)
            if not (np.isfinite(rms) and rms > 0):
                raise ValueError(f"noise_rms must be positive, got {rms}.")
        object.__setattr__(self, "bad_columns", _check_int("bad_columns", self.bad_columns, 0))
        if not 0 <= float(self.masked_fraction) < 1:
            raise ValueError(f"masked_fraction must be in [0, 1), got {self.masked_fraction}.")
        for name in ("saturation", "gain"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number or None, got {value}.")

    @property
    def needs_weight(self) -> bool:
        """Whether the image gets a weight map (some pixel is not plain background)."""
        return (self.gain is not None or self.masked_fraction > 0 or bool(self.bad_columns)
                or self.saturation is not None)


@dataclass(frozen=True)
class SourceSettings:
    """How each PSF of a :func:`make_psf_field` image depends on its source.

    By default a PSF is that of its position alone (the paper's). Conventions:
    :ref:`simulations` (*Colour and brightness*).

    Parameters
    ----------
    chromatic : bool, default=False
        Each source's PSF depends on its blackbody colour (truth column ``g_i``).
    airmass : float, optional
        With ``chromatic``: differential chromatic refraction at this airmass (>= 1);
        default none.
    optics_fraction : float, default=0.1
        With ``chromatic``: the optics' share of the PSF's second moment, in [0, 1].
    brighter_fatter : float, default=0
        Each PSF dilated by ``1 + brighter_fatter * (snr - min) / (max - min)`` over the
        stars' S/N (>= 0; truth column ``source_snr``).

    Raises
    ------
    ValueError
        For ``airmass`` < 1 or given without ``chromatic``, ``optics_fraction`` outside
        [0, 1], a negative ``brighter_fatter``.

    Examples
    --------
    >>> from sklearn_psf.simulate import SourceSettings
    >>> s = SourceSettings(chromatic=True, airmass=1.2)
    >>> s.chromatic, s.airmass, s.optics_fraction, s.active
    (True, 1.2, 0.1, True)
    >>> SourceSettings().active
    False
    """

    chromatic: bool = False
    airmass: float | None = None
    optics_fraction: float = 0.1
    brighter_fatter: float = 0.0

    def __post_init__(self):
        airmass = self.airmass
        if airmass is not None and not (self.chromatic and np.isfinite(airmass)
                                        and airmass >= 1):
            raise ValueError(f"airmass must be a number >= 1 and needs chromatic=True, got "
                             f"{airmass!r} (chromatic={self.chromatic}).")
        if not 0 <= float(self.optics_fraction) <= 1:
            raise ValueError(f"optics_fraction must be in [0, 1], got {self.optics_fraction}.")
        bf = self.brighter_fatter
        if not (np.isfinite(bf) and bf >= 0):
            raise ValueError(f"brighter_fatter must be a number >= 0, got {bf}.")

    @property
    def active(self) -> bool:
        """Whether any PSF depends on its source (colour or flux)."""
        return bool(self.chromatic or self.brighter_fatter)


def _settings(value, cls, name, shorthand=None):
    """``value`` as a ``cls``: None gives the defaults, ``shorthand`` (a keyword of ``cls``)
    takes a dict."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if shorthand is not None and isinstance(value, dict):
        return cls(**{shorthand: value})
    what = f"a {cls.__name__}" + (" or a dict" if shorthand else "")
    raise TypeError(f"{name} must be {what} or None, got {type(value).__name__}.")
