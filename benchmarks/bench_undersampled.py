"""Undersampled stars: `sklearn-psf fit` against PSFEx and PIFF on a Euclid-VIS-like (or
Roman-like) GalSim CCD.

The CCD (:func:`sklearn_psf.simulate.render_galsim_ccd`): 2048 x 2048 pixels of 0.1",
``galsim.OpticalPSF`` at 700 nm through 1.2 m (obscuration 0.3) with defocus, astigmatism,
coma and trefoil varying smoothly over the chip (low-order polynomials of the position, the
``OpticalPSF`` made at each star's and each truth position), 0.025" jitter:
pixel-convolved FWHM ~1.5 px; stars at random sub-pixel positions, S/N 30-1000, galaxies,
saturated stars. ``--field roman``: 0.11" pixels, 1.06 um through 2.4 m (obscuration 0.31),
0.012" jitter, FWHM ~1.3 px. Source Extractor catalogues it (25 x 25 VIGNETs); each tool
fits the same catalogue: ``sklearn-psf fit --stars cat.ldac --no-plots`` (its defaults: the
super-resolved basis for these stars), PSFEx 3.21 with ``PSF_SAMPLING`` automatic and 0.5
(degree 2, ``SAMPLE_FWHMRANGE`` from 0.5 px) and PIFF's ``piffify`` on the image and the
stars fit selects (PixelGrid at half the pixel scale, 25 samples, on 13-pixel stamps: the
grid's extent; BasisPolynomial of order 2, Chisq outliers; skipped, with the reason, when PIFF
is not installed or with ``--no-piff``).

Accuracy at the truth: random positions, each model's stamp and the true PSF at native
sampling, phase 0: every profile (the truth, PSFEx's and PIFF's; ours by its own convention,
the same) drawn with its adaptive centroid, measured on the pixel-convolved profile sampled
every half pixel, on the centre pixel; measured with fixed-weight moments
(:func:`sklearn_psf.measure.fixed_moments`, sigma 1.5 px): e rms (sqrt <de1^2 + de2^2>),
size rms and size bias (relative, of det(M)^(1/4)). CPU: user + system time of each command
(child processes), one thread each. Clean stars: unsaturated true stars with a catalogue
source within 1 px and FLAGS 0.

``--optics-band`` also runs ``sklearn-psf fit --band-limit`` with the optics' cutoff
``D / lambda`` in cycles per pixel (0.83 Euclid-like, 1.21 Roman-like).

``--noise-draws K`` runs every tool again on K new noise realisations of the same CCD (same
sources, dead columns and truth: ``render_galsim_ccd(noise_seed=1..K)``), each catalogued
afresh, and prints each figure's mean and standard deviation over the K + 1 runs: how much of
a figure measured on one CCD is that CCD's noise.

``--bound`` prints the Cramer-Rao bound of the mean PSF's size from the CCD's clean stars
for a model on a fine grid (the mean fine image free within a band, each star's flux and
offset free, the noise of every pixel its sky plus signal / gain): the smallest standard
deviation that the size bias measured on one CCD can have, for a fit that is unbiased on
average. It is evaluated at the band the default fit found, the optics' cutoff and the whole
grid.

Run: ``python benchmarks/bench_undersampled.py [--seed 3] [--n-stars 600] [--field roman]``
(~5 min with PIFF on 2 shared cores).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


#: The fields: pixel scale ("/px), wavelength (nm), aperture (m), obscuration, jitter (").
FIELDS = {"euclid": (0.1, 700.0, 1.2, 0.3, 0.025),   # VIS: pixel-convolved FWHM ~1.5 px
          "roman": (0.11, 1060.0, 2.4, 0.31, 0.012)}  # WFI at 1.06 um: FWHM ~1.3 px


def _psf_factory(n, field="euclid"):
    """The field's PSF at pixel (x, y): ``galsim.OpticalPSF`` with Zernikes (waves) that are
    low-order polynomials of the chip position, evaluated at each position (the PSF varies
    smoothly; one pupil, ``galsim.Aperture``, shared by all: ~10 ms a profile), convolved with
    a Gaussian jitter."""
    import galsim

    _, lam, diam, obscuration, jitter = FIELDS[field]
    aper = galsim.Aperture(diam=diam, lam=lam, obscuration=obscuration)
    blur = galsim.Gaussian(sigma=jitter)

    def psf(x, y):
        u, v = x / n - 0.5, y / n - 0.5
        ab = [0, 0, 0, 0, 0.03 + 0.04 * (u * u + v * v), 0.04 * u, 0.04 * v, 0.03 * u,
              -0.03 * v, 0.01, 0, 0.02]
        return galsim.Convolve(galsim.OpticalPSF(lam=lam, diam=diam, aberrations=ab, aper=aper,
                                                 scale_unit=galsim.arcsec), blur)
    return psf


def _phase_zero(prof, side, scale):
    """``prof`` (a GalSim profile that includes the pixel response, in units of ``scale``
    per pixel) drawn on a ``side`` x ``side`` stamp at phase 0: its adaptive centroid,
    measured on the profile sampled every half pixel, on the centre pixel (the package's
    centre convention, applied alike to the truth and to the peers' profiles)."""
    import galsim

    fine = prof.drawImage(nx=51, ny=51, scale=scale / 2, method="no_pixel")
    c = (galsim.hsm.FindAdaptiveMom(fine).moments_centroid - fine.true_center) / 2
    return prof.drawImage(nx=side, ny=side, scale=scale, offset=(-c.x, -c.y),
                          method="no_pixel").array


def _truth(psf, P, side, scale):
    import galsim

    return np.array([_phase_zero(galsim.Convolve(psf(x, y), galsim.Pixel(scale)), side, scale)
                     for x, y in P])


def _selected_stars(cat, side):
    """0-based positions of the catalogue's stars as ``sklearn-psf fit`` selects them
    (:func:`sklearn_psf.exposure.select_stars` with fit's defaults): the stars PIFF is given."""
    from sklearn_psf.exposure import select_stars
    from sklearn_psf.exposure import read_exposure

    inputs = read_exposure(catalog=cat)
    table = inputs.catalog
    keep, _ = select_stars(table, saturation=inputs.saturation, stamp_size=side, min_stars=0)
    return np.column_stack([table["x"], table["y"]])[keep]


def _run_piff(image, weight, stars, folder, side, scale, sky, gain, P, env):
    """PIFF's ``piffify`` on the image and a catalogue of ``stars`` (0-based): PixelGrid of
    25 samples at half the pixel scale, on stamps of 13 pixels (the grid's extent, 12.5
    pixels: on larger stamps the stars' wings beyond the grid are left unmodelled, PIFF's
    outlier test drops the bright stars and its e rms at the truth triples),
    BasisPolynomial of order 2, Chisq outliers; its profiles at ``P`` drawn at phase 0
    (:func:`_phase_zero`) on ``side`` x ``side`` stamps. Returns (stamps, stars used, CPU s)
    or a reason."""
    try:
        import piff
    except ImportError:
        return "piff is not installed (pip install piff)"
    import galsim
    import yaml
    from astropy.table import Table

    folder.mkdir(exist_ok=True)
    Table({"x": stars[:, 0] + 1.0, "y": stars[:, 1] + 1.0}).write(folder / "stars.fits",
                                                                    overwrite=True)
    config = {
        "input": {"image_file_name": str(image), "weight_file_name": str(weight),
                  "weight_hdu": 0, "cat_file_name": str(folder / "stars.fits"),
                  "x_col": "x", "y_col": "y", "sky": float(sky), "gain": float(gain),
                  "stamp_size": 13},  # the PixelGrid's extent
        "select": {"reserve_frac": 0.0},
        "psf": {"type": "Simple",
                "model": {"type": "PixelGrid", "scale": scale / 2, "size": 25},  # 1.25"
                "interp": {"type": "BasisPolynomial", "order": 2},
                "outliers": {"type": "Chisq", "nsigma": 4, "max_remove": 0.05}},
        "output": {"file_name": str(folder / "piff.fits")},
        "verbose": 1,
    }
    with open(folder / "piff.yaml", "w") as fh:
        yaml.safe_dump(config, fh)
    cpu = _cpu()
    out = subprocess.run(["piffify", str(folder / "piff.yaml")], capture_output=True,
                         text=True, env=env, cwd=folder)
    cpu = _cpu() - cpu
    if out.returncode:
        return f"piffify failed: {out.stderr.strip().splitlines()[-1:]}"
    psf = piff.read(str(folder / "piff.fits"))
    used = sum(1 for s in psf.stars if not s.is_flagged and not s.is_reserve)
    stamps = np.empty((len(P), side, side))
    for k, (x, y) in enumerate(P):
        pos = galsim.PositionD(x + 1.0, y + 1.0)  # the FITS image's 1-based pixels
        prof = psf.get_profile(pos.x, pos.y)[0]
        local = psf.wcs[0].local(image_pos=pos)
        stamps[k] = _phase_zero(local.toImage(prof), side, 1.0)
    return stamps, used, cpu


def _scores(stamps, truth):
    from sklearn_psf.measure import fixed_moments

    side = truth.shape[-1]
    mt = fixed_moments(truth, 1.5)
    mp = fixed_moments(np.asarray(stamps).reshape(-1, side, side), 1.5)
    ok = (np.asarray(mt["flag"]) == 0) & (np.asarray(mp["flag"]) == 0)
    de = np.hypot(np.asarray(mp["e1"]) - mt["e1"], np.asarray(mp["e2"]) - mt["e2"])[ok]
    ds = ((np.asarray(mp["sigma"]) - mt["sigma"]) / np.asarray(mt["sigma"]))[ok]
    return float(np.sqrt(np.mean(de**2))), float(np.sqrt(np.mean(ds**2))), float(ds.mean())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--n-stars", type=int, default=600)
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--n-truth", type=int, default=2000)
    parser.add_argument("--field", choices=sorted(FIELDS), default="euclid",
                        help="euclid (0.1\"/px, 700 nm, 1.2 m) or roman (0.11\"/px, 1.06 um, "
                             "2.4 m)")
    parser.add_argument("--no-piff", action="store_true", help="skip PIFF (slow)")
    parser.add_argument("--optics-band", action="store_true",
                        help="also run sklearn-psf fit with --band-limit the optics' cutoff "
                             "D/lambda (0.83 cycles per pixel Euclid-like, 1.21 Roman-like)")
    parser.add_argument("--noise-draws", type=int, default=0, metavar="K",
                        help="run every tool again on K new noise realisations of the same "
                             "CCD (same sources, render_galsim_ccd's noise_seed 1..K) and print "
                             "each figure's mean and standard deviation over the K + 1 runs")
    parser.add_argument("--bound", action="store_true",
                        help="also print the Cramer-Rao bound of the mean PSF's size from the "
                             "CCD's clean stars, for a fine-grid model held to the band fit "
                             "found, the optics' cutoff and the whole grid")
    args = parser.parse_args(argv)
    n, side, scale = args.size, 25, FIELDS[args.field][0]
    psf = _psf_factory(n, args.field)
    rng = np.random.default_rng(args.seed + 1)
    P = rng.uniform(0, n - 1, (args.n_truth, 2))
    truth = _truth(psf, P, side, scale)
    rows, n_ours, notes, ccd, cat, found = _run(args, psf, P, truth, None)
    print(f"\naccuracy at the truth ({args.n_truth} positions, fixed-weight moments sigma "
          "1.5 px, native sampling, phase 0 for every model)")
    print(f"{'model':<42} {'e rms':>8} {'size rms':>9} {'size bias':>10} {'stars':>6} "
          f"{'CPU s':>6}")
    for name, e, s, b, used, c in rows:
        print(f"{name:<42} {e:8.4f} {s:9.4f} {b:+10.4f} {used:6d} {c:6.1f}")
    print()
    _ratios(rows, n_ours)
    print(notes)
    if args.bound:
        clean, _ = _clean(ccd.stars, cat)
        bands = [found, _cutoff(args.field), None]
        print(f"\nCramer-Rao bound of the mean PSF's relative size, fixed-weight at phase 0, "
              f"from the {int(clean.sum())} clean stars (a fine-grid model: the mean fine image "
              "free within the band, each star's flux and offset free; noise sky + signal / "
              "gain; linearised at the fit of the stars drawn without noise, whose size bias "
              "at the truth is given): the smallest standard deviation of one CCD's size bias "
              "for a fit unbiased at that band")
        names = ["found by fit", "optics' D / lambda", "whole grid"]
        for name, band, (sd, bias) in zip(names, bands,
                                          _size_bound(ccd, clean, side, bands, P, truth)):
            where = "" if band is None else f" ({band:.2f} cycles per pixel)"
            print(f"  {name}{where}: standard deviation {sd:.1e}; noiseless fit's size bias "
                  f"{bias:+.4f}")
    if not args.noise_draws:
        return
    runs = [rows]
    for k in range(1, args.noise_draws + 1):
        runs.append(_run(args, psf, P, truth, k)[0])
        print(f"noise draw {k}: " + "; ".join(f"{r[0]} {r[1]:.4f} / {r[2]:.4f} / {r[3]:+.4f}"
                                              for r in runs[-1]), flush=True)
    figures = np.array([[r[1:4] for r in run] for run in runs])  # (run, model, 3)
    mean, sd = figures.mean(axis=0), figures.std(axis=0, ddof=1)
    print(f"\nover the CCD's own noise and {args.noise_draws} new noise draws (same sources): "
          "mean +- standard deviation of e rms / size rms / size bias; share of runs with "
          "|size bias| < 1e-3")
    for i, row in enumerate(rows):
        within = np.mean(np.abs(figures[:, i, 2]) < 1e-3)
        print(f"{row[0]:<42} " + "  ".join(f"{m:+.4f} +- {d:.4f}" if j == 2 else
                                         f"{m:.4f} +- {d:.4f}"
                                         for j, (m, d) in enumerate(zip(mean[i], sd[i])))
              + f"  {within:.0%}")
    _ratios([(row[0], *mean[i]) for i, row in enumerate(rows)], n_ours, "mean ")


def _cutoff(field):
    """The optics' diffraction cutoff D / lambda in cycles per pixel."""
    scale, lam, diam, _, _ = FIELDS[field]
    return diam / (lam * 1e-9) * scale / 206264.806


def _ratios(rows, n_ours, what=""):
    """Print our rows' e rms and size rms over the best peer's (rows: name, e, size, ...)."""
    e_best = min(rows[n_ours:], key=lambda r: r[1])
    s_best = min(rows[n_ours:], key=lambda r: r[2])
    for row in rows[:n_ours]:
        print(f"{row[0]} / best peer: {what}e rms {row[1] / e_best[1]:.2f}x ({e_best[0]}), "
              f"{what}size rms {row[2] / s_best[2]:.2f}x ({s_best[0]})")


def _run(args, psf, P, truth, noise_seed):
    """Render the CCD (``noise_seed``: see :func:`render_galsim_ccd`), catalogue it and run
    every tool on it: rows (name, e rms, size rms, size bias, stars, CPU s), how many rows are
    ours (the first), the notes printed under the table (star counts, our verdict), the CCD,
    its catalogue and the band (cycles per pixel) our default fit found."""
    from astropy.io import fits

    from sklearn_psf.io import run_psfex, run_sextractor
    from sklearn_psf.model import load_model
    from sklearn_psf.simulate import render_galsim_ccd
    import galsim
    import galsim.des  # noqa: F401  (not imported by galsim itself)

    n, side, scale = args.size, 25, FIELDS[args.field][0]
    work = Path(tempfile.mkdtemp(prefix="bench_undersampled_"))
    t = time.time()
    ccd = render_galsim_ccd(shape=(n, n), pixel_scale=scale, n_stars=args.n_stars,
                            n_galaxies=args.n_stars, psf=psf, snr_range=(30.0, 1000.0),
                            random_state=args.seed, noise_seed=noise_seed)
    image = ccd.write(work, overwrite=True)
    cat = run_sextractor(image, work / "cat.ldac", weight_path=ccd.weight_path(image),
                         vignet=(side, side), overwrite=True)
    if noise_seed is None:
        print(f"CCD {n}x{n} at {scale}\"/px, {len(ccd.stars)} stars: rendered and catalogued "
              f"in {time.time() - t:.0f} s ({work})")
    rows = []
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    cutoff = _cutoff(args.field)
    ours = [("sklearn-psf fit", [])]
    if args.optics_band:
        ours.append((f"sklearn-psf fit --band-limit {cutoff:.2f}",
                     ["--band-limit", f"{cutoff:.4f}"]))
    for name, extra in ours:
        cpu = _cpu()
        out = subprocess.run([sys.executable, "-m", "sklearn_psf", "fit", "--stars", str(cat),
                              "-o", str(work / "ours.fits"), "--no-plots", "--overwrite",
                              *extra], capture_output=True, text=True, env=env, check=True)
        cpu = _cpu() - cpu
        model = load_model(work / "ours.fits")
        used, n_fitted = int(model.inlier_mask_.sum()), len(model.inlier_mask_)
        if not extra:
            report = [line for line in out.stdout.splitlines() if "reserved stars" in line]
            kept = f"{used} of {n_fitted}"
            found = float(model.basis_.band_limit_)
        rows.append((name, *_scores(model.predict(P), truth), used, cpu))
    for sampling in (0.0, 0.5):
        cpu = _cpu()
        folder = work / f"psfex_{sampling}"
        # SAMPLE_FWHMRANGE from 0.5 px: PSFEx's default (2-10 px) drops undersampled stars
        path = run_psfex(cat, folder, config={"PSF_SAMPLING": sampling, "PSF_SIZE": "41,41",
                                              "PSFVAR_DEGREES": 2, "NTHREADS": 1,
                                              "SAMPLE_FWHMRANGE": "0.5,10.0"},
                         overwrite=True)
        cpu = _cpu() - cpu
        with fits.open(path) as hdul:
            head = hdul[1].header
            used = int(head.get("ACCEPTED", -1))
            actual = float(head.get("PSF_SAMP", sampling))
        psfex = galsim.des.DES_PSFEx(str(path))  # profiles in pixels, 1-based positions
        pred = np.array([_phase_zero(psfex.getPSF(galsim.PositionD(x + 1.0, y + 1.0)), side,
                                     1.0) for x, y in P])
        name = f"PSFEx PSF_SAMPLING {'auto' if not sampling else sampling}"
        if noise_seed is None:
            name += f" ({actual:.2f})"
        rows.append((name, *_scores(pred, truth), used, cpu))
    if args.no_piff:
        if noise_seed is None:
            print("PIFF: skipped (--no-piff)")
    else:
        got = _run_piff(image, ccd.weight_path(image), _selected_stars(cat, side),
                        work / "piff", side, scale, ccd.header["SKYLEVEL"], ccd.header["GAIN"],
                        P, env)
        if isinstance(got, str):
            if noise_seed is None:
                print(f"PIFF: skipped ({got})")
        else:
            rows.append(("PIFF PixelGrid 0.5 px + BasisPolynomial 2", *_scores(got[0], truth),
                         *got[1:]))
    clean, selected = _clean_stars(ccd.stars, cat, _selected_stars(cat, side))
    notes = (f"clean stars (unsaturated true stars catalogued within 1 px, FLAGS 0): {clean}; "
             f"selected by fit: {selected} ({selected / clean:.1%}); fitted stars kept: "
             f"{kept} ({rows[0][0]})\nour verdict lines:\n  " + "\n  ".join(report))
    return rows, len(ours), notes, ccd, cat, found


def _clean(truth, cat):
    """Clean stars (unsaturated true stars with a catalogue source within 1 px and FLAGS 0):
    a mask over ``truth``'s rows, and each one's catalogue position."""
    from scipy.spatial import cKDTree

    from sklearn_psf.exposure import read_exposure

    table = read_exposure(catalog=cat).catalog
    xy = np.column_stack([table["x"], table["y"]])
    flags = np.asarray(table["flags"]) if "flags" in table.colnames else np.zeros(len(xy))
    dist, idx = cKDTree(xy).query(np.column_stack([truth["x"], truth["y"]]))
    found = (dist < 1.0) & (flags[np.minimum(idx, len(xy) - 1)] == 0)
    return found & ~np.asarray(truth["saturated"]), xy[np.minimum(idx, len(xy) - 1)]


def _clean_stars(truth, cat, selected):
    """How many clean stars (see :func:`_clean`) there are and how many of them fit selects."""
    from scipy.spatial import cKDTree

    clean, xy = _clean(truth, cat)
    dist, _ = cKDTree(selected).query(xy[clean])
    return int(clean.sum()), int((dist < 1e-6).sum())


def _size_bound(ccd, clean, side, bands, P, truth):
    """Cramer-Rao bound of the mean PSF's relative size (fixed-weight, phase 0) from the
    clean stars, for a fine-grid model of the PSF: the mean fine image free within each band
    (cycles per pixel; None: the whole square grid), each star's flux and offset free, every
    pixel's noise its sky plus signal / gain. Linearised at ``SuperResolvedPCA``'s fit on the
    stars drawn without noise at their true positions and fluxes (the truth known); uses the
    basis's own drawing methods. Returns, per band, (standard deviation of ln size, the
    noiseless fit's size bias at the truth)."""
    import galsim

    from sklearn_psf.measure import fixed_moments
    from sklearn_psf.model import PSFModel
    from sklearn_psf.preprocessing import SuperResolvedPCA
    from sklearn_psf.preprocessing._normalize import phase_ramp

    stars = ccd.stars[clean]
    sky, gain = ccd.header["SKYLEVEL"] / ccd.header["GAIN"], ccd.header["GAIN"]
    X = np.column_stack([stars["x"], stars["y"]])
    c = np.round(X)
    stamps = np.array([galsim.Convolve(ccd.psf(x, y), galsim.Pixel(ccd.pixel_scale))
                       .drawImage(nx=side, ny=side, scale=ccd.pixel_scale, method="no_pixel",
                                  offset=(x - cx, y - cy)).array.ravel() * flux
                       for (x, y), (cx, cy), flux in zip(X, c, stars["flux"])])
    u = 1.0 / (sky + np.maximum(stamps, 0.0) / gain)
    out = []
    for band in bands:
        model = PSFModel(basis=SuperResolvedPCA(band_limit=band), outliers=None).fit(
            X, stamps, weights=u)
        b = model.basis_
        fit = b.project(stamps, u)
        f, size, o = b._grid(side)
        mask = b._band()
        flux = np.asarray(fit.flux)[:, None]
        offsets = np.asarray(fit.offsets)
        mean = b.fine_mean_
        # each star's flux and offset, profiled out of its pixels (in u)
        drawn, slope = b._draw(mean[None], offsets, np.ones_like(flux), gradient=True)
        J = np.concatenate([drawn[:, None], slope(flux)], axis=1)
        Ju = J * u[:, None, :]
        JuJ = np.linalg.pinv(Ju @ J.transpose(0, 2, 1), hermitian=True)
        normal = b._normal(u, flux, offsets, mask, lambda x: x, (Ju, JuJ))

        def fisher(x):
            return normal(x.reshape(1, -1)).ravel()

        # the size at phase 0 after recentring on the fine image's own Gaussian-weighted
        # centroid: unchanged by a shift of the mean that every star's offset takes up
        yy, xx = (np.mgrid[0:size, 0:size] - (size - 1) / 2) / f

        def sizes(images):
            img = images.reshape(-1, size, size)
            cen = np.zeros((len(img), 2))
            for _ in range(4):
                w = img * np.exp(-((xx - cen[:, :1, None]) ** 2 + (yy - cen[:, 1:, None]) ** 2)
                                 / (2 * 1.5**2))
                cen = np.stack([(w * xx).sum((1, 2)), (w * yy).sum((1, 2))], 1) \
                    / w.sum((1, 2))[:, None]
            ramp = phase_ramp(size, -f * cen[:, 0], -f * cen[:, 1])
            drawn = np.fft.irfft2(np.fft.rfft2(img) * ramp * mask, s=(size, size))
            return fixed_moments(f * f * drawn[:, o:o + f * side:f, o:o + f * side:f],
                                 1.5)["sigma"]

        h = 1e-5 * np.abs(mean).max()
        grad = np.empty(mean.size)
        for lo in range(0, mean.size, 512):
            idx = np.arange(lo, min(lo + 512, mean.size))
            step = np.zeros((len(idx), mean.size))
            step[np.arange(len(idx)), idx] = h
            grad[idx] = (sizes(mean + step) - sizes(mean - step)) / (2 * h)
        g = np.fft.irfft2(np.fft.rfft2(grad.reshape(size, size)) * mask,
                          s=(size, size)).ravel() / sizes(mean[None])[0]
        # conjugate gradients on fisher(z) = g, the mean's shift and scale (to which the size
        # is blind, g is orthogonal to them) held by a penalty
        ky, kx = np.fft.fftfreq(size)[:, None], np.fft.rfftfreq(size)[None, :]
        fmean = np.fft.rfft2(mean.reshape(size, size))
        gauge = np.stack([np.fft.irfft2(fmean * k * mask, s=(size, size)).ravel()
                          for k in (2j * np.pi * kx, 2j * np.pi * ky)] + [mean])
        gauge /= np.linalg.norm(gauge, axis=1)[:, None]
        probe = np.random.default_rng(0).standard_normal(mean.size)
        lam = float(probe @ fisher(probe)) / float(probe @ probe)
        z, r = np.zeros_like(g), g.copy()
        d, rr = r.copy(), float(r @ r)
        for _ in range(2000):
            q = fisher(d) + lam * gauge.T @ (gauge @ d)
            alpha = rr / float(d @ q)
            z += alpha * d
            r -= alpha * q
            if float(r @ r) < 1e-16 * float(g @ g):
                break
            d, rr = r + float(r @ r) / rr * d, float(r @ r)
        out.append((float(np.sqrt(g @ z)), _scores(model.predict(P), truth)[2]))
    return out


if __name__ == "__main__":
    main()
