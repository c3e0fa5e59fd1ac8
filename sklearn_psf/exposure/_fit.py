"""The whole real-data path in one call: read an exposure (its image and/or its source
catalogue), select the stars, cut their stamps, fit a PSF model with reserved stars, and judge
it. ``sklearn-psf fit`` is this call plus printing and saving."""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from .._files import InputError
from ._inputs import key_columns, read_exposure
from ._report import _report, _selection_lines
from ._select import PSFEX_FLAG_MASK

__all__ = ["ExposureFit", "SelectionCuts", "StarSelectionError", "fit_exposure"]


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


@dataclasses.dataclass(frozen=True)
class SelectionCuts:
    """The star selection's cuts that :func:`fit_exposure` applies, in one object.

    Each is the parameter of the same name of :func:`~sklearn_psf.exposure.select_stars`
    (and, on an image without a catalogue, of :func:`~sklearn_psf.exposure.find_stars`:
    ``min_snr``, ``isolation``, ``locus_width``); the defaults are ``sklearn-psf fit``'s.

    Attributes
    ----------
    flag_mask : int or None, default=PSFEX_FLAG_MASK
        Bits of ``FLAGS`` that reject a source: PSFEx's ``0xfe``, so that sources flagged
        only 1 (neighbours) are kept and their neighbours masked.
    min_snr : float, default=20.0
        Smallest S/N of a star.
    isolation : float, optional
        Smallest distance (pixels) to another source; default: a star is rejected only when a
        neighbour's light reaches its core, and the other neighbours' pixels are masked.
    locus_width : float or "auto", default="auto"
        Relative half-width of the size-magnitude locus.
    max_spread_model : float, default=0.003
        Largest ``|SPREAD_MODEL|`` of a point source, unless it rejects most of the locus.
    min_class_star : float, default=0.8
        Smallest ``CLASS_STAR`` of a point source, unless it rejects most of the locus.

    Examples
    --------
    >>> from sklearn_psf.exposure import SelectionCuts
    >>> cuts = SelectionCuts(min_snr=10)
    >>> cuts.min_snr, hex(cuts.flag_mask), cuts.select_kwargs()["locus_width"]
    (10, '0xfe', 'auto')
    """

    flag_mask: int | None = PSFEX_FLAG_MASK
    min_snr: float = 20.0
    isolation: float | None = None
    locus_width: float | str = "auto"
    max_spread_model: float = 0.003
    min_class_star: float = 0.8

    def select_kwargs(self) -> dict:
        """The cuts as keyword arguments of :func:`~sklearn_psf.exposure.select_stars`."""
        return dataclasses.asdict(self)


@dataclasses.dataclass
class ExposureFit:
    """A PSF model of an exposure and its verdict, as :func:`fit_exposure` returns them.

    Attributes
    ----------
    model : PSFModel
        Fitted on the selected, non-reserved stars.
    residuals : astropy.table.Table
        The reserved stars' residuals (see :func:`~sklearn_psf.validation.fit_and_validate`).
    summary : dict
        The verdict (see :func:`~sklearn_psf.validation.fit_and_validate`), what the model file
        saves with the model, with ``selection`` (the stamp cut's counts), ``image`` (the
        input's path), ``interpolator``, ``nan_pixels``, ``saturation``, ``gain``, ``keys``
        (the catalogue columns of the model's extra dimensions, when given) and ``wcs``
        (header string) when the image has a celestial WCS.
    selection : dict
        The star selection's counts (:func:`~sklearn_psf.exposure.select_stars`), {} without
        one.
    stars : StarStamps
        The stamps the model was fitted and validated on; with a catalogue, ``stars.rows``
        holds each star's row in it (0-based), e.g. the reserved stars'
        ``stars.rows[residuals["index"]]``.
    lines : list of str
        What was read and selected, in words (the start of :meth:`report`).
    image_shape : tuple of int
        (ny, nx) of the field (the image, its header, else the stars' extent).
    """

    model: object
    residuals: object
    summary: dict
    selection: dict
    stars: object
    lines: list
    image_shape: tuple

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
                      CatalogColumnWarning, stacklevel=4)
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


