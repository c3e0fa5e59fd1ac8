"""The whole real-data path in one call: read an exposure (its image and/or its source
catalogue), select the stars, cut their stamps, fit a PSF model with reserved stars, and judge
it. ``sklearn-psf fit`` is this call plus printing and saving."""

from __future__ import annotations

import contextlib
import os
from typing import NamedTuple

import numpy as np

from .._files import InputError, is_input_error

__all__ = ["ExposureInputs", "ExposureFit", "StarSelectionError", "fit_exposure",
           "key_columns", "read_exposure"]


class StarSelectionError(InputError):
    """Too few stars pass the selection for a PSF model.

    The message counts the sources each cut dropped and names the parameter that relaxes it;
    :meth:`text` renders it with other names for the parameters (e.g. the command line's
    options).

    Attributes
    ----------
    head : str
        What was selected, in words.
    counts : dict
        Selection reason -> number of sources dropped (see
        :func:`~sklearn_psf.exposure.select_stars`).
    hint : str
        What else the user can do.
    lines : list of str
        What was read and selected before (the start of :meth:`ExposureFit.report`).
    """

    def __init__(self, head, counts, hint, lines=()):
        self.head, self.counts, self.hint, self.lines = head, counts, hint, list(lines)
        super().__init__(self.text())

    def text(self, names=None, hint=None) -> str:
        """The message, each selection parameter shown as ``names[parameter]``, ending with
        ``hint`` (default :attr:`hint`).

        Examples
        --------
        >>> from sklearn_psf.exposure import StarSelectionError
        >>> err = StarSelectionError("3 of 40 sources pass", {"low_snr": 37}, "or give more")
        >>> err.text({"min_snr": "--min-snr"})
        '3 of 40 sources pass: too few for a PSF model (need 5); dropped by cut (option relaxing it): low_snr 37 (--min-snr); or give more'
        """
        from ._select import SELECTION_OPTIONS, SELECTION_REASONS

        names = names or {}
        per_cut = ", ".join(
            f"{k} {self.counts[k]} ({names.get(SELECTION_OPTIONS[k], SELECTION_OPTIONS[k])})"
            for k in SELECTION_REASONS if self.counts.get(k) and k in SELECTION_OPTIONS)
        return (f"{self.head}: too few for a PSF model (need {MIN_STARS})"
                + (f"; dropped by cut (option relaxing it): {per_cut}" if per_cut else "")
                + f"; {self.hint if hint is None else hint}")


#: Fewest stars :func:`fit_exposure` fits a model on.
MIN_STARS = 5


def _gain(header):
    """Detector gain (e-/ADU): GAIN, else the gain SExtractor used (SEXGAIN); None."""
    for key in ("GAIN", "SEXGAIN"):
        value = header.get(key)
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    return None


class ExposureInputs(NamedTuple):
    """An exposure as read by :func:`read_exposure`.

    Attributes
    ----------
    image : ndarray of shape (ny, nx) or None
        The image (None for a catalogue of VIGNETs alone).
    weight : ndarray or None
        Its weight map (inverse variance, 0 = bad pixel).
    header : dict-like
        The image's header, else the catalogue's image header (``LDAC_IMHEAD``), else {}.
    catalog : astropy.table.Table or None
        The catalogue (0-based ``x``, ``y``), None without one.
    saturation : float or None
        The saturation level given, else the header's ``SATURATE``, else the level at which
        the catalogue's brightest sources' peaks pile up
        (:func:`~sklearn_psf.exposure.saturation_level`).
    gain : float or None
        ``GAIN`` (else ``SEXGAIN``) of the header, e-/ADU.
    image_path, catalog_path : str or None
        Where they were read from (named in error messages).
    """

    image: object
    weight: object
    header: dict
    catalog: object
    saturation: float | None
    gain: float | None
    image_path: str | None = None
    catalog_path: str | None = None
    #: Where ``saturation`` comes from: "given", "header", "catalogue peaks" (with the
    #: number of sources piled up there) or None.
    saturation_source: str | None = None

    @property
    def has_vignettes(self) -> bool:
        """True when the stamps come from the catalogue's ``VIGNET`` (no image)."""
        return self.image is None and self.catalog is not None and "VIGNET" in [
            c.upper() for c in self.catalog.colnames]

    @property
    def default_stamp_size(self) -> int:
        """The side of the catalogue's VIGNETs, else 25."""
        if self.has_vignettes:
            name = [c for c in self.catalog.colnames if c.upper() == "VIGNET"][0]
            return int(np.shape(self.catalog[name])[1])
        return 25

    @property
    def image_shape(self):
        """(ny, nx) of the image, else of the catalogue's image header, else None."""
        if self.image is not None:
            return self.image.shape
        if "NAXIS2" in self.header and "NAXIS1" in self.header:
            return int(self.header["NAXIS2"]), int(self.header["NAXIS1"])
        return None

    def cut_stamps(self, catalog=None, stamp_size=None):
        """The stars' stamps (:class:`~sklearn_psf.exposure.StarStamps`): the catalogue's VIGNETs
        without an image (cropped to ``stamp_size``), else cut from the image (side 25 by
        default), with the weight map and the saturation level."""
        from ._stars import extract_star_stamps
        from ._vignettes import extract_vignettes

        catalog = self.catalog if catalog is None else catalog
        with _naming(self.catalog_path or self.image_path):
            if self.image is None:
                return extract_vignettes(catalog, stamp_size, saturation=self.saturation,
                                         gain=self.gain)
            return extract_star_stamps(self.image, catalog, stamp_size or 25,
                                       weight=self.weight, saturation=self.saturation)


