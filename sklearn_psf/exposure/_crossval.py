"""K-fold cross-validation of PSF models on a catalogue's stars: every star judged once, out
of sample, by every model, so that two tools are compared star by star (a paired test)."""

from __future__ import annotations

import os
import tempfile

import numpy as np
from astropy.table import Table

from .._files import InputError

__all__ = ["CrossValidation", "cross_validate_catalog"]


class CrossValidation:
    """What :func:`cross_validate_catalog` returns.

    Attributes
    ----------
    table : astropy.table.Table
        One row per star judged: ``row`` (its row in the catalogue, 0-based), ``x``, ``y``
        (0-based pixels), ``snr`` (the catalogue's S/N, NaN without one), ``fold`` (from
        0), ``dof``, ``judged`` (1 where every PSFEx
        setting accepts the star: the comparisons' stars, else 0), and for every model
        ``chi2_<name>`` (NaN where the model could not be measured on it).
    models : list of str
        The models' names, this package's first.
    counts : dict
        ``n_rows`` (catalogue rows), ``n_selected`` (stars this package selects),
        ``n_psfex`` (stars PSFEx accepts, per PSFEx setting), ``n_judged`` (stars in the
        comparisons), and ``n_fit`` (the stars each fold's model of this package rests on,
        per fold).
    """

    def __init__(self, table, models, counts):
        self.table, self.models, self.counts = table, list(models), dict(counts)

    def compare(self, a=None, b=None, **kwargs) -> dict:
        """:func:`~sklearn_psf.validation.paired_comparison` of model ``a`` (default this
        package's) against ``b`` (default the next model)."""
        a = self.models[0] if a is None else a
        b = self.models[1] if b is None else b
        t = self.table[np.asarray(self.table["judged"], dtype=bool)]
        from ..validation import paired_comparison

        return paired_comparison(t[f"chi2_{a}"], t[f"chi2_{b}"], t["dof"], **kwargs)

    def lines(self) -> list:
        """The comparison in words, one line per model against this package's."""
        ours = self.models[0]
        t = self.table[np.asarray(self.table["judged"], dtype=bool)]
        out = [f"{len(t)} stars judged out of sample in {int(np.max(t['fold'])) + 1} folds "
               "(chi^2 of each raw star against the model moved to it by a fitted sub-pixel "
               "shift, with its flux and background fitted, in the star's pixel noise)"]
        for name in self.models:
            c = np.asarray(t[f"chi2_{name}"], float)
            ok = np.isfinite(c)
            out.append(f"  {name}: {int(ok.sum())} stars measured, summed chi^2/dof "
                       f"{c[ok].sum() / np.asarray(t['dof'])[ok].sum():.4f}")
        for other in self.models[1:]:
            r = self.compare(ours, other)
            if not r["n"]:
                continue
            lo, hi = r["mean_diff_ci"]
            out.append(
                f"  {ours} against {other} on the {r['n']} stars both measure: lower chi^2 on "
                f"{r['a_lower']:.0%} of them (sign test p = {r['sign_p']:.2g}); summed chi^2 "
                f"ratio {r['sum_ratio']:.4f}; median ratio {r['median_ratio']:.4f}; mean "
                f"difference of chi^2/dof {r['mean_diff']:+.4f} (95% bootstrap interval "
                f"{lo:+.4f} to {hi:+.4f})")
        return out


def _psfex_accepted(path, config, folder):
    """Which rows of the catalogue PSFEx accepts (``FLAGS_PSF`` 0 in its output catalogue)."""
    from astropy.io import fits

    from ..io import run_psfex

    out = os.path.join(folder, "psfex_full.cat")
    run_psfex(path, folder, config={**config, "OUTCAT_TYPE": "FITS_LDAC", "OUTCAT_NAME": out},
              overwrite=True)
    with fits.open(out) as hdul:
        objects = hdul["LDAC_OBJECTS"].data
        number = np.asarray(objects["SOURCE_NUMBER"]) - 1  # 1-based rows of the input
        flags = np.asarray(objects["FLAGS_PSF"])
    accepted = np.zeros(int(number.max()) + 1 if len(number) else 0, dtype=bool)
    accepted[number[flags == 0]] = True
    return accepted