def _read_stage(image, catalog, read_options, keys, stamp_size):
    """Read the exposure; check the keys are columns and the stamp fits; the report's first
    line (the image's bad pixels). Returns the inputs, the stamp side, the report lines and
    the number of NaN pixels."""
    inputs = read_exposure(image, catalog, **read_options)
    data, table = inputs.image, inputs.catalog
    if keys:
        if table is None:
            raise InputError(f"keys ({', '.join(keys)}) are catalogue columns: give a "
                             "catalogue")
        key_columns(table[:0], keys, _source(inputs))  # a missing column named before any work
    lines, n_nan = [], 0
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
    return inputs, stamp_size, lines, n_nan


def _source(inputs):
    """How messages name the exposure."""
    return inputs.catalog_path or inputs.image_path or "the catalogue"


def _catalog_lines(inputs, table):
    """The catalogue's report lines; positions all off the image are refused."""
    lines = [f"sources in the catalogue: {len(table)}"
             f" ({'1' if table.meta['one_based'] else '0'}-based "
             f"{table.meta['x_column']}, {table.meta['y_column']})"]
    if (inputs.saturation_source or "").startswith("catalogue"):
        lines.append(f"saturation level: {inputs.saturation:.6g}, where the highest "
                     f"pixels of the brightest sources pile up (the header gives no "
                     f"SATURATE; {inputs.saturation_source}): stars peaking above 0.9 "
                     "of it are left out (--saturation sets it)")
    data = inputs.image
    if data is not None:
        x, y = np.asarray(table["x"]), np.asarray(table["y"])
        ny, nx = data.shape
        if not ((x > -0.5) & (x < nx - 0.5) & (y > -0.5) & (y < ny - 0.5)).any():
            raise InputError(
                f"All {len(table)} catalogue positions fall outside the image "
                f"{inputs.image_path} (ny, nx = {ny}, {nx}): check the HDU, or whether "
                "the positions are 1-based (one_based=True, --one-based)")
    return lines


def _select_catalog(inputs, cuts, stamp_size, lines):
    """The catalogue's stars (:func:`select_stars`): the selected rows' table, the counts,
    the rows in the full catalogue and the full catalogue as selected (with the VIGNETs cut
    from the image when it has none)."""
    from ._select import select_stars

    data, table = inputs.image, inputs.catalog
    if data is not None and not any(c.upper() == "VIGNET" for c in table.colnames):
        # sources measured on the image's cut-outs, their neighbours masked, as on
        # a catalogue's VIGNETs (FLUX_RADIUS would carry the neighbours' light)
        from ._stars import _image_vignettes

        table = table.copy(copy_data=False)
        table["VIGNET"] = _image_vignettes(data, table, stamp_size, inputs.weight)
    keep, counts = select_stars(table, image_shape=None if data is None else data.shape,
                                saturation=inputs.saturation, stamp_size=stamp_size,
                                min_stars=0, **cuts.select_kwargs())
    n_kept = int(keep.sum())
    lines += _selection_lines(counts, n_kept, "selected as stars: ", cuts.max_spread_model,
                              cuts.min_class_star)
    if n_kept < MIN_STARS:
        raise StarSelectionError(
            f"{n_kept} of the {len(table)} sources of {_source(inputs)} pass the star "
            "selection", counts, "or use no selection (select=False, --no-select) if "
            "the catalogue holds stars only", lines)
    table, full = table[keep], table
    if cuts.flag_mask is not None and "flags" in table.colnames:
        # flags outside the mask were accepted: the stamp cutters must not skip them
        table["flags"] = np.asarray(table["flags"]).astype(np.int64) & int(cuts.flag_mask)
    return table, counts, np.flatnonzero(keep), full


def _find_on_image(inputs, cuts, stamp_size, lines):
    """The image's stars (:func:`find_stars`) and the finder's counts."""
    from ._stars import find_stars

    table = find_stars(inputs.image, weight=inputs.weight, stamp_size=stamp_size,
                       min_snr=cuts.min_snr, saturation=inputs.saturation,
                       isolation=cuts.isolation, locus_width=cuts.locus_width)
    counts = {**table.meta["rejected"], "locus_size": None}
    lines += _selection_lines(counts, len(table), f"sources detected: "
                              f"{table.meta['n_detections']}, selected as stars: ",
                              cuts.max_spread_model, cuts.min_class_star)
    if len(table) < MIN_STARS:
        raise StarSelectionError(
            f"found {len(table)} usable stars in {inputs.image_path} "
            f"({table.meta['n_detections']} detections)", counts,
            "or give a star catalogue", lines)
    return table, counts


