"""Running Source Extractor and PSFEx (external programs) with PSFEx's usual recipe.

Both programs are optional: :func:`find_program` says whether each is installed (e.g. for
skipping tests), and the runners raise :class:`ProgramNotFoundError` when it is not, or
:class:`ProgramError` (with the end of the program's standard error) when it fails.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["DEFAULT_SEXTRACTOR_CONFIG", "DEFAULT_SEXTRACTOR_PARAMS", "ProgramError",
           "ProgramNotFoundError", "find_program", "run_psfex", "run_sextractor",
           "write_sextractor_config"]

_EXECUTABLES = {"source-extractor": ("source-extractor", "sex"), "psfex": ("psfex",)}

#: Output columns of :func:`run_sextractor` by default: what PSFEx reads (``VIGNET``,
#: positions, aperture fluxes, ``FLUX_RADIUS``, ``ELONGATION``, ``FLAGS``, ``SNR_WIN``) and
#: what star selectors use. ``FLUX_APER``/``FLUXERR_APER`` get one value per
#: ``PHOT_APERTURES`` entry and ``FLUX_RADIUS`` one per ``PHOT_FLUXFRAC`` entry.
DEFAULT_SEXTRACTOR_PARAMS = (
    "NUMBER", "X_IMAGE", "Y_IMAGE", "XWIN_IMAGE", "YWIN_IMAGE", "FLUX_APER", "FLUXERR_APER",
    "FLUX_AUTO", "FLUXERR_AUTO", "MAG_AUTO", "MAGERR_AUTO", "FLUX_MAX", "FLUX_RADIUS",
    "SNR_WIN", "ELONGATION", "FLAGS", "CLASS_STAR",
)

#: Settings of :func:`run_sextractor` by default (any SExtractor setting can be overridden
#: with ``config``): PSFEx's ``prepsfex.sex`` (3 pixels above 4 sigma, the 3x3 "all-ground"
#: filter), several apertures of which the first (15 pixels, PSFEx's ``PHOTFLUX_KEY
#: FLUX_APER(1)``) is the reference, ``GAIN`` and ``SATURATE`` read from the image header.
DEFAULT_SEXTRACTOR_CONFIG = {
    "DETECT_MINAREA": 3, "DETECT_THRESH": 4.0, "ANALYSIS_THRESH": 4.0, "FILTER": "Y",
    "PHOT_APERTURES": "15,5,10,20,30", "PHOT_FLUXFRAC": 0.5, "SATUR_KEY": "SATURATE",
    "SATUR_LEVEL": 50000.0, "GAIN_KEY": "GAIN", "GAIN": 0.0, "SEEING_FWHM": 1.0,
    "BACK_SIZE": 64, "CHECKIMAGE_TYPE": "NONE", "WRITE_XML": "N", "VERBOSE_TYPE": "NORMAL",
}

# a 3x3 Gaussian of FWHM 2 pixels (SExtractor's "all-ground" detection filter)
_FILTER = "CONV NORM\n1 2 1\n2 4 2\n1 2 1\n"


class ProgramNotFoundError(FileNotFoundError):
    """An external program (Source Extractor, PSFEx) is not installed."""


class ProgramError(RuntimeError):
    """An external program failed; the message ends with its standard error's last lines."""


def find_program(name: str):
    """Path of an installed external program, or None.

    Parameters
    ----------
    name : {"source-extractor", "psfex"}
        Source Extractor is looked for as ``source-extractor`` (Debian's name) and ``sex``.

    Returns
    -------
    path : str or None

    Examples
    --------
    >>> from sklearn_psf.io import find_program
    >>> path = find_program("psfex")        # None where PSFEx is not installed
    >>> path is None or path.endswith("psfex")
    True
    """
    if name not in _EXECUTABLES:
        raise ValueError(f"name must be one of {sorted(_EXECUTABLES)}, got {name!r}.")
    for exe in _EXECUTABLES[name]:
        path = shutil.which(exe)
        if path:
            return path
    return None


def _require(name):
    path = find_program(name)
    if path is None:
        raise ProgramNotFoundError(
            f"{name} is not installed (looked for {', '.join(_EXECUTABLES[name])} on the PATH); "
            f"e.g. apt-get install {name}.")
    return path


def _value(v) -> str:
    if isinstance(v, bool):
        return "Y" if v else "N"
    if isinstance(v, (list, tuple)):
        return ",".join(_value(x) for x in v)
    return str(v)


