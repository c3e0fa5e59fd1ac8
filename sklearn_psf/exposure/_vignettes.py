"""Star stamps from a catalogue's own cut-outs: SExtractor ``VIGNET`` (what PSFEx reads).

Centre convention
-----------------
SExtractor cuts ``VIGNET(v, v)`` around the pixel nearest to the object: with the 1-based
``X_IMAGE``, the vignette's pixel ``(v // 2, v // 2)`` is image pixel ``round(X_IMAGE)``
(1-based), i.e. ``floor(x + 0.5)`` for the 0-based ``x = X_IMAGE - 1`` the package uses, the
same pixel as :func:`~sklearn_psf.preprocessing.cut_stamps` centres a stamp on. For an odd
side that is the centre pixel; for an even one (e.g. 32x32) the pixel right of and above the
vignette's centre point (GalSim's ``Image.center``), and stamps cropped from it keep the star at
index ``stamp_size // 2``. The star itself sits at ``x - floor(x + 0.5)`` (in [-0.5, 0.5))
pixels from that pixel.
Masked pixels (SExtractor writes -1e30, also NaN) become zero-weight pixels set to 0.
"""

from __future__ import annotations

import numpy as np
from astropy.table import Table

from .._files import InputError
from ..preprocessing import estimate_pixel_weights
from ..io._image import _level
from ._select import _on_field
from ._stars import REJECTION_REASONS, StarStamps

__all__ = ["extract_vignettes", "VIGNET_MASKED"]

#: Value below which a VIGNET pixel is masked (SExtractor writes -1e30).
VIGNET_MASKED = -1e29