def _cut_stage(inputs, table, stamp_size, keys, selected, isolation, lines):
    """The stars' stamps, their neighbours masked (with ``selected``, the rows of the
    selected stars and the catalogue they were selected in), their rows in the catalogue;
    the key values of the stars used (None without keys)."""
    source = _source(inputs)
    stars = inputs.cut_stamps(table, stamp_size)
    extra = _drop_missing_keys(stars, keys, source) if keys else None
    skipped = {k: v for k, v in stars.counts.items() if k not in ("input", "used") and v}
    lines.append(f"stars used: {stars.counts['used']} of {stars.counts['input']}"
                 + (" (skipped: " + ", ".join(f"{k} {v}" for k, v in skipped.items()) + ")"
                    if skipped else ""))
    used = np.asarray(stars.catalog["used"], dtype=bool)
    rows, full = selected or (None, None)
    if rows is not None and isolation is None:
        _mask_neighbours(stars, full, rows[used], lines)
    if table is not None and inputs.catalog is not None:  # the stars' rows in the catalogue
        stars.rows = (np.flatnonzero(used) if rows is None else rows[used])
    if stars.counts["used"] < MIN_STARS:
        raise InputError(f"{stars.counts['used']} stars of {source} are usable: too few for "
                         f"a PSF model (need {MIN_STARS})")
    return stars, extra


def _fit_stage(X, stars, wcs, interpolator, basis, reserve, random_state):
    """The model fitted and judged (:func:`~sklearn_psf.validation.fit_and_validate`)."""
    from ..model import INTERPOLATORS, PSFModel, make_interpolator
    from ..validation import fit_and_validate

    options = {"reserve": reserve, "random_state": random_state, "weights": stars.weights,
               "wcs": wcs}
    if interpolator == "auto":
        candidates = {n: PSFModel(basis=basis, interpolator=make_interpolator(n))
                      for n in INTERPOLATORS}
        return fit_and_validate(X, stars.stamps, candidates=candidates, **options)
    return fit_and_validate(
        X, stars.stamps, PSFModel(basis=basis, interpolator=make_interpolator(interpolator)),
        **options)


def _add_to_summary(summary, inputs, stars, interpolator, n_nan, keys, wcs):
    """What the summary (saved in the model file) says of the exposure besides the verdict."""
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