def _run(cmd, cwd, what):
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, errors="replace")
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.strip().splitlines()[-12:])
        raise ProgramError(f"{what} failed (exit status {proc.returncode}): "
                           f"{' '.join(map(str, cmd))}\n{tail}")
    return proc


def _n_values(setting) -> int:
    return len([v for v in _value(setting).replace(" ", ",").split(",") if v])


def _nnw_file(exe):
    """SExtractor's star/galaxy network, in the program's share folder."""
    prefix = Path(os.path.realpath(exe)).parent.parent
    for sub in ("source-extractor", "sextractor", "sex"):
        path = prefix / "share" / sub / "default.nnw"
        if path.exists():
            return path
    return None


#: Columns of ``spread.param`` (:func:`write_sextractor_config`): Source Extractor's model
#: fitting with a ``.psf`` (``PSF_NAME``), for ``SPREAD_MODEL`` star/galaxy separation.
_SPREAD_PARAMS = ("NUMBER", "XWIN_IMAGE", "YWIN_IMAGE", "FLUX_AUTO", "FLUXERR_AUTO",
                  "MAG_AUTO", "FLAGS", "FLUX_RADIUS", "SPREAD_MODEL", "SPREADERR_MODEL")


def _settings_and_columns(params, config, vignet, exe):
    """The settings (:data:`DEFAULT_SEXTRACTOR_CONFIG` updated with ``config``) and output
    columns (vector columns sized to the apertures and flux fractions) of a run."""
    settings = dict(DEFAULT_SEXTRACTOR_CONFIG)
    settings.update({str(k).upper(): v for k, v in (config or {}).items()})
    n_aper = _n_values(settings["PHOT_APERTURES"])
    n_frac = _n_values(settings["PHOT_FLUXFRAC"])
    columns = list(DEFAULT_SEXTRACTOR_PARAMS if params is None else params)
    if params is None and vignet is not None:
        columns.insert(0, f"VIGNET({int(vignet[0])},{int(vignet[1])})")
    sized = {"FLUX_APER": n_aper, "FLUXERR_APER": n_aper, "MAG_APER": n_aper,
             "MAGERR_APER": n_aper, "FLUX_RADIUS": n_frac}
    columns = [f"{c}({sized[c]})" if c in sized else c for c in (s.strip() for s in columns)]
    if "CLASS_STAR" in {c.split("(")[0] for c in columns} and "STARNNW_NAME" not in settings:
        nnw = None if exe is None else _nnw_file(exe)
        if nnw is None and exe is not None:
            raise ProgramError("CLASS_STAR needs SExtractor's default.nnw, not found beside "
                               f"{exe}: pass config={{'STARNNW_NAME': path}}.")
        settings["STARNNW_NAME"] = str(nnw) if nnw is not None else "default.nnw"
    return settings, columns


def _write_files(folder, name, settings, columns, skip=()):
    """``name.param``, ``name.conv`` and ``name.sex`` (every setting but ``skip``) in
    ``folder``; their paths."""
    folder = Path(folder)
    paths = {kind: folder / f"{name}.{kind}" for kind in ("sex", "param", "conv")}
    paths["param"].write_text("\n".join(columns) + "\n")
    paths["conv"].write_text(_FILTER)
    settings = {**settings, "FILTER_NAME": settings.get("FILTER_NAME", paths["conv"].name),
                "PARAMETERS_NAME": paths["param"].name}
    paths["sex"].write_text("".join(f"{k} {_value(v)}\n" for k, v in settings.items()
                                    if k not in skip))
    return paths