@contextlib.contextmanager
def _naming(path):
    """Input errors about a file's content name the file (a failure that is not about the
    input goes on as it is: a bug must not pass for the user's fault)."""
    try:
        yield
    except ValueError as exc:
        if path is None or str(path) in str(exc) or not is_input_error(exc):
            raise
        raise InputError(f"{path}: {exc}") from None


def read_exposure(image=None, catalog=None, *, hdu=None, weight_hdu=None,
                  one_based: bool | None = None, x_col: str | None = None,
                  y_col: str | None = None, saturation: float | None = None) -> ExposureInputs:
    """Read an exposure: a FITS image (and its weight map) and/or a source catalogue.

    Parameters
    ----------
    image : str or os.PathLike, optional
        FITS image (:func:`~sklearn_psf.io.read_image`); optional with a catalogue holding
        ``VIGNET`` stamps.
    catalog : str, os.PathLike or astropy.table.Table, optional
        Source catalogue (:func:`~sklearn_psf.io.read_catalog`: FITS_LDAC, FITS table,
        SExtractor ASCII, CSV).
    hdu, weight_hdu : int or str, optional
        The image's HDU and its weight map's HDU.
    one_based, x_col, y_col :
        Position columns and their convention (see :func:`~sklearn_psf.io.read_catalog`).
    saturation : float, optional
        Saturation level; default the header's ``SATURATE``.

    Returns
    -------
    ExposureInputs

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import read_exposure
    >>> cat = Table({"x": [10.0, 20.0], "y": [5.0, 8.0], "VIGNET": np.zeros((2, 15, 15))})
    >>> inputs = read_exposure(catalog=cat)
    >>> inputs.has_vignettes, inputs.default_stamp_size, inputs.image_shape
    (True, 15, None)
    """
    from ..io import read_catalog, read_image
    from ._select import saturation_level

    if image is None and catalog is None:
        raise InputError("Give an image, or a catalogue with VIGNET stamps.")
    header, data, weight, table = {}, None, None, None
    if image is not None:
        data, weight, header = read_image(image, hdu=hdu, weight_hdu=weight_hdu)
    catalog_path = None if catalog is None or not isinstance(catalog, (str, os.PathLike)) \
        else str(catalog)
    if catalog is not None:
        with _naming(catalog_path):
            table = read_catalog(catalog, one_based=one_based, x_col=x_col, y_col=y_col)
        if data is None:
            header = table.meta.get("image_header") or {}
    source = None if saturation is None else "given"
    if saturation is None and "SATURATE" in header:
        saturation, source = float(header["SATURATE"]), "header"
    if saturation is None and table is not None:
        saturation, piled = saturation_level(table)
        source = None if saturation is None else f"catalogue peaks ({piled} sources)"
    return ExposureInputs(data, weight, header, table, saturation, _gain(header),
                          None if image is None else str(image), catalog_path, source)


