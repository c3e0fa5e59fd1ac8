"""Benchmark: where PSFModel()'s excess over the oracle comes from (a decomposition).

On each simulation of the default field (1000 stars, 2000 galaxy-PSFs; S/N 100 unless
``--snr``), every row below predicts the PSF at the galaxy-PSFs; ``e_rms`` is the rms over
the galaxy-PSFs (measured in every row) of |e_predicted - e_true| (adaptive moments), and
each row is printed as its ratio to the oracle's ``e_rms`` (median and 16th-84th
percentiles over the simulations):

- ``PSFModel()``: the default model on raw stamps with their weights;
  ``PSFModel(outliers=None)``: the same without outlier rejection (what rejecting clean stars
  costs); ``PSFModel(), MinMaxScaler``: with the previous default interpolator, positions scaled to [0, 1] on each axis (the
  field, 10,032 x 7,769 pixels, stretched by 1.29 along y) instead of by the longer side;
- ``oracle on PSFModel's basis``: the oracle's predictor (best linear unbiased, the true
  signal covariance, each star's k x k noise covariance as the basis propagates it) applied
  to ``PSFModel()``'s own coefficients on its own estimated basis, rendered with that basis.
  The true covariance of those coefficients is the field's, mapped by the linear regression
  of the estimated coefficients on the stars' true ones (``c = b + M w``). Its excess over
  the oracle is what the estimated basis costs; PSFModel()'s excess over it is what the
  interpolation (kernel, hyperparameters) costs on that basis;
- ``reference basis, default interpolator``: the default interpolator (fitted kernel,
  co-Kriging with the propagated noise) on the oracle's own measurement (weighted
  least-squares coefficients on the simulation's basis), rendered with that basis: the
  interpolation's cost without the basis's (``exact ML``: with the exact likelihood instead
  of Vecchia's approximation; ``MinMaxScaler``: as above; ``noise variances only``: each
  coefficient Kriged on its own with its noise variance, no co-Kriging);
- ``PSFModel's basis, true coefficients``: the true galaxy-PSF stamps fitted on
  ``PSFModel()``'s basis (mean + components, least squares, flux free): the ellipticity error
  of the best stamps that basis can represent, as a fraction of the oracle's ``e_rms`` (an
  error of its own, not a ratio of two models: it does not add in quadrature to the others).

``PSFModel() / oracle`` is the product of ``PSFModel() / oracle on PSFModel's basis`` (what
the interpolation costs) and ``oracle on PSFModel's basis / oracle`` (what the basis costs).

Run ``python benchmarks/bench_optimum_gap.py`` (10 simulations, S/N 100) or
``--seeds 1 2 3``; ``--snr realistic`` for the realistic S/N mix. BLAS on one thread.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler

from sklearn_psf import PSFModel, adaptive_moments
from sklearn_psf.model import make_default_interpolator
from sklearn_psf.model._noise import fit_interpolator
from sklearn_psf.study.compare import FieldOracle
from sklearn_psf.study.compare._oracle import _CoKriging, universal_co_kriging

from bench_optimum import field, galaxies, star_data


def blup(f, X, coef, noise_cov, X_query, M=None):
    """Best linear unbiased predictor of ``coef`` (n, k) at ``X_query`` with the field's true
    covariance, when ``coef = b + w @ M.T`` (w the true weights; M = I by default) plus noise
    of covariance ``noise_cov`` (n, k, k)."""
    k = coef.shape[1]
    M = np.eye(k) if M is None else M
    Minv = np.linalg.inv(M)
    z = coef @ Minv.T  # weights plus an offset: the field's covariance
    noise_z = Minv @ noise_cov @ Minv.T
    d, K = f.weight_covariance_factors(X)
    _, mean, alpha = universal_co_kriging(_CoKriging((d, K), noise_z), z)
    _, Kq = f.weight_covariance_factors(X_query, X)
    pred_z = mean + (Kq @ alpha.T) * d
    return pred_z @ M.T


def e_errors(stamps, f):
    mom = adaptive_moments(np.asarray(stamps, float))
    de = np.column_stack([mom["e1"] - f.galaxies["e1"], mom["e2"] - f.galaxies["e2"]])
    return de, np.asarray(mom["flag"]) == 0


def minmax_interpolator():
    """The previous default interpolator: each axis scaled to [0, 1]."""
    return make_pipeline(MinMaxScaler(), make_default_interpolator()[-1])


def decompose(seed, snr):
    f = field(seed, snr)
    X, stamps, weights, keep = star_data(f)
    Xg = galaxies(f)
    rows = {}
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = PSFModel().fit(X[keep], stamps[keep], weights=weights[keep])
        seconds = time.perf_counter() - t0
        rows["PSFModel()"] = model.predict(Xg)
        for name, kw in (("PSFModel(outliers=None)", {"outliers": None}),
                         ("PSFModel(), MinMaxScaler", {"interpolator": minmax_interpolator()})):
            other = PSFModel(**kw).fit(X[keep], stamps[keep], weights=weights[keep])
            rows[name] = other.predict(Xg)
    Xs = model.X_fit_
    inl = model.inlier_mask_

    oracle = FieldOracle(f).fit(Xs)
    rows["oracle"] = oracle.predict(Xg)
    ref = oracle.basis_
    fit = ref.project(stamps[keep], weights[keep])  # the oracle's measurement, propagated noise
    used = inl & (fit.flag == 0)

    # the oracle's predictor on PSFModel's own basis and coefficients
    c_est = model.coefficients_[inl]
    w_true = np.asarray(f.stars["coeffs"], float)[oracle.rows_][inl]
    design = np.column_stack([np.ones(len(w_true)), w_true])
    lsq = np.linalg.lstsq(design, c_est, rcond=None)[0]
    M = lsq[1:].T  # (k_est, k_ref)
    if M.shape[0] == M.shape[1]:
        c_pred = blup(f, Xs[inl], c_est, model.coefficient_cov_[inl], Xg, M)
        rows["oracle on PSFModel's basis"] = model.basis_.inverse_transform(c_pred)

    # the default interpolator on the oracle's measurement (reference basis)
    exact = make_default_interpolator().set_params(krigingregressor__likelihood="exact")
    for name, interp in (("reference basis, default interpolator",
                          make_default_interpolator()),
                         ("reference basis, exact ML", exact),
                         ("reference basis, MinMaxScaler", minmax_interpolator()),
                         ("reference basis, noise variances only", make_default_interpolator())):
        cov = None if "variances" in name else fit.coefficient_cov[used]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit_interpolator(interp, Xs[used], fit.coefficients[used],
                             fit.coefficient_var[used], cov)
        rows[name] = ref.inverse_transform(interp.predict(Xg))

    # PSFModel's basis with the true coefficients of the galaxy-PSFs (its floor)
    truth = np.asarray(f.galaxies["stamp"], float)
    truth = truth / truth.sum(axis=1, keepdims=True)
    b = model.basis_
    basis = np.vstack([b.mean_, b.components_])
    a = np.linalg.lstsq(basis.T, truth.T, rcond=None)[0].T  # flux free, as the stars' fit
    c_true = a[:, 1:] / a[:, :1]
    rows["PSFModel's basis, true coefficients"] = b.inverse_transform(c_true)

    errs = {name: e_errors(s, f) for name, s in rows.items()}
    truth_ok = np.asarray(f.galaxies["moments_flag"]) == 0
    de_o, ok_o = errs.pop("oracle")
    ratios = {}
    for name, (de, ok) in errs.items():  # on the galaxy-PSFs measured in both, as
        both = ok & ok_o & truth_ok      # oracle_e_rms_ratio (bench_optimum.py) does
        ratios[name] = float(np.sqrt(np.mean(np.sum(de[both] ** 2, axis=1))
                                     / np.mean(np.sum(de_o[both] ** 2, axis=1))))
    oracle_rms = float(np.sqrt(np.mean(np.sum(de_o[ok_o & truth_ok] ** 2, axis=1))))
    return ratios, oracle_rms, seconds, model.n_components_, int((~inl).sum())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    parser.add_argument("--snr", default="100", help="a S/N or 'realistic'")
    args = parser.parse_args(argv)
    table = []
    with threadpool_limits(1):
        for seed in args.seeds:
            ratios, oracle_rms, seconds, k, rejected = decompose(seed, args.snr)
            table.append(ratios)
            if len(table) == 1:
                print("columns: " + "; ".join(ratios))
            print(f"seed {seed:2d}: oracle e_rms {oracle_rms:.5f}, k = {k}, {rejected} stars "
                  f"rejected, fit {seconds:.1f} s; ratios "
                  + "  ".join(f"{v:.4f}" for v in ratios.values()), flush=True)
    print(f"\nS/N {args.snr}: e_rms / oracle's e_rms over {len(table)} simulations "
          "(median, 16-84%)")
    for name in table[0]:
        r = np.array([t[name] for t in table if name in t])
        lo, med, hi = np.percentile(r, [16, 50, 84])
        print(f"  {name:40s} {med:.4f}  ({lo:.4f}-{hi:.4f})")
    print("(the last row is an error of its own over the oracle's, not a model's ratio)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