def write_sextractor_config(folder=".", *, config=None, vignet=(35, 35),
                            overwrite: bool = False) -> dict:
    """Write the Source Extractor configuration of :func:`run_sextractor` (PSFEx's usual
    recipe) to ``folder``, for the command line.

    ``prepsfex.sex`` (:data:`DEFAULT_SEXTRACTOR_CONFIG` with ``config``, ``CATALOG_TYPE
    FITS_LDAC``, the star/galaxy network ``default.nnw`` of the installed Source Extractor),
    ``prepsfex.param`` (:data:`DEFAULT_SEXTRACTOR_PARAMS` with ``VIGNET``: the catalogue
    PSFEx and ``sklearn-psf fit`` read), ``prepsfex.conv`` (the detection filter) and
    ``spread.param`` (the columns of Source Extractor's model fitting with a ``.psf``,
    ``SPREAD_MODEL`` and ``SPREADERR_MODEL``, with ``-PARAMETERS_NAME spread.param
    -PSF_NAME ccd.psf``). The user guide's recipe "From Source Extractor to a .psf that
    Source Extractor uses" runs with them as printed.

    Parameters
    ----------
    folder : str or os.PathLike, default="."
        Created if needed.
    config : dict, optional
        Settings overriding :data:`DEFAULT_SEXTRACTOR_CONFIG` (as :func:`run_sextractor`'s).
    vignet : (int, int), default=(35, 35)
        Size of the ``VIGNET`` column.
    overwrite : bool, default=False
        Replace existing files.

    Returns
    -------
    paths : dict
        ``"sex"``, ``"param"``, ``"conv"``, ``"spread_param"``: the files written.

    Examples
    --------
    >>> import tempfile
    >>> from sklearn_psf.io import write_sextractor_config
    >>> paths = write_sextractor_config(tempfile.mkdtemp())
    >>> sorted(p.name for p in paths.values())
    ['prepsfex.conv', 'prepsfex.param', 'prepsfex.sex', 'spread.param']
    >>> "VIGNET(35,35)" in paths["param"].read_text()
    True
    """
    folder = Path(folder)
    names = ("prepsfex.sex", "prepsfex.param", "prepsfex.conv", "spread.param")
    existing = [n for n in names if (folder / n).exists()]
    if existing and not overwrite:
        raise FileExistsError(f"{str(folder / existing[0])!r} already exists: pass "
                              "overwrite=True.")
    folder.mkdir(parents=True, exist_ok=True)
    settings, columns = _settings_and_columns(None, config, vignet,
                                              find_program("source-extractor"))
    settings["CATALOG_TYPE"] = "FITS_LDAC"
    paths = _write_files(folder, "prepsfex", settings, columns)
    paths["spread_param"] = folder / "spread.param"
    paths["spread_param"].write_text("\n".join(_SPREAD_PARAMS) + "\n")
    return paths


def run_sextractor(image_path, catalog_path, *, weight_path=None, params=None, config=None,
                   vignet=(35, 35), catalog_type: str = "FITS_LDAC",
                   overwrite: bool = False) -> Path:
    """Run Source Extractor on an image with PSFEx's usual recipe; return the catalogue's path.

    The ``.param``, ``.conv`` and ``.sex`` files are written to a temporary folder (removed
    afterwards), the catalogue to ``catalog_path``.

    Parameters
    ----------
    image_path : str or os.PathLike
        A FITS image (its primary HDU; ``GAIN`` and ``SATURATE`` read from its header).
    catalog_path : str or os.PathLike
        The catalogue to write.
    weight_path : str or os.PathLike, optional
        An inverse-variance map (``WEIGHT_TYPE MAP_WEIGHT``; 0 = bad pixel).
    params : sequence of str, optional
        Output columns, replacing :data:`DEFAULT_SEXTRACTOR_PARAMS` and ``vignet`` (write
        ``"VIGNET(n,n)"`` yourself; vector sizes such as ``FLUX_APER(3)`` are kept as given,
        bare ``FLUX_APER``/``FLUXERR_APER``/``MAG_APER``/``MAGERR_APER`` get one value per
        aperture and ``FLUX_RADIUS`` one per ``PHOT_FLUXFRAC``).
    config : dict, optional
        SExtractor settings overriding :data:`DEFAULT_SEXTRACTOR_CONFIG`, e.g.
        ``{"DETECT_THRESH": 5, "PHOT_APERTURES": "5,10", "PHOT_FLUXFRAC": "0.5,0.8",
        "PSF_NAME": "ccd.psf"}``; lists are joined with commas, booleans become Y/N.
    vignet : (int, int) or None, default=(35, 35)
        Size of the ``VIGNET`` column (None: no vignettes).
    catalog_type : str, default="FITS_LDAC"
    overwrite : bool, default=False
        Replace an existing catalogue.

    Returns
    -------
    path : pathlib.Path

    Raises
    ------
    ProgramNotFoundError
        Source Extractor is not installed (or the image is missing: FileNotFoundError).
    ProgramError
        Source Extractor failed (its standard error's last lines in the message).

    Examples
    --------
    >>> import tempfile
    >>> from sklearn_psf.io import find_program, run_sextractor
    >>> from sklearn_psf.simulate import render_galsim_ccd
    >>> folder = tempfile.mkdtemp()
    >>> ccd = render_galsim_ccd(shape=(256, 256), n_stars=15, n_galaxies=5, random_state=0)
    >>> image = ccd.write(folder)
    >>> if find_program("source-extractor"):
    ...     cat = run_sextractor(image, folder + "/ccd.ldac",
    ...                          weight_path=ccd.weight_path(image))
    """
    exe = _require("source-extractor")
    image_path = Path(image_path)
    if not image_path.exists():
        raise FileNotFoundError(f"The image {str(image_path)!r} does not exist.")
    if weight_path is not None and not Path(weight_path).exists():
        raise FileNotFoundError(f"The weight map {str(weight_path)!r} does not exist.")
    catalog_path = Path(catalog_path)
    if catalog_path.exists() and not overwrite:
        raise FileExistsError(f"{str(catalog_path)!r} already exists: pass overwrite=True.")
    settings, columns = _settings_and_columns(params, config, vignet, exe)
    settings["CATALOG_TYPE"] = catalog_type
    with tempfile.TemporaryDirectory(prefix="sklearn_psf_sex_") as tmp:
        tmp = Path(tmp)
        _write_files(tmp, "psf", settings, columns,
                     skip=("WEIGHT_IMAGE", "STARNNW_NAME", "PSF_NAME"))
        cmd = [exe, str(image_path.resolve()), "-c", "psf.sex", "-CATALOG_NAME", "out.cat"]
        for key in ("STARNNW_NAME", "PSF_NAME"):   # paths: one argument each (spaces)
            if key in settings:
                cmd += [f"-{key}", str(Path(settings[key]).resolve())]
        if weight_path is not None:
            cmd += ["-WEIGHT_TYPE", "MAP_WEIGHT", "-WEIGHT_IMAGE",
                    str(Path(weight_path).resolve())]
        _run(cmd, tmp, "Source Extractor")
        if not (tmp / "out.cat").exists():
            raise ProgramError(f"Source Extractor wrote no catalogue: {' '.join(cmd)}")
        shutil.move(str(tmp / "out.cat"), catalog_path)
    return catalog_path