class ExposureFit:
    """A PSF model of an exposure and its verdict, as :func:`fit_exposure` returns them.

    Attributes
    ----------
    model : PSFModel
        Fitted on the selected, non-reserved stars.
    residuals : astropy.table.Table
        The reserved stars' residuals (see :func:`~sklearn_psf.validation.fit_and_validate`).
    summary : dict
        The verdict (see :func:`~sklearn_psf.validation.fit_and_validate`) with ``selection`` (the stamp cut's
        counts), ``image`` (the input's path), ``interpolator``, ``nan_pixels``,
        ``saturation``, ``gain`` and ``wcs`` (header string) when the image has a celestial
        WCS.
    selection : dict
        The star selection's counts (:func:`~sklearn_psf.exposure.select_stars`), {} without one.
    stars : StarStamps
        The stamps the model was fitted and validated on; with a catalogue, ``stars.rows``
        holds each star's row in it (0-based), e.g. the reserved stars'
        ``stars.rows[residuals["index"]]``.
    lines : list of str
        What was read and selected, in words (the start of :meth:`report`).
    image_shape : tuple
        (ny, nx) of the field (the image, its header, else the stars' extent).
    """

    def __init__(self, model, residuals, summary, selection, stars, lines, image_shape):
        self.model, self.residuals, self.summary = model, residuals, summary
        self.selection, self.stars, self.lines = selection, stars, lines
        self.image_shape = image_shape

    def __repr__(self):
        return (f"ExposureFit(stars={self.summary['n_stars']}, fitted={self.summary['n_fit']}, "
                f"reserved={self.summary['n_reserved']})")

    def report(self) -> list:
        """The fit's report, line by line: what was read and selected, the basis, the
        reserved stars' residuals, the verdict against their noise, the rho statistics."""
        return list(self.lines) + _report(self.summary)

    def figures(self) -> dict:
        """The diagnostic figures (matplotlib): ``stamps`` (reserved stars, model, residuals),
        ``whiskers`` (e of stars, model, residuals), ``maps`` (model e and size across the
        field) and ``rho`` (rho1-rho5, with enough reserved stars); {} without measured
        reserved stars."""
        from ..validation import (plot_psf_maps, plot_rho_statistics, plot_stamp_residuals,
                                  plot_whiskers)

        if not self.summary.get("n_measured"):
            return {}
        figures = {"stamps": plot_stamp_residuals(self.residuals),
                   "whiskers": plot_whiskers(self.residuals),
                   "maps": plot_psf_maps(self.model, self.image_shape)}
        if self.summary.get("rho1"):
            figures["rho"] = plot_rho_statistics(self.summary)
        return figures


def key_columns(catalog, keys, where="the catalogue") -> np.ndarray:
    """The catalogue's columns ``keys`` as the model's extra dimensions, one column each.

    PSFEx's ``PSFVAR_KEYS``: any catalogue quantity (a colour, a magnitude, a flux) as a
    dimension of the model after the positions. Names are matched without regard to case.

    Parameters
    ----------
    catalog : astropy.table.Table
    keys : sequence of str
        Column names.
    where : str
        How error messages name the catalogue.

    Returns
    -------
    ndarray of shape (n, len(keys))
        float64 (NaN where a value is masked or missing).

    Raises
    ------
    InputError
        A key that is not a column (the message lists some that are), or a column that does
        not hold one number per row.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import key_columns
    >>> cat = Table({"x": [1.0, 2.0], "y": [3.0, 4.0], "G_I": [0.5, 1.5]})
    >>> key_columns(cat, ["g_i"]).tolist()
    [[0.5], [1.5]]
    """
    lower = {name.lower(): name for name in catalog.colnames}
    out = np.empty((len(catalog), len(keys)))
    for j, key in enumerate(keys):
        name = lower.get(str(key).lower())
        if name is None:
            some = [c for c in catalog.colnames if np.ndim(catalog[c]) == 1][:12]
            raise InputError(f"{where} has no column {key!r} (a --keys / keys entry); "
                             f"columns include: {', '.join(some)}"
                             + (", ..." if len(catalog.colnames) > len(some) else ""))
        column = catalog[name]
        if np.ndim(column) != 1 or column.dtype.kind not in "biuf":
            raise InputError(f"{where}: column {name!r} (a --keys / keys entry) does not hold "
                             f"one number per row (dtype {column.dtype}, shape "
                             f"{np.shape(column)})")
        values = np.ma.asarray(column).astype(np.float64)
        out[:, j] = np.ma.filled(values, np.nan)
    return out


