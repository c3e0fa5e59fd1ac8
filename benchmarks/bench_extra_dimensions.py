"""Benchmark: colour and flux as dimensions of the PSF model (issue: the PSF of each source).

For each simulation (``make_psf_field`` with S/N uniform in 50-500, the same seed for every
variant, so that the stars, the PSF pattern and the noise are shared):

- a control field (the PSF of the position only), a chromatic one
  (``SourceSettings(chromatic=True, airmass=1.2)``: blackbody colours, stars g-i 0.3-3.0,
  galaxies 0-2) and a brighter-fatter one (``SourceSettings(brighter_fatter=0.02)``: the
  brightest star 2% larger than the faintest, galaxies fainter than every star);
- the default ``PSFModel`` on (x, y) and on (x, y, extra columns): g-i on the chromatic field,
  ``source_snr`` on the brighter-fatter one, both (doing nothing) on the control field.

Figures (relative size residual ``ds = (sigma_model - sigma_true) / sigma_true`` at the
galaxies, adaptive moments):

- colour: the slope of ``ds`` against the galaxies' g-i, position-only vs colour model (target:
  at most 10%), raw and paired (minus the position-only model's ``ds`` on the control field,
  which removes the interpolation error the two share); the colour part of the size rms (in
  quadrature above the same model's on the control field: the position-only model there, the
  colour model fitted with the colours that do nothing) (target: at most 0.5x), and paired:
  the rms of the difference of ``ds`` from the same model's on the control field;
- brighter-fatter: the mean ``ds`` at the galaxies, position-only vs flux model (target: at
  most 1e-3), raw and paired;
- no dependence: the e rms at the galaxies of the model with both extra columns over the
  position-only model's on the control field (paired per simulation; target: at most 1.02),
  and the fit-time ratio (best of ``--repeat`` fits of each, alternated, one BLAS thread;
  target: at most 1.5).

``--extra-drifts linear,quadratic`` measures the models with extra columns with each trend
in the extra dimensions (``KrigingRegressor(extra_drift=...)``; the default model's is
linear), paired on the same simulations.

Usage::

    python benchmarks/bench_extra_dimensions.py [--n-sims 10] [--n-stars 600]
                                                [--n-galaxies 2000] [--repeat 3]
                                                [--extra-drifts linear] [--first-seed 0]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from sklearn_psf.model import PSFModel
from sklearn_psf.simulate import SourceSettings, make_psf_field
from sklearn_psf.study.colour import galaxy_residuals


def _model(drift=None):
    model = PSFModel()
    if drift is not None:
        model.set_params(interpolator__krigingregressor__extra_drift=drift)
    return model


def _fit(field, extra=(), drift=None):
    return galaxy_residuals(_model(drift), field, extra)


def _fit_times(field, extra, repeat, drift=None):
    """Best fit time of the position-only and the extra-column model, fitted alternately
    (a busy spell of a shared machine then slows both)."""
    stamps, weights, _ = field.star_stamps(return_weights=True)
    best = [np.inf, np.inf]
    for _ in range(repeat):
        for i, cols in enumerate(((), extra)):
            X = np.column_stack([field.stars["x"], field.stars["y"]]
                                + [field.stars[c] for c in cols])
            t = time.perf_counter()
            _model(drift).fit(X, stamps, weights=weights)
            best[i] = min(best[i], time.perf_counter() - t)
    return best


def one_simulation(seed, n_stars, n_galaxies, repeat, drift=None):
    rng = np.random.default_rng(seed)
    kw = dict(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=(3000, 3000),
              snr=rng.uniform(50.0, 500.0, n_stars), random_state=seed)
    ctrl = make_psf_field(**kw)
    chrom = make_psf_field(sources=SourceSettings(chromatic=True, airmass=1.2), **kw)
    bf = make_psf_field(sources=SourceSettings(brighter_fatter=0.02), **kw)
    for name in ("stars", "galaxies"):  # the extra columns, doing nothing on the control
        getattr(ctrl, name)["g_i"] = getattr(chrom, name)["g_i"]
        getattr(ctrl, name)["source_snr"] = getattr(bf, name)["source_snr"]
    colour = np.asarray(chrom.galaxies["g_i"])
    ds0, de0 = _fit(ctrl)
    ds_x, de_x = _fit(ctrl, ("g_i", "source_snr"), drift)
    t0, t_x = _fit_times(ctrl, ("g_i", "source_snr"), repeat, drift)
    ds_c0, _ = _fit(ctrl, ("g_i",), drift)
    ds_p, _ = _fit(chrom)
    ds_c, _ = _fit(chrom, ("g_i",), drift)
    ds_bp, _ = _fit(bf)
    ds_bf, _ = _fit(bf, ("source_snr",), drift)

    def slope(d):
        return np.polyfit(colour, d, 1)[0]

    def part(a, b):
        return np.sqrt(max(np.mean(a**2) - np.mean(b**2), 0.0))

    return {
        "slope_pos": slope(ds_p), "slope_col": slope(ds_c),
        "slope_pos_paired": slope(ds_p - ds0), "slope_col_paired": slope(ds_c - ds0),
        "colour_rms_pos": part(ds_p, ds0), "colour_rms_col": part(ds_c, ds_c0),
        "colour_rms_pos_paired": np.sqrt(np.mean((ds_p - ds0) ** 2)),
        "colour_rms_col_paired": np.sqrt(np.mean((ds_c - ds_c0) ** 2)),
        "bf_pos": ds_bp.mean(), "bf_flux": ds_bf.mean(),
        "bf_pos_paired": (ds_bp - ds0).mean(), "bf_flux_paired": (ds_bf - ds0).mean(),
        "e_rms_ratio": np.sqrt(de_x.mean() / de0.mean()), "time_ratio": t_x / t0,
        "t_pos": t0,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-sims", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0,
                        help="random_state of the first simulation [0]")
    parser.add_argument("--n-stars", type=int, default=600)
    parser.add_argument("--n-galaxies", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--extra-drifts", default="linear",
                        help="comma-separated trends in the extra dimensions to measure "
                        "(linear, quadratic)")
    args = parser.parse_args()
    for drift in args.extra_drifts.split(","):
        print(f"\n=== extra_drift={drift!r} ===", flush=True)
        report(args, drift)


def report(args, drift):
    rows = []
    warnings.simplefilter("ignore")
    with threadpool_limits(limits=1, user_api="blas"):
        for seed in range(args.first_seed, args.first_seed + args.n_sims):
            r = one_simulation(seed, args.n_stars, args.n_galaxies, args.repeat, drift)
            rows.append(r)
            print(f"sim {seed}: size slope vs g-i pos {r['slope_pos']:+.2e} colour "
                  f"{r['slope_col']:+.2e} (paired {r['slope_pos_paired']:+.2e} / "
                  f"{r['slope_col_paired']:+.2e}); colour rms pos {r['colour_rms_pos']:.2e} "
                  f"colour {r['colour_rms_col']:.2e}; BF bias pos {r['bf_pos']:+.2e} flux "
                  f"{r['bf_flux']:+.2e} (paired {r['bf_pos_paired']:+.2e} / "
                  f"{r['bf_flux_paired']:+.2e}); e rms ratio {r['e_rms_ratio']:.4f}; fit "
                  f"time ratio {r['time_ratio']:.2f} ({r['t_pos']:.2f} s)", flush=True)
    m = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    n = len(rows)
    print(f"\n{n} simulations, {args.n_stars} stars, {args.n_galaxies} galaxies")
    print(f"colour: size-residual slope vs galaxies' g-i, mean over simulations: position-only "
          f"{m['slope_pos'].mean():+.3e}, colour {m['slope_col'].mean():+.3e}: ratio "
          f"{abs(m['slope_col'].mean() / m['slope_pos'].mean()):.3f} (target <= 0.10)")
    print(f"        paired: {m['slope_pos_paired'].mean():+.3e} / "
          f"{m['slope_col_paired'].mean():+.3e}: ratio "
          f"{abs(m['slope_col_paired'].mean() / m['slope_pos_paired'].mean()):.3f}")
    print(f"        colour part of the size rms (quadrature): position-only "
          f"{np.sqrt(np.mean(m['colour_rms_pos'] ** 2)):.3e}, colour "
          f"{np.sqrt(np.mean(m['colour_rms_col'] ** 2)):.3e}: ratio "
          f"{np.sqrt(np.mean(m['colour_rms_col'] ** 2) / np.mean(m['colour_rms_pos'] ** 2)):.3f}"
          " (target <= 0.5)")
    pos_rms = np.sqrt(np.mean(m["colour_rms_pos_paired"] ** 2))
    col_rms = np.sqrt(np.mean(m["colour_rms_col_paired"] ** 2))
    print(f"        paired (rms of the difference from the same model on the control): "
          f"position-only {pos_rms:.3e}, colour {col_rms:.3e}: ratio {col_rms / pos_rms:.3f}")
    print(f"brighter-fatter: mean size bias at the (faint) galaxies: position-only "
          f"{m['bf_pos'].mean():+.3e}, flux {m['bf_flux'].mean():+.3e} (target |.| <= 1e-3; "
          f"worst simulation {m['bf_flux'][np.argmax(np.abs(m['bf_flux']))]:+.3e}); paired "
          f"{m['bf_pos_paired'].mean():+.3e} / {m['bf_flux_paired'].mean():+.3e}")
    print(f"no dependence: e rms ratio (extra columns / position-only, paired) median "
          f"{np.median(m['e_rms_ratio']):.4f}, mean {m['e_rms_ratio'].mean():.4f}, worst "
          f"{m['e_rms_ratio'].max():.4f} (target <= 1.02)")
    print(f"fit time ratio: median {np.median(m['time_ratio']):.2f}, worst "
          f"{m['time_ratio'].max():.2f} (target <= 1.5; position-only fit median "
          f"{np.median(m['t_pos']):.2f} s)")


if __name__ == "__main__":
    main()