def extract_vignettes(catalog: Table, stamp_size: int | None = None, *,
                      saturation: float | None = None, gain: float | None = None,
                      core_size: int = 5, column: str = "VIGNET") -> StarStamps:
    """Star stamps and pixel weights from the ``VIGNET`` column of a catalogue: no image needed.

    Each vignette is cropped to its central ``stamp_size`` pixels (see the module's centre
    convention). A star is skipped, under the first reason that applies, when its position is
    NaN or off the image of ``catalog.meta["image_header"]`` (its ``NAXIS1`` x ``NAXIS2``:
    SExtractor's ``LDAC_IMHEAD``) (``bad_position``), its ``flags`` are non-zero
    (``catalog_flag``), a masked pixel lies in the central ``core_size`` box (``masked``) or a
    pixel reaches ``saturation`` (``saturated``).

    Weights are the inverse variance of each pixel: the background variance of the star's
    vignette (from its border, see :func:`~sklearn_psf.preprocessing.estimate_pixel_weights`:
    each vignette its own, pooled where they share one level), plus the source's Poisson
    variance ``max(pixel, 0) / gain`` when ``gain`` (e-/ADU) is given; 0 for masked pixels.

    Parameters
    ----------
    catalog : astropy.table.Table
        From :func:`~sklearn_psf.io.read_catalog` (0-based ``x``, ``y``; ``VIGNET`` of shape
        (n, v, v), background-subtracted as SExtractor writes it).
    stamp_size : int, optional
        Side of the stamps, at most v (odd or even, see the centre convention); default v.
    saturation : float, optional
        Saturation level; None: no cut.
    gain : float, optional
        Detector gain in e-/ADU for the Poisson part of the weights.
    core_size : int, default=5
    column : str, default="VIGNET"

    Returns
    -------
    StarStamps
        With ``weights``; ``counts`` holds every reason of
        :data:`~sklearn_psf.exposure.REJECTION_REASONS`.

    Raises
    ------
    InputError
        Without a vignette column, with a too small or too large ``stamp_size``, or when no
        star is usable.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import extract_vignettes
    >>> vig = np.random.default_rng(0).normal(0.0, 1.0, (2, 9, 9))
    >>> vig[:, 4, 4] += 100.0
    >>> vig[1, 0, 0] = -1e30                      # a masked pixel in the wing
    >>> cut = extract_vignettes(Table({"x": [10.2, 40.0], "y": [5.0, 7.4], "VIGNET": vig}), 7)
    >>> cut.stamps.shape, cut.weights.shape, cut.counts["used"]
    ((2, 49), (2, 49), 2)
    """
    lower = {c.lower(): c for c in catalog.colnames}
    if column.lower() not in lower:
        names = catalog.colnames
        shown = ", ".join(names[:8]) + (f", ... ({len(names)} columns)" if len(names) > 8
                                        else "")
        raise InputError(f"The catalogue has no {column} column ({shown}): give the image to "
                         f"cut the stamps, or have SExtractor write {column}(v,v).")
    n = len(catalog)
    if n == 0:
        raise InputError("The star catalogue is empty.")
    try:
        cube = np.array(catalog[lower[column.lower()]], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{column} does not hold numbers (type "
                         f"{catalog[lower[column.lower()]].dtype}).") from None
    if cube.ndim != 3 or cube.shape[1] != cube.shape[2] or cube.shape[1] < 3:
        raise InputError(f"{column} must hold square vignettes of side 3 or more, got shape "
                         f"{cube.shape[1:]}.")
    saturation, gain = _level(saturation, "saturation"), _level(gain, "gain")
    v = cube.shape[1]
    s = v if stamp_size is None else int(stamp_size)
    if s < 3 or s > v:
        raise InputError(f"stamp_size must be >= 3 and at most the vignette side {v}, "
                         f"got {stamp_size!r}.")
    lo = v // 2 - s // 2  # the star's pixel stays at index s // 2
    cube = cube[:, lo:lo + s, lo:lo + s]
    valid = np.isfinite(cube) & (cube > VIGNET_MASKED)
    stamps = np.where(valid, cube, 0.0)
    sky = estimate_pixel_weights(np.where(valid, cube, np.nan)).reshape(cube.shape)
    var = 1.0 / np.where(valid, sky, 1.0)
    if gain is not None:
        var = var + np.maximum(stamps, 0.0) / float(gain)
    weights = np.where(valid, 1.0 / var, 0.0)
    pos = np.column_stack([np.asarray(catalog["x"], dtype=np.float64),
                           np.asarray(catalog["y"], dtype=np.float64)])
    h, c = s // 2, max(1, min(int(core_size), s)) // 2
    flags = np.asarray(catalog["flags"]) if "flags" in catalog.colnames else np.zeros(n)
    tests = {
        "bad_position": ~_on_field(pos[:, 0], pos[:, 1], None,
                                   catalog.meta.get("image_header")),
        "catalog_flag": flags != 0,
        "masked": ~valid[:, h - c:h + c + 1, h - c:h + c + 1].all(axis=(1, 2)),
        "saturated": (np.where(valid, cube, -np.inf).max(axis=(1, 2)) >= float(saturation)
                      if saturation is not None else np.zeros(n, dtype=bool)),
    }
    reason = np.full(n, "", dtype=object)
    for name in REJECTION_REASONS:
        if name in tests:
            reason[(reason == "") & tests[name]] = name
    used = reason == ""
    counts = {"input": n, "used": int(used.sum())}
    counts.update({name: int(np.count_nonzero(reason == name)) for name in REJECTION_REASONS})
    if not used.any():
        skipped = ", ".join(f"{k}: {v}" for k, v in counts.items()
                            if k not in ("input", "used") and v)
        raise InputError(f"None of the {n} catalogue vignettes is usable ({skipped}).")
    out = Table(catalog, copy=False)
    out = out[[name for name in out.colnames if name != lower[column.lower()]]]
    out["used"] = used
    out["reason"] = np.asarray(reason, dtype=str)
    return StarStamps(pos[used], stamps[used].reshape(-1, s * s), out, counts,
                      weights[used].reshape(-1, s * s))