def _drop_missing_keys(stars, keys, where):
    """The used stars' key values (m, len(keys)); stars with a NaN or infinite value are
    dropped from ``stars`` (counted as ``missing_key`` with a warning)."""
    import warnings

    from ..io import CatalogColumnWarning

    used = np.flatnonzero(np.asarray(stars.catalog["used"], dtype=bool))
    extra = key_columns(stars.catalog[used], keys, where)
    bad = ~np.isfinite(extra).all(axis=1)
    if bad.any():
        warnings.warn(f"{int(bad.sum())} of the {len(used)} stars of {where} have NaN or "
                      f"infinite values in the keys {', '.join(keys)}: left out of the fit",
                      CatalogColumnWarning, stacklevel=3)
        stars.positions, stars.stamps = stars.positions[~bad], stars.stamps[~bad]
        if stars.weights is not None:
            stars.weights = stars.weights[~bad]
        stars.catalog["used"][used[bad]] = False
        reason = np.asarray(stars.catalog["reason"], dtype=object)
        reason[used[bad]] = "missing_key"
        stars.catalog["reason"] = reason.astype(str)
        stars.counts["used"] -= int(bad.sum())
        stars.counts["missing_key"] = int(bad.sum())
    return extra[~bad]


def _selection_lines(counts, n_kept, head, max_spread_model, min_class_star):
    from ._select import SELECTION_REASONS

    rejected = ", ".join(f"{k} {counts[k]}" for k in SELECTION_REASONS if counts.get(k))
    lines = [f"{head}{n_kept}" + (f" (rejected: {rejected})" if rejected else "")]
    size = {"flux_radius": "FLUX_RADIUS", "adaptive_sigma": "adaptive-moment sigma of the "
            "VIGNETs", "adaptive_sigma_masked": "adaptive-moment sigma of the VIGNETs, "
            "neighbours masked"}.get(counts.get("locus_size"))
    if size and np.isfinite(counts["locus_radius"]):
        lines.append(f"  size-magnitude locus: {size} {counts['locus_radius']:.3g} pixels "
                     f"(median over the selected stars), accepted within +-"
                     f"{counts['locus_width']:.1%} (median; wider at low S/N)")
    if counts.get("snr_from") == "vignets":
        lines.append("  S/N: in a Gaussian window on the VIGNETs, as Source Extractor's SNR_WIN "
                     "(the catalogue has none; its fluxes' S/N is lower for faint stars)")
    cuts = {"class_star": f"CLASS_STAR >= {min_class_star:g}",
            "spread_model": f"|SPREAD_MODEL| <= {max_spread_model:g}"}
    for name, fraction in counts.get("not_applied", {}).items():
        lines.append(f"  not applied: {cuts[name]}, which would reject {fraction:.0%} of the "
                     "sources on the size-magnitude locus"
                     + (" (the locus decides: SExtractor's CLASS_STAR depends on the "
                        "SEEING_FWHM and detection threshold it was given)"
                        if name == "class_star" else ""))
    return lines


