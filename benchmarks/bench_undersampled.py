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
    (:func:`sklearn_psf.io.select_stars` with fit's defaults): the stars PIFF is given."""
    from sklearn_psf.io import select_stars
    from sklearn_psf.validation import read_exposure

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
    args = parser.parse_args(argv)
    from astropy.io import fits

    from sklearn_psf.io import run_psfex, run_sextractor
    from sklearn_psf.model import load_model
    from sklearn_psf.simulate import render_galsim_ccd
    import galsim
    import galsim.des  # noqa: F401  (not imported by galsim itself)

    n, side, scale = args.size, 25, FIELDS[args.field][0]
    psf = _psf_factory(n, args.field)
    work = Path(tempfile.mkdtemp(prefix="bench_undersampled_"))
    t = time.time()
    ccd = render_galsim_ccd(shape=(n, n), pixel_scale=scale, n_stars=args.n_stars,
                            n_galaxies=args.n_stars, psf=psf, snr_range=(30.0, 1000.0),
                            random_state=args.seed)
    image = ccd.write(work, overwrite=True)
    cat = run_sextractor(image, work / "cat.ldac", weight_path=ccd.weight_path(image),
                         vignet=(side, side), overwrite=True)
    print(f"CCD {n}x{n} at {scale}\"/px, {len(ccd.stars)} stars: rendered and catalogued in "
          f"{time.time() - t:.0f} s ({work})")
    rng = np.random.default_rng(args.seed + 1)
    P = rng.uniform(0, n - 1, (args.n_truth, 2))
    truth = _truth(psf, P, side, scale)
    rows = []

    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    _, lam, diam, _, _ = FIELDS[args.field]
    cutoff = diam / (lam * 1e-9) * scale / 206264.806  # D / lambda, cycles per pixel
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
        name = f"PSFEx PSF_SAMPLING {'auto' if not sampling else sampling} ({actual:.2f})"
        rows.append((name, *_scores(pred, truth), used, cpu))
    if args.no_piff:
        print("PIFF: skipped (--no-piff)")
    else:
        got = _run_piff(image, ccd.weight_path(image), _selected_stars(cat, side),
                        work / "piff", side, scale, ccd.header["SKYLEVEL"], ccd.header["GAIN"],
                        P, env)
        if isinstance(got, str):
            print(f"PIFF: skipped ({got})")
        else:
            rows.append(("PIFF PixelGrid 0.5 px + BasisPolynomial 2", *_scores(got[0], truth),
                         *got[1:]))
    clean, selected = _clean_stars(ccd.stars, cat, _selected_stars(cat, side))
    print(f"\naccuracy at the truth ({args.n_truth} positions, fixed-weight moments sigma "
          "1.5 px, native sampling, phase 0 for every model)")
    print(f"{'model':<42} {'e rms':>8} {'size rms':>9} {'size bias':>10} {'stars':>6} "
          f"{'CPU s':>6}")
    for name, e, s, b, used, c in rows:
        print(f"{name:<42} {e:8.4f} {s:9.4f} {b:+10.4f} {used:6d} {c:6.1f}")
    e_best = min(rows[len(ours):], key=lambda r: r[1])
    s_best = min(rows[len(ours):], key=lambda r: r[2])
    print()
    for row in rows[:len(ours)]:
        print(f"{row[0]} / best peer: e rms {row[1] / e_best[1]:.2f}x ({e_best[0]}), size rms "
              f"{row[2] / s_best[2]:.2f}x ({s_best[0]})")
    print(f"clean stars (unsaturated true stars catalogued within 1 px, FLAGS 0): {clean}; "
          f"selected by fit: {selected} ({selected / clean:.1%}); fitted stars kept: "
          f"{kept} ({rows[0][0]})")
    print("our verdict lines:\n  " + "\n  ".join(report))


def _clean_stars(truth, cat, selected):
    """Clean stars (unsaturated true stars with a catalogue source within 1 px and FLAGS 0)
    and how many of them fit selects."""
    from scipy.spatial import cKDTree

    from sklearn_psf.validation import read_exposure

    table = read_exposure(catalog=cat).catalog
    xy = np.column_stack([table["x"], table["y"]])
    flags = np.asarray(table["flags"]) if "flags" in table.colnames else np.zeros(len(xy))
    true = np.column_stack([truth["x"], truth["y"]])[~np.asarray(truth["saturated"])]
    dist, idx = cKDTree(xy).query(true)
    found = (dist < 1.0) & (flags[np.minimum(idx, len(xy) - 1)] == 0)
    dist, _ = cKDTree(selected).query(xy[idx[found]])
    return int(found.sum()), int((dist < 1e-6).sum())


if __name__ == "__main__":
    main()
