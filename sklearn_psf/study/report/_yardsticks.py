"""The report's yardsticks: metric definitions, the ratio to the oracle, the verdicts' assumptions.

- :data:`METRICS`: each column of the scores table with its unit and definition.
- :func:`oracle_ratios`: every scheme against the best linear unbiased predictor on the same
  simulations (e rms, and the residual correlation D1 theta bin by theta bin).
- :func:`multipole_sensitivity`: median sigma_sys^2 for several upper multipoles of the
  integral (the survey verdicts depend on it).
- :func:`d1_rule`: the paper's own rule, D1 against the requirement line theta by theta.
"""

from __future__ import annotations

import numpy as np
from astropy.table import Table

from .._names import ORACLE
from ..plotting._common import _mask, _unique_in_order

#: Fewer simulations per configuration than this and a verdict is flagged as underpowered.
MIN_SIMULATIONS = 10
#: Upper multipoles of the sensitivity row of sigma_sys^2.
ELL_MAX_VALUES = (3e3, 5e3, 1e4, 2e4, 5e4)

#: (column, unit, definition) of the scores table.
METRICS = (
    ("e_rms", "dimensionless", "rms over galaxy-PSFs of |e_model - e_true|, e = (e1, e2) the "
     "adaptive-moment distortion (Q11 - Q22, 2 Q12) / (Q11 + Q22)"),
    ("e1_rms, e2_rms", "dimensionless", "the same per component"),
    ("e_rms_ratio", "dimensionless", "e_rms of the scheme over e_rms of the oracle on the same "
     "simulation (1 = optimal)"),
    ("coeff_rms", "normalised flux units (stamp sums to 1)", "rms over galaxy-PSFs and PCA "
     "components of model minus true coefficient (NaN for models with their own basis)"),
    ("rho1_mean_abs", "dimensionless", "mean over theta bins of |D1(theta)|, D1 = xi+ of the "
     "ellipticity residuals (Rowe 2010's rho1)"),
    ("sigma_sys2", "dimensionless (shear variance)", "variance of the systematic shear implied by "
     "D1 (Amara & Refregier 2008): D1 bounds delta xi+ through P_gamma = 1.84 and a galaxy/PSF "
     "size ratio 1.5, Hankel-transformed to C_l and integrated over l(l+1) C_l / 2 pi dln l"),
    ("dM22_rel_rms", "dimensionless", "rms over galaxy-PSFs of the spin-0 fourth moment's "
     "residual (M22 of the model - of the truth) over the true sigma^4; M22 = <r^4> under the "
     "adaptive Gaussian weight (PIFF's definition), 2 sigma^4 for a Gaussian; the main "
     "comparison's configuration only"),
    ("dM4_rel_rms", "dimensionless", "the same for the spin-2 fourth moment, |dM31 + i dM13|, "
     "M31 = <r^2 (u^2 - v^2)>, M13 = <2 r^2 u v>"),
    ("theta", "arcmin", "separation of the correlation bins (log-spaced)"),
    ("best_score", "dimensionless", "tuning: minus the mean |rho1| of held-out stars between 1 "
     "and 10 arcmin in 5-fold cross-validation (higher is better)"),
    ("fit_seconds", "s", "wall time of one model's fit"),
)


def underpowered(n_simulations) -> str:
    """A note for a verdict drawn from too few simulations, else ``""``."""
    n = int(n_simulations)
    if n >= MIN_SIMULATIONS:
        return ""
    return f" (underpowered: {n} simulation{'s' if n != 1 else ''}, < {MIN_SIMULATIONS})"


def _mean_xi(correlations, config, scheme, kind="residual"):
    rows = correlations[_mask(correlations, config=config, scheme=scheme, kind=kind)]
    if len(rows) == 0:
        return None
    return np.asarray(rows["xi"], float).reshape(len(rows), -1)


def _nonzero(xi_stack):
    """Bins whose mean over simulations is more than two standard errors from zero."""
    if len(xi_stack) < 2:
        return np.zeros(xi_stack.shape[1], bool)
    sem = xi_stack.std(0, ddof=1) / np.sqrt(len(xi_stack))
    return np.abs(xi_stack.mean(0)) > 2 * sem