def fit_exposure(image=None, catalog=None, *, hdu=None, weight_hdu=None,
                 one_based: bool | None = None, x_col: str | None = None,
                 y_col: str | None = None, select: bool = True, flag_mask: int | None = 0xfe,
                 min_snr: float = 20.0, saturation: float | None = None,
                 isolation: float | None = None, locus_width: float | str = "auto",
                 max_spread_model: float = 0.003, min_class_star: float = 0.8,
                 stamp_size: int | None = None, interpolator: str = "kriging",
                 reserve: float = 0.2, random_state=0, keys=None, band_limit=None,
                 progress=None) -> ExposureFit:
    """Fit and validate the PSF model of an exposure, from its files to the verdict.

    What ``sklearn-psf fit`` does, as one call: read the exposure (:func:`read_exposure`),
    select the stars (:func:`~sklearn_psf.exposure.select_stars` with a catalogue,
    :func:`~sklearn_psf.exposure.find_stars` without), cut their stamps and mask their neighbours,
    then fit and judge the model (:func:`~sklearn_psf.validation.fit_and_validate`). The steps:
    :ref:`exposure-details` in the user guide.

    Parameters
    ----------
    image, catalog, hdu, weight_hdu, one_based, x_col, y_col :
        The inputs, as :func:`read_exposure` takes them. The catalogue's x, y must fall on
        the image.
    select : bool, default=True
        False uses every catalogue row as a star (a catalogue of stars only).
    flag_mask, min_snr, saturation, isolation, locus_width, max_spread_model, min_class_star :
        The selection's cuts (:func:`~sklearn_psf.exposure.select_stars`). ``flag_mask`` defaults
        to PSFEx's ``0xfe``: sources flagged only 1 (neighbours) are kept. ``saturation``
        defaults to the header's ``SATURATE``.
    stamp_size : int, optional
        Stamp side; default the catalogue's VIGNET side, else 25.
    interpolator : str, default="kriging"
        A scheme of :func:`~sklearn_psf.model.make_interpolator`, or ``"auto"`` to choose it
        by cross-validation among them.
    band_limit : float, optional
        The PSF's band limit in cycles per pixel for undersampled stars (the optics' cutoff
        ``D / lambda`` times the pixel scale in radians): the basis is then
        ``SuperResolvedPCA(band_limit=band_limit)``. Default: ``PSFModel``'s basis (its band
        chosen from the stars when they are undersampled).
    reserve : float, default=0.2
        Fraction of the stars reserved for the verdict.
    random_state : int, default=0
        Seed of the reserved-star draw.
    keys : sequence of str, optional
        Catalogue columns (a colour, a magnitude) added as the model's dimensions after the
        positions, as PSFEx's ``PSFVAR_KEYS`` (:func:`key_columns`); stars with a NaN in a
        key are left out with a :class:`~sklearn_psf.io.CatalogColumnWarning`.
    progress : callable, optional
        Called with the name of each step (``"selecting stars"``, ``"cutting stamps"``,
        ``"fitting and validating"``) as it starts: a progress bar's hook.

    Returns
    -------
    ExposureFit

    Raises
    ------
    StarSelectionError
        Fewer than 5 stars pass the selection (the counts of each cut in the message).
    ValueError
        Unreadable inputs (the file named), positions all off the image, a key that is not a
        column of the catalogue (or no catalogue).

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf import make_psf_field
    >>> from sklearn_psf.exposure import fit_exposure
    >>> field = make_psf_field(n_stars=60, n_galaxies=1, image_shape=(1000, 1000),
    ...                        random_state=0)
    >>> stamps, weights, flags = field.star_stamps(normalize=False, return_weights=True)
    >>> side = int(np.sqrt(stamps.shape[1]))
    >>> cat = Table({"x": field.stars["x"], "y": field.stars["y"],
    ...              "VIGNET": stamps.reshape(-1, side, side)})
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     fit = fit_exposure(catalog=cat, select=False, reserve=0.2)
    >>> fit.summary["n_reserved"], fit.summary["n_fit"]
    (12, 48)
    >>> fit.report()[0]
    'sources in the catalogue: 60 (0-based x, y)'

    48 stars are too few for this PSF: the verdict warns.

    >>> [w.category.__name__ for w in caught]
    ['PSFQualityWarning']
    """
    from ..io import celestial_wcs
    from ..model import INTERPOLATORS, PSFModel, make_interpolator
    from ..preprocessing import SuperResolvedPCA
    from ..validation import fit_and_validate
    from ._select import select_stars
    from ._stars import find_stars

    step = progress or (lambda name: None)
    inputs = read_exposure(image, catalog, hdu=hdu, weight_hdu=weight_hdu,
                           one_based=one_based, x_col=x_col, y_col=y_col,
                           saturation=saturation)
    data, table = inputs.image, inputs.catalog
    source = inputs.catalog_path or inputs.image_path or "the catalogue"
    keys = [str(k) for k in (keys or ())]
    if keys:
        if table is None:
            raise InputError(f"keys ({', '.join(keys)}) are catalogue columns: give a "
                             "catalogue")
        key_columns(table[:0], keys, source)  # a missing column named before any work
    lines, counts, rows = [], {}, None
    n_nan = 0
    if data is not None:
        n_nan = int(np.isnan(data).sum())
        weight = inputs.weight
        n_zero = 0 if weight is None else int(np.sum(~(np.asarray(weight) > 0)))
        lines.append(f"image: {data.shape[1]} x {data.shape[0]} pixels; NaN pixels: {n_nan}"
                     + ("" if weight is None else f"; zero-weight pixels: {n_zero}")
                     + " (masked: a star with one in its core is skipped)")
    side = inputs.default_stamp_size if inputs.has_vignettes else \
        None if data is None else min(data.shape)
    if stamp_size is None:
        stamp_size = inputs.default_stamp_size
    elif side is not None and stamp_size > side:
        raise InputError(f"stamp_size {stamp_size} (--stamp-size) is larger than the "
                         f"{'VIGNETs' if inputs.has_vignettes else 'image'} ({side} pixels)")
    step("selecting stars")
    if table is not None:
        lines.append(f"sources in the catalogue: {len(table)}"
                     f" ({'1' if table.meta['one_based'] else '0'}-based "
                     f"{table.meta['x_column']}, {table.meta['y_column']})")
        if (inputs.saturation_source or "").startswith("catalogue"):
            lines.append(f"saturation level: {inputs.saturation:.6g}, where the highest "
                         f"pixels of the brightest sources pile up (the header gives no "
                         f"SATURATE; {inputs.saturation_source}): stars peaking above 0.9 "
                         "of it are left out (--saturation sets it)")
        if data is not None:
            x, y = np.asarray(table["x"]), np.asarray(table["y"])
            ny, nx = data.shape
            if not ((x > -0.5) & (x < nx - 0.5) & (y > -0.5) & (y < ny - 0.5)).any():
                raise InputError(
                    f"All {len(table)} catalogue positions fall outside the image "
                    f"{inputs.image_path} (ny, nx = {ny}, {nx}): check the HDU, or whether "
                    "the positions are 1-based (one_based=True, --one-based)")
        if select:
            if data is not None and not any(c.upper() == "VIGNET" for c in table.colnames):
                # sources measured on the image's cut-outs, their neighbours masked, as on
                # a catalogue's VIGNETs (FLUX_RADIUS would carry the neighbours' light)
                from ._stars import _image_vignettes

                table = table.copy(copy_data=False)
                table["VIGNET"] = _image_vignettes(data, table, stamp_size, inputs.weight)
            keep, counts = select_stars(
                table, image_shape=None if data is None else data.shape,
                min_snr=min_snr, saturation=inputs.saturation, flag_mask=flag_mask,
                stamp_size=stamp_size, isolation=isolation, locus_width=locus_width,
                max_spread_model=max_spread_model, min_class_star=min_class_star,
                min_stars=0)
            n_kept = int(keep.sum())
            lines += _selection_lines(counts, n_kept, "selected as stars: ", max_spread_model,
                                      min_class_star)
            if n_kept < MIN_STARS:
                raise StarSelectionError(
                    f"{n_kept} of the {len(table)} sources of {source} pass the star "
                    "selection", counts, "or use no selection (select=False, --no-select) if "
                    "the catalogue holds stars only", lines)
            table, full = table[keep], table
            rows = np.flatnonzero(keep)  # the stars' rows in the full catalogue
            if flag_mask is not None and "flags" in table.colnames:
                # flags outside the mask were accepted: the stamp cutters must not skip them
                table["flags"] = np.asarray(table["flags"]).astype(np.int64) & int(flag_mask)
    else:
        table = find_stars(data, weight=inputs.weight, stamp_size=stamp_size, min_snr=min_snr,
                           saturation=inputs.saturation, isolation=isolation,
                           locus_width=locus_width)
        counts = {**table.meta["rejected"], "locus_size": None}
        lines += _selection_lines(counts, len(table), f"sources detected: "
                                  f"{table.meta['n_detections']}, selected as stars: ",
                                  max_spread_model, min_class_star)
        if len(table) < MIN_STARS:
            raise StarSelectionError(
                f"found {len(table)} usable stars in {inputs.image_path} "
                f"({table.meta['n_detections']} detections)", counts,
                "or give a star catalogue", lines)
    step("cutting stamps")
    stars = inputs.cut_stamps(table, stamp_size)
    extra = _drop_missing_keys(stars, keys, source) if keys else None
    skipped = {k: v for k, v in stars.counts.items() if k not in ("input", "used") and v}
    lines.append(f"stars used: {stars.counts['used']} of {stars.counts['input']}"
                 + (" (skipped: " + ", ".join(f"{k} {v}" for k, v in skipped.items()) + ")"
                    if skipped else ""))
    used = np.asarray(stars.catalog["used"], dtype=bool)
    if rows is not None and isolation is None:
        _mask_neighbours(stars, full, rows[used], lines)
    if table is not None and inputs.catalog is not None:  # the stars' rows in the catalogue
        stars.rows = (np.flatnonzero(used) if rows is None else rows[used])
    if stars.counts["used"] < MIN_STARS:
        raise InputError(f"{stars.counts['used']} stars of {source} are usable: too few for "
                         f"a PSF model (need {MIN_STARS})")
    X = stars.positions if extra is None else np.column_stack([stars.positions, extra])
    step("fitting and validating")
    wcs = celestial_wcs(inputs.header)
    options = {"reserve": reserve, "random_state": random_state, "weights": stars.weights,
               "wcs": wcs}
    basis = None if band_limit is None else SuperResolvedPCA(band_limit=float(band_limit))
    if interpolator == "auto":
        candidates = {n: PSFModel(basis=basis, interpolator=make_interpolator(n))
                      for n in INTERPOLATORS}
        model, residuals, summary = fit_and_validate(X, stars.stamps, candidates=candidates,
                                                     **options)
    else:
        model, residuals, summary = fit_and_validate(
            X, stars.stamps, PSFModel(basis=basis, interpolator=make_interpolator(interpolator)),
            **options)
    summary["selection"] = dict(stars.counts)
    summary["image"] = os.path.abspath(inputs.image_path or inputs.catalog_path or ".")
    summary["interpolator"] = summary.get("scheme", interpolator)
    summary["nan_pixels"] = n_nan
    summary["saturation"] = inputs.saturation
    summary["gain"] = inputs.gain
    if keys:  # the model's extra dimensions, as the catalogue names them
        lower = {c.lower(): c for c in stars.catalog.colnames}
        summary["keys"] = [lower[k.lower()] for k in keys]
    if wcs is not None:  # predict can then take and return (RA, Dec)
        summary["wcs"] = wcs.to_header_string()
    shape = inputs.image_shape
    if shape is None:  # a catalogue without image header: the stars' extent
        shape = tuple(int(v) + 1 for v in stars.positions.max(axis=0)[::-1])
    return ExposureFit(model, residuals, summary, counts, stars, lines, shape)