def run_psfex(catalog_path, out_dir, *, config=None, overwrite: bool = False) -> Path:
    """Run PSFEx on a SExtractor FITS_LDAC catalogue; return the ``.psf`` file's path.

    Parameters
    ----------
    catalog_path : str or os.PathLike
        A catalogue with ``VIGNET`` (e.g. from :func:`run_sextractor`).
    out_dir : str or os.PathLike
        Folder of the ``.psf`` (PSFEx's ``PSF_DIR``), created if needed; PSFEx names it
        after the catalogue, its last extension replaced by ``.psf``.
    config : dict, optional
        PSFEx settings, e.g. ``{"PSFVAR_DEGREES": 3, "NTHREADS": 1,
        "PSFVAR_KEYS": "XWIN_IMAGE,YWIN_IMAGE"}``; ``CHECKPLOT_TYPE NONE``,
        ``CHECKIMAGE_TYPE NONE`` and ``WRITE_XML N`` unless given.
    overwrite : bool, default=False
        Replace an existing ``.psf``.

    Returns
    -------
    path : pathlib.Path

    Raises
    ------
    ProgramNotFoundError, ProgramError
        As :func:`run_sextractor`, for PSFEx.

    Examples
    --------
    >>> from sklearn_psf.io import find_program, run_psfex
    >>> if find_program("psfex"):
    ...     pass        # psf_path = run_psfex("ccd.ldac", "out", config={"NTHREADS": 1})
    """
    exe = _require("psfex")
    catalog_path = Path(catalog_path)
    if not catalog_path.exists():
        raise FileNotFoundError(f"The catalogue {str(catalog_path)!r} does not exist.")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    settings = {"CHECKPLOT_TYPE": "NONE", "CHECKIMAGE_TYPE": "NONE", "WRITE_XML": "N"}
    settings.update({str(k).upper(): v for k, v in (config or {}).items()})
    suffix = _value(settings.get("PSF_SUFFIX", ".psf"))
    out = out_dir / (catalog_path.name.rsplit(".", 1)[0] + suffix)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{str(out)!r} already exists: pass overwrite=True.")
    settings["PSF_DIR"] = str(out_dir.resolve())
    out.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="sklearn_psf_psfex_") as tmp:
        (Path(tmp) / "psf.psfex").write_text("")
        cmd = [exe, str(catalog_path.resolve()), "-c", "psf.psfex"]
        for k, v in settings.items():
            cmd += [f"-{k}", _value(v)]
        _run(cmd, tmp, "PSFEx")
    if not out.exists():
        raise ProgramError(f"PSFEx wrote no {out.name} in {str(out_dir)!r} (too few stars "
                           f"accepted?): {' '.join(cmd)}")
    return out

