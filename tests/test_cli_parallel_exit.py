"""``sklearn-psf fit --n-jobs 2`` ends cleanly: no leaked semaphores, no Python warning."""

import os
import re
import subprocess
import sys

import pytest
from astropy.io import fits

from sklearn_psf.simulate import write_example_ldac

pytest.importorskip("joblib")


@pytest.fixture(scope="module")
def catalogues(tmp_path_factory):
    """Two small catalogues of VIGNETs (150 stars each), distinct names."""
    folder = tmp_path_factory.mktemp("parallel_exit")
    paths = []
    for k in (1, 2):
        sub = folder / str(k)
        sub.mkdir()
        made = write_example_ldac(sub, n_stars=150, n_galaxies=30, image_shape=(1500, 1500),
                                  snr=500, random_state=10 + k)
        path = folder / f"ccd{k}.ldac"
        os.rename(made["catalog"], path)
        paths.append(path)
    return paths


def test_parallel_fit_leaves_no_semaphore_and_no_warning(tmp_path, catalogues):
    """The worker's tqdm lock was a named semaphore, left behind when the worker is stopped
    at the end of the command: Python's resource tracker then warned of "1 leaked semaphore
    objects" per worker at exit."""
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "PYTHONWARNINGS": "default"}
    proc = subprocess.run(
        [sys.executable, "-m", "sklearn_psf", "fit", "--stars", *map(str, catalogues),
         "--no-plots", "--n-jobs", "2", "-o", str(out / "psf.fits")],
        capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    err = proc.stderr
    assert "leaked" not in err and "resource_tracker" not in err, err[-2000:]
    # no Python warning of any category; the command's own verdicts on a model
    # ("sklearn-psf: warning: ...") are its report, not a warning of the machinery
    assert not re.search(r"\w+Warning\b", err), err[-2000:]
    lines = [s.strip() for s in re.split(r"[\r\n]", err)]
    stray = [s for s in lines if s and "warning" in s.lower()
             and not s.startswith("sklearn-psf: warning:")]
    assert not stray, stray
    for k in (1, 2):  # both models written, each one a model file
        with fits.open(out / f"psf_ccd{k}.fits") as hdul:
            assert len(hdul) > 1