def _mask_neighbours(stars, catalog, rows, lines):
    """Zero the weight (and the value) of the stamps' pixels that the catalogue's other
    sources cover (:func:`~sklearn_psf.exposure.neighbour_masks`); say how many."""
    from ._select import neighbour_masks
    from ..preprocessing import estimate_pixel_weights

    side = int(round(np.sqrt(stars.stamps.shape[1])))
    masks = neighbour_masks(catalog, rows, side).reshape(len(rows), -1)
    hit = masks.any(axis=1)
    if not hit.any():
        return
    weights = stars.weights if stars.weights is not None else \
        estimate_pixel_weights(stars.stamps)
    stars.weights = np.where(masks, 0.0, weights)
    stars.stamps = np.where(masks, 0.0, stars.stamps)
    lines.append(f"neighbours masked: in {int(hit.sum())} stamps (median "
                 f"{int(np.median(masks[hit].sum(axis=1)))} pixels of {masks.shape[1]}), the "
                 "pixels of the catalogue's other sources")


def _report(summary):
    """The lines of the report after the selection: basis, residuals, verdict."""
    from ..model._psf_model import MIN_LIKELIHOOD_STARS

    lines = []
    if "cv" in summary:
        lines.append("cross-validation (e rms): " + ", ".join(
            f"{r['scheme']} {r['e_rms']:.4f}" for r in summary["cv"])
            + f" -> {summary['scheme']}")
    interpolator = summary["interpolator"]
    if summary.get("spatial_model") == "constant":  # too few stars for its likelihood
        interpolator = (f"a constant PSF ({summary['n_inliers']} stars kept are fewer than "
                        f"the {MIN_LIKELIHOOD_STARS} that {interpolator}'s maximum likelihood "
                        "needs; PSFEx lowers its degree likewise)")
    lines.append(f"interpolator: {interpolator}; fitted stars: {summary['n_fit']}, "
                 f"outliers rejected: {summary['n_outliers']}, reserved: "
                 f"{summary['n_reserved']}")
    if "pixel_noise" in summary:
        noise = summary["pixel_noise"]
        gain = summary.get("gain")
        poisson = (f"a Poisson term of {noise['poisson']:.3g} per unit of flux (a gain of "
                   f"{1 / noise['poisson']:.3g} in the stamps' units) missing from them"
                   if noise["poisson"] > 0 else "no Poisson term missing from them")
        lines.append(f"pixel noise learnt from the stars' residuals: {noise['sky']:.3g} times "
                     f"the weights' variance, {poisson}, a model error of "
                     f"{np.sqrt(noise['eps2']):.2%} of each pixel's value (header gain: "
                     f"{'none' if gain is None else f'{gain:g}'}); the outlier test judges "
                     "the stars in it, and against each other")
    if summary.get("contaminated_stamps"):
        lines.append(f"pixels masked as holding light the star's model does not (uncatalogued "
                     f"neighbours, cosmic rays, defects; outside the cores): in "
                     f"{summary['contaminated_stamps']} stamps (median "
                     f"{summary['contaminated_median']} pixels)")
    if "n_components" in summary:
        lines.append(f"basis: {summary['n_components']} components: "
                     f"{summary['components_reason']}")
    if summary.get("kriging_range") is not None:
        lines.append(f"Kriging range (maximum likelihood): {summary['kriging_range']:.3g}; "
                     f"stars' typical spacing: {summary['star_spacing']:.3g} (median distance "
                     "to the nearest star; both in the interpolator's coordinates, the field "
                     "scaled to the unit square)")
    if summary.get("n_reserved_outliers"):
        rows = summary["reserved_outliers"]
        lines.append(f"reserved stars rejected by the outlier test (left out of what follows): "
                     f"{len(rows)} (rows " + ", ".join(map(str, rows[:10]))
                     + (", ..." if len(rows) > 10 else "") + " of the stars used)")
    if summary["n_measured"]:
        lines.append(
            f"reserved stars (star - model, {summary['n_measured']} measured): "
            f"e rms {summary['e_rms']:.4f} (e1 mean {summary['de1_mean']:+.4f} rms "
            f"{summary['de1_rms']:.4f}, e2 mean {summary['de2_mean']:+.4f} rms "
            f"{summary['de2_rms']:.4f}), size mean {summary['dsigma_mean']:+.4f} rms "
            f"{summary['dsigma_rms']:.4f} pixels; {summary.get('moments', 'adaptive')} moments")
    if summary.get("n_verdict"):
        lines.append(
            f"reserved stars against their own noise ({summary['n_verdict']} stars; a constant "
            f"PSF fitted on the same stars in brackets): median chi^2 per degree of freedom "
            f"{summary['chi2_dof_median']:.3f} ({summary['chi2_dof_median_constant']:.3f}); "
            f"e residual rms "
            f"over e noise rms {summary['e_resid_over_noise']:.2f} "
            f"({summary['e_resid_over_noise_constant']:.2f}; e noise per component "
            f"{summary['e_noise']:.4f}); 1 is pure noise")
    if summary.get("rho1"):
        unit = "arcmin" if "wcs" in summary else "pixel"
        means = []
        for k in range(1, 6):
            xi = np.asarray((summary.get(f"rho{k}") or {}).get("xi", []), dtype=float)
            means.append(f"rho{k} {np.nanmean(np.abs(xi)):.2e}" if np.isfinite(xi).any()
                         else f"rho{k} -")
        theta = summary["rho1"]["theta"]
        lines.append(f"rho statistics of the reserved stars (mean |rho| over {len(theta)} bins, "
                     f"{theta[0]:.3g}-{theta[-1]:.3g} {unit}): " + ", ".join(means))
    if np.isfinite(summary.get("dM22_rel_rms", np.nan)):
        lines.append(
            f"fourth moments, same stars (residual star - model over the star's sigma^4; a "
            f"Gaussian's M22 is 2): spin-0 dM22 mean {summary['dM22_rel_mean']:+.2e} rms "
            f"{summary['dM22_rel_rms']:.2e}, spin-2 |dM31 + i dM13| rms "
            f"{summary['dM4_rel_rms']:.2e}"
            + (f"; residual rms over noise rms {summary['dM22_resid_over_noise']:.2f} "
               f"(spin 0), {summary['dM4_resid_over_noise']:.2f} (spin 2)"
               if np.isfinite(summary.get("dM22_resid_over_noise", np.nan)) else ""))
    if summary.get("rho_M4"):
        means = []
        for name in ("rho_M4", "rho_eM4", "rho_M22", "rho_TM22"):
            xi = np.asarray((summary.get(name) or {}).get("xi", []), dtype=float)
            means.append(f"{name} {np.nanmean(np.abs(xi)):.2e}" if np.isfinite(xi).any()
                         else f"{name} -")
        lines.append("their correlation functions (mean |xi|, same bins; M4 = M31 + i M13, "
                     "e and T = 2 sigma^2 of the second moments): " + ", ".join(means))
    return lines