def cross_validate_catalog(catalog, *, n_folds: int = 5, psfex=None, fit_options=None,
                           models=None, random_state=0, progress=None,
                           work_dir=None) -> CrossValidation:
    """K-fold cross-validation of this package's model (and PSFEx's) on a catalogue's stars.

    The stars this package selects (:func:`fit_exposure`'s selection, with usable
    VIGNETs) are split at random into ``n_folds`` folds. For each fold, every tool is fitted
    on the catalogue without that fold's stars (its own selection and outlier rejection on
    what is left: the catalogue written to a file, as PSFEx reads it) and judged on them:
    each star is judged once, out of sample, by every model, in the same pixels and noise
    (:func:`~sklearn_psf.validation.validate_models`: chi^2 of the raw star against the model
    moved to it by a fitted sub-pixel shift, its flux and background fitted; neighbours masked as
    :func:`fit_exposure` masks them). The comparisons (:meth:`CrossValidation.compare`)
    are on the stars that every PSFEx setting accepts when run on the whole catalogue
    (``FLAGS_PSF`` 0), the stars "both tools take".

    Parameters
    ----------
    catalog : str or os.PathLike
        A SExtractor FITS_LDAC catalogue with ``VIGNET`` stamps (PSFEx's input).
    n_folds : int, default=5
    psfex : dict, list of dict or None
        PSFEx settings (e.g. ``{"PSFVAR_DEGREES": 2}``, a model named ``psfex``), a list of
        them (named ``psfex_1``, ``psfex_2``, ...) or a dict of them by name; PSFEx must be
        installed. None: no PSFEx model.
    fit_options : dict, optional
        Options of :func:`fit_exposure` for this package's model (``reserve`` is 0); its
        ``cuts`` (:class:`SelectionCuts`) also select the stars to fold.
    models : dict, optional
        ``{name: callable(fold, train_catalog_path) -> model}``: further models per fold
        (an object with ``predict``, or a model file), ``fold`` from 0.
    random_state : int, default=0
        Seed of the folds.
    progress : callable, optional
        Called with a short text as each fold starts.
    work_dir : str, optional
        Folder for the folds' training catalogues (``fold<k>_train.ldac``, k from 1) and
        PSFEx's files (default a temporary folder, removed afterwards).

    Returns
    -------
    CrossValidation

    Raises
    ------
    InputError
        A catalogue without VIGNETs, or fewer selected stars than folds.
    """
    from sklearn.model_selection import KFold

    from ..io import run_psfex, write_catalog_rows
    from ..validation import load_psf_model, validate_models
    from ._fit import SelectionCuts, _mask_neighbours, fit_exposure
    from ._inputs import read_exposure
    from ._select import select_stars

    path = os.fspath(catalog)
    fit_options = {k: v for k, v in (fit_options or {}).items() if k != "reserve"}
    if psfex is None:
        psfex = {}
    elif isinstance(psfex, dict) and not all(isinstance(v, dict) for v in psfex.values()):
        psfex = {"psfex": psfex}
    elif not isinstance(psfex, dict):
        psfex = {("psfex" if len(psfex) == 1 else f"psfex_{k + 1}"): c
                 for k, c in enumerate(psfex)}
    configs = list(psfex.values())
    step = progress or (lambda text: None)
    inputs = read_exposure(catalog=path)
    table = inputs.catalog
    if not inputs.has_vignettes:
        raise InputError(f"{path} has no VIGNET column: cross-validation reads the stars' "
                         "stamps from the catalogue (PSFEx's input)")
    side = inputs.default_stamp_size
    cuts = fit_options.get("cuts") or SelectionCuts()
    flag_mask = cuts.flag_mask
    keep, _ = select_stars(table, saturation=inputs.saturation, stamp_size=side, min_stars=0,
                           **cuts.select_kwargs())
    stars_table = table.copy(copy_data=False)
    if flag_mask is not None and "flags" in stars_table.colnames:
        stars_table["flags"] = np.asarray(stars_table["flags"]).astype(np.int64) & int(flag_mask)
    selected = np.flatnonzero(keep)
    cut = inputs.cut_stamps(stars_table[selected], side)
    selected = selected[np.asarray(cut.catalog["used"], dtype=bool)]
    if len(selected) < n_folds:
        raise InputError(f"{len(selected)} stars of {path} are selected with usable VIGNETs: "
                         f"too few for {n_folds} folds")
    names = ["sklearn_psf", *psfex, *(models or {})]
    counts = {"n_rows": len(table), "n_selected": len(selected), "n_psfex": [], "n_fit": []}
    fold_of = np.full(len(table), -1)
    splits = KFold(n_folds, shuffle=True, random_state=random_state).split(selected)
    for k, (_, test) in enumerate(splits):
        fold_of[selected[test]] = k
    accepted = np.ones(len(table), dtype=bool)
    columns = {name: np.full(len(table), np.nan) for name in names}
    dof = np.zeros(len(table), dtype=np.int64)
    with tempfile.TemporaryDirectory(prefix="sklearn_psf_cv_") as tmp:
        folder = tmp if work_dir is None else os.fspath(work_dir)
        os.makedirs(folder, exist_ok=True)
        for j, config in enumerate(configs):
            ok = _psfex_accepted(path, config, os.path.join(tmp, f"full_{j + 1}"))
            ok = np.pad(ok, (0, max(0, len(table) - len(ok))))[:len(table)]
            counts["n_psfex"].append(int(ok.sum()))
            accepted &= ok
        for k in range(n_folds):
            step(f"fold {k + 1} of {n_folds}")
            test = np.flatnonzero(fold_of == k)
            train = os.path.join(folder, f"fold{k + 1}_train.ldac")
            write_catalog_rows(path, train, fold_of != k, overwrite=True)
            fitted = {}
            fit = fit_exposure(catalog=train, reserve=0.0, **fit_options)
            fitted["sklearn_psf"] = fit.model
            counts["n_fit"].append(int(np.sum(fit.model.inlier_mask_)))
            for j, config in enumerate(configs):
                out = os.path.join(tmp, f"fold{k + 1}_psfex{j + 1}")
                psf = run_psfex(train, out, config=config, overwrite=True)
                fitted[names[1 + j]] = load_psf_model(psf, side)
            for name, make in (models or {}).items():
                fitted[name] = make(k, train)
            stars = inputs.cut_stamps(stars_table[test], side)
            _mask_neighbours(stars, table, test, [])
            _, results = validate_models(stars.positions, stars.stamps, fitted,
                                         weights=stars.weights)
            for name, (res, _) in results.items():
                index = test[np.asarray(res["index"])]
                columns[name][index] = np.asarray(res["chi2"], float)
                dof[index] = np.asarray(res["dof"])
    rows = selected[dof[selected] > 0]
    snr = np.asarray(table["snr"], float)[rows] if "snr" in table.colnames else \
        np.full(len(rows), np.nan)
    out = Table({"row": rows, "x": np.asarray(table["x"])[rows],
                 "y": np.asarray(table["y"])[rows], "snr": snr, "fold": fold_of[rows],
                 "dof": dof[rows], "judged": accepted[rows].astype(np.int8)})
    for name in names:
        out[f"chi2_{name}"] = columns[name][rows]
    counts["n_judged"] = int(accepted[rows].sum())
    return CrossValidation(out, names, counts)