def fit_exposure(image=None, catalog=None, *, hdu=None, weight_hdu=None,
                 one_based: bool | None = None, x_col: str | None = None,
                 y_col: str | None = None, select: bool = True,
                 cuts: SelectionCuts | None = None, saturation: float | None = None,
                 stamp_size: int | None = None, interpolator: str = "kriging",
                 reserve: float = 0.2, random_state=0, keys=None, band_limit=None,
                 basis=None, progress=None) -> ExposureFit:
    """Fit and validate the PSF model of an exposure, from its files to the verdict.

    What ``sklearn-psf fit`` does, as one call: read the exposure (:func:`read_exposure`),
    select the stars (:func:`~sklearn_psf.exposure.select_stars` with a catalogue,
    :func:`~sklearn_psf.exposure.find_stars` without), cut their stamps and mask their
    neighbours, then fit and judge the model
    (:func:`~sklearn_psf.validation.fit_and_validate`); :ref:`exposure-details` in the user
    guide.

    Parameters
    ----------
    image, catalog, hdu, weight_hdu, one_based, x_col, y_col :
        The inputs, as :func:`read_exposure` takes them. The catalogue's x, y must fall on
        the image.
    select : bool, default=True
        False uses every catalogue row as a star (a catalogue of stars only).
    cuts : SelectionCuts, optional
        The selection's cuts (``flag_mask``, ``min_snr``, ``isolation``, ``locus_width``,
        ``max_spread_model``, ``min_class_star``); default ``SelectionCuts()``, the
        command's defaults.
    saturation : float, optional
        Saturation level: stars peaking near it are left out. Default the header's
        ``SATURATE``, else where the catalogue's brightest peaks pile up.
    stamp_size : int, optional
        Stamp side; default the catalogue's VIGNET side, else 25.
    interpolator : str, default="kriging"
        A scheme of :func:`~sklearn_psf.model.make_interpolator`, or ``"auto"`` to choose it
        by cross-validation among them.
    reserve : float, default=0.2
        Fraction of the stars reserved for the verdict.
    random_state : int, default=0
        Seed of the reserved-star draw.
    keys : sequence of str, optional
        Catalogue columns (a colour, a magnitude) added as the model's dimensions after the
        positions, as PSFEx's ``PSFVAR_KEYS`` (:func:`key_columns`); stars with a NaN in a
        key are left out with a :class:`~sklearn_psf.io.CatalogColumnWarning`.
    band_limit, basis : float or estimator, optional
        The stamp basis, unfitted (cloned, not modified), e.g. ``StampPCA()`` on
        undersampled stars; or, with ``band_limit`` (cycles per pixel, the optics'
        ``D / lambda`` in pixels), ``SuperResolvedPCA(band_limit=band_limit)``. Not both.
        Default: ``PSFModel``'s basis.
    progress : callable, optional
        Called with the name of each step (``"selecting stars"``, ``"cutting stamps"``,
        ``"fitting and validating"``) as it starts: a progress bar's hook.

    Returns
    -------
    ExposureFit
        The model, its verdict, the stars, the report.

    Raises
    ------
    StarSelectionError
        Fewer than 5 stars pass the selection (the counts of each cut in the message).
    ValueError
        Unreadable inputs (the file named), positions all off the image, a key that is not a
        catalogue column.

    Examples
    --------
    >>> import warnings
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf import make_psf_field
    >>> from sklearn_psf.exposure import fit_exposure
    >>> field = make_psf_field(n_stars=60, n_galaxies=1, image_shape=(1000, 1000),
    ...                        random_state=0)
    >>> stamps, weights, flags = field.star_stamps(normalize=False, return_weights=True)
    >>> cat = Table({"x": field.stars["x"], "y": field.stars["y"],
    ...              "VIGNET": stamps.reshape(60, field.stamp_size, field.stamp_size)})
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     fit = fit_exposure(catalog=cat, select=False, reserve=0.2)
    >>> fit.summary["n_reserved"], fit.summary["n_fit"]
    (12, 48)
    >>> fit.report()[0]
    'sources in the catalogue: 60 (0-based x, y)'
    >>> [w.category.__name__ for w in caught]  # 48 stars, too few for this PSF: a warning
    ['PSFQualityWarning']
    """
    from ..io import celestial_wcs

    if band_limit is not None and basis is not None:
        raise ValueError("give band_limit or basis, not both: band_limit sets the basis "
                         "SuperResolvedPCA(band_limit=band_limit)")
    cuts = SelectionCuts() if cuts is None else cuts
    step = progress or (lambda name: None)
    keys = [str(k) for k in (keys or ())]
    inputs, stamp_size, lines, n_nan = _read_stage(
        image, catalog, {"hdu": hdu, "weight_hdu": weight_hdu, "one_based": one_based,
                         "x_col": x_col, "y_col": y_col, "saturation": saturation},
        keys, stamp_size)
    step("selecting stars")
    table, counts, selected = inputs.catalog, {}, None
    if table is None:
        table, counts = _find_on_image(inputs, cuts, stamp_size, lines)
    else:
        lines += _catalog_lines(inputs, table)
        if select:
            table, counts, *selected = _select_catalog(inputs, cuts, stamp_size, lines)
    step("cutting stamps")
    stars, extra = _cut_stage(inputs, table, stamp_size, keys, selected, cuts.isolation,
                              lines)
    X = stars.positions if extra is None else np.column_stack([stars.positions, extra])
    step("fitting and validating")
    wcs = celestial_wcs(inputs.header)
    if band_limit is not None:  # (a given basis: PSFModel fits a clone of it)
        from ..preprocessing import SuperResolvedPCA

        basis = SuperResolvedPCA(band_limit=float(band_limit))
    model, residuals, summary = _fit_stage(X, stars, wcs, interpolator, basis, reserve,
                                           random_state)
    _add_to_summary(summary, inputs, stars, interpolator, n_nan, keys, wcs)
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