def oracle_ratios(result, config: str = "default") -> Table | None:
    """Each scheme's e rms and D1 over the oracle's, on the simulations of ``config``.

    Returns
    -------
    table : astropy.table.Table or None
        One row per scheme: ``e_rms_ratio`` median, 16th and 84th percentiles over
        simulations, ``d1_ratio`` (per theta bin: |mean D1| of the scheme over |mean D1| of
        the oracle) and ``d1_significant`` (both means more than two standard errors from
        zero; elsewhere the ratio is noise). None when the study has no oracle.
    """
    scores = result.scores
    if "e_rms_ratio" not in scores.colnames:
        return None
    sel = scores[np.asarray(scores["config"]).astype(str) == config]
    correlations = getattr(result, "correlations", None)
    floor = None if correlations is None else _mean_xi(correlations, config, ORACLE)
    rows = []
    for scheme in _unique_in_order(sel["scheme"]):
        ratio = np.asarray(sel["e_rms_ratio"][np.asarray(sel["scheme"]) == scheme], float)
        ratio = ratio[np.isfinite(ratio)]
        if not ratio.size:
            continue
        d1 = None if floor is None else _mean_xi(correlations, config, scheme)
        nbins = len(result.theta)
        if d1 is None:
            d1_ratio, significant = np.full(nbins, np.nan), np.zeros(nbins, bool)
        else:
            d1_ratio = np.abs(d1.mean(0)) / np.abs(floor.mean(0))
            significant = _nonzero(d1) & _nonzero(floor)
        rows.append((scheme, len(ratio), float(np.median(ratio)), *np.percentile(ratio, [16, 84]),
                     d1_ratio, significant))
    names = ["scheme", "n_simulations", "e_rms_ratio_median", "e_rms_ratio_p16",
             "e_rms_ratio_p84", "d1_ratio", "d1_significant"]
    return Table(rows=rows, names=names) if rows else None


def multipole_sensitivity(result, config: str = "default",
                          ell_max_values=ELL_MAX_VALUES) -> Table | None:
    """Median sigma_sys^2 over simulations for several upper multipoles of the integral.

    Each simulation's C_l of D1 is computed once (:func:`~sklearn_psf.metrics.hankel_xi_to_cl`
    from l = 10 to the largest ``ell_max``, 155 points per decade as ``sigma_sys2``) and
    integrated up to each ``ell_max``.
    """
    from ...metrics import hankel_xi_to_cl, shear_bias_bound, sigma_sys2_from_cl

    correlations = getattr(result, "correlations", None)
    if correlations is None or getattr(result, "theta", None) is None:
        return None
    theta = np.asarray(result.theta, float)
    top = max(ell_max_values)
    ell = np.geomspace(10.0, top, int(155 * np.log10(top / 10.0)) + 1)
    rows = []
    for scheme in _unique_in_order(result.scores["scheme"]):
        d1 = _mean_xi(correlations, config, scheme)
        if d1 is None:
            continue
        per_sim = []
        for xi in d1:
            ok = np.isfinite(xi)
            if ok.sum() >= 2:
                cl = hankel_xi_to_cl(theta[ok], shear_bias_bound(xi[ok]), ell)
                per_sim.append([sigma_sys2_from_cl(ell[ell <= lmax], cl[ell <= lmax])
                                for lmax in ell_max_values])
        values = np.median(per_sim, axis=0) if per_sim else np.full(len(ell_max_values), np.nan)
        rows.append((scheme, *(float(v) for v in values)))
    names = ["scheme"] + [f"ell_max={v:g}" for v in ell_max_values]
    return Table(rows=rows, names=names) if rows else None


def d1_rule(result, surveys, config: str = "default") -> Table | None:
    """The paper's rule: a scheme meets a survey when |mean D1| is below the D1 limit of the
    survey's sigma_sys^2 at every theta bin (limits of :func:`~sklearn_psf.metrics.
    requirement_curves`, the paper's fig_cor lines)."""
    from ...metrics import requirement_curves

    correlations = getattr(result, "correlations", None)
    if correlations is None or getattr(result, "theta", None) is None or surveys is None:
        return None
    theta = np.asarray(result.theta, float)
    levels = [float(v) for v in surveys["sigma_sys2"]]
    limits = requirement_curves(theta, levels).d1_limit
    rows = []
    for scheme in _unique_in_order(result.scores["scheme"]):
        d1 = _mean_xi(correlations, config, scheme)
        if d1 is None:
            continue
        mean = np.abs(d1.mean(0))
        for survey, limit in zip(surveys["survey"], limits):
            below = mean <= np.asarray(limit, float)
            rows.append((scheme, str(survey), int(below.sum()), len(theta), bool(below.all())))
    names = ["scheme", "survey", "bins_below", "bins", "meets"]
    return Table(rows=rows, names=names) if rows else None
