"""The command line: end to end at a small size, and one-line errors on bad input."""

import os
import subprocess
import sys

import numpy as np
import pytest

from sklearn_psf.cli import main

SMALL = ["--quick", "--n-simulations", "1", "--study-simulations", "1", "--n-stars", "150",
         "--n-galaxies", "200", "--image-shape", "1500,2000"]


def test_compare_writes_tables_report_and_figures(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["compare", *SMALL, "--schemes", "polynomial,delaunay,kriging",
                 "--studies", "maps,snr,scale", "-o", str(out)])
    assert code == 0
    names = set(os.listdir(out))
    assert {"report.md", "scores.csv", "scores.fits", "galaxies.fits", "fig_cor.png",
            "fig_ell.png", "fig_corhsn.png"} <= names
    report = (out / "report.md").read_text()
    assert "CFHTLS" in report and "kriging" in report
    for png in (n for n in names if n.endswith(".png")):
        assert png in report
    assert "underpowered: 1 simulation" in report and "(oracle)" in report
    scores = (out / "scores.csv").read_text()
    for label in ('scale=4"', 'scale=16"', "oracle", "e_rms_ratio"):
        assert label in scores
    stdout = capsys.readouterr().out
    assert "kriging" in stdout and "report.md" in stdout


@pytest.mark.parametrize("args, message", [
    (["--schemes", "kriging,splines"], "unknown scheme 'splines'"),
    (["--studies", "weather"], "unknown study 'weather'"),
    (["--reference", "nowhere.fits"], "--reference 'nowhere.fits' is neither"),
])
def test_bad_choices_one_line_error(tmp_path, capsys, args, message):
    code = main(["compare", *SMALL, *args, "-o", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1
    assert "Traceback" not in err


@pytest.mark.parametrize("args", [["--n-stars", "-5"], ["--snr", "0"], ["--image-shape", "10"]])
def test_bad_numbers_exit_nonzero_without_traceback(args):
    proc = subprocess.run([sys.executable, "-m", "sklearn_psf", "compare", *args],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "error" in proc.stderr


def test_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    code = main(["compare", *SMALL, "-o", str(blocker / "sub")])
    err = capsys.readouterr().err
    assert code == 2 and "cannot write to the output folder" in err
    assert len(err.strip().splitlines()) == 1


def test_scheduler_runs_on_a_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed", reason="the dask extra is not installed")
    serial, on_dask = tmp_path / "serial", tmp_path / "dask"
    args = [*SMALL, "--schemes", "kriging", "--studies", "none"]
    assert main(["compare", *args, "-o", str(serial)]) == 0
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        assert main(["compare", *args, "--scheduler", cluster.scheduler_address,
                     "-o", str(on_dask)]) == 0
    assert (serial / "scores.csv").read_text() != ""
    a = (serial / "scores.csv").read_text().splitlines()
    b = (on_dask / "scores.csv").read_text().splitlines()
    # identical tables but for the fit times, to the last bits of a float (a sum's rounding
    # may follow the memory alignment of its array, which differs between processes)
    drop = a[0].split(",").index("fit_seconds")
    assert a[0] == b[0] and len(a) == len(b)
    for line_a, line_b in zip(a[1:], b[1:]):
        for k, (u, v) in enumerate(zip(line_a.split(","), line_b.split(","), strict=True)):
            if k == drop:
                continue
            try:
                assert float(u) == pytest.approx(float(v), rel=1e-12, abs=0.0), (k, u, v)
            except ValueError:  # text columns
                assert u == v


def test_unreachable_scheduler_is_a_one_line_error(tmp_path, capsys):
    pytest.importorskip("distributed", reason="the dask extra is not installed")
    code = main(["compare", *SMALL, "--studies", "none", "--scheduler", "tcp://127.0.0.1:9",
                 "-o", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "Dask scheduler" in err and len(err.strip().splitlines()) == 1


def test_missing_optional_package_is_an_input_error_before_any_output(tmp_path, capsys,
                                                                    monkeypatch):
    """An option or a model file that needs a package not installed (Dask for --scheduler,
    PIFF for a PIFF model): exit 2 with its pip install line in one line, before any file or
    folder is made."""
    from astropy.io import fits

    monkeypatch.setitem(sys.modules, "distributed", None)
    monkeypatch.setitem(sys.modules, "piff", None)
    piff_file, stars = tmp_path / "model.piff", tmp_path / "stars.csv"
    header = fits.Header([("HIERARCH PIFF_VERSION", "1.3")])
    fits.HDUList([fits.PrimaryHDU(header=header)]).writeto(piff_file)
    stars.write_text("x,y\n10,20\n")
    new = tmp_path / "new" / "out"
    runs = {
        "compare": ["compare", *SMALL, "--scheduler", "tcp://127.0.0.1:9", "-o", str(new)],
        "fit": ["fit", "--stars", str(stars), "--scheduler", "tcp://127.0.0.1:9",
                "-o", str(new / "m.fits")],
        "validate": ["validate", "--stars", str(stars), "-m", str(piff_file), "-o", str(new)],
    }
    for command, argv in runs.items():
        assert main(argv) == 2, command
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1, err
        extra = "piff" if command == "validate" else "dask"
        assert f"pip install 'sklearn-psf[{extra}]'" in err, err
        assert sorted(os.listdir(tmp_path)) == ["model.piff", "stars.csv"], command


def test_failing_commands_leave_no_empty_folder(tmp_path, capsys):
    """A command that fails after making its output folder removes it (and the parents it
    made) when nothing was written there; an existing folder stays."""
    stars = tmp_path / "stars.csv"
    stars.write_text("x,y\n10,20\n")
    model = tmp_path / "m.psf"
    from sklearn_psf.validation import write_psfex

    write_psfex(model, np.ones((1, 5, 5)), (0.0, 0.0), (1.0, 1.0))
    new = tmp_path / "a" / "b"
    failing = [
        ["compare", *SMALL, "--schemes", "kriging,splines", "-o", str(new)],
        ["compare", *SMALL, "--reference", "nowhere.fits", "-o", str(new)],
        ["validate", "--stars", str(stars), "-m", str(model), "-o", str(new)],  # no image
    ]
    for argv in failing:
        assert main(argv) == 2, argv
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
        assert not (tmp_path / "a").exists(), argv
    kept = tmp_path / "kept"
    kept.mkdir()
    assert main(["validate", "--stars", str(stars), "-m", str(model), "-o", str(kept)]) == 2
    assert kept.is_dir()


def test_help_imports_neither_the_study_nor_matplotlib():
    code = ("import sys; from sklearn_psf.cli import build_parser; build_parser(); "
            "print(sorted(m for m in sys.modules if m.startswith(('sklearn_psf.study', "
            "'matplotlib', 'tqdm'))))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_missing_input_is_reported_before_the_library_is_imported(tmp_path):
    """``fit`` with a missing file answers at once: no library module is imported (measured
    0.2-0.8 s for the whole command on a shared machine, against 4-8 s with the imports)."""
    code = ("import sys; from sklearn_psf.cli import main; "
            f"code = main(['fit', {str(tmp_path / 'none.fits')!r}, '-o', "
            f"{str(tmp_path / 'm.fits')!r}]); "
            "print(code, sorted(m for m in sys.modules if m.startswith(('sklearn_psf.io', "
            "'sklearn_psf.model', 'sklearn.', 'astropy', 'scipy'))))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.stdout.strip() == "2 []", proc.stdout + proc.stderr
    assert "none.fits' does not exist" in proc.stderr


#: a command line that parses (the tests replace what would run it)
_ARGV = ["sklearn-psf", "predict", "m.fits", "--positions", "xy.txt", "-o", "o.fits"]


def test_console_script_collects_less_often_and_freezes_at_exit():
    """The command's process collects its youngest generation every 10,000 allocations (not
    Python's 700) while it runs, and freezes what it leaves before the interpreter exits."""
    code = ("import gc, sys; import sklearn_psf.cli as c; seen = []; "
            f"sys.argv = {_ARGV!r}; "
            "c._run = lambda args: seen.append(gc.get_threshold()[0]) or 0; "
            "code = c._console_script(); print(code, seen, gc.get_freeze_count() > 0)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.stdout.strip() == "0 [10000] True", proc.stdout + proc.stderr


def test_console_script_keeps_freed_memory_for_the_next_arrays():
    """In the command's process (glibc), 32 MB of 1 MB arrays made, freed and made again are
    faulted in once; with the allocator's defaults the heap is trimmed between the two."""
    import platform

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("the allocator is tuned only where the C library is glibc")
    code = ("import resource, sys; import numpy as np; import sklearn_psf.cli as c; "
            "c._run = lambda args: 0; "
            f"sys.argv = {_ARGV!r}; {{tune}}"
            "faults = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_minflt; "
            "make = lambda: [np.ones(1 << 17) for _ in range(32)]; "
            "a = make(); del a; before = faults(); a = make(); print(faults() - before)")
    counts = []
    for tune in ("c._console_script(); ", ""):
        proc = subprocess.run([sys.executable, "-c", code.format(tune=tune)],
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        counts.append(int(proc.stdout))
    # 32 MB are 8,192 pages of 4 kB
    assert counts[0] < 1_000 and counts[1] > 6_000, counts


def test_console_script_imports_sklearn_without_pandas_which_imports_later_as_usual():
    """The command's process imports scikit-learn without pandas (~0.3 s of CPU it never
    uses); pandas imported afterwards is a full module that scikit-learn recognises."""
    pytest.importorskip("pandas", reason="pandas is not installed: nothing to leave out")
    code = ("import sys; import sklearn_psf.cli as c; seen = []; "
            f"sys.argv = {_ARGV!r}; "
            "c._run = lambda args: seen.append(('sklearn' in sys.modules, "
            "'pandas' in sys.modules)) or 0; c._console_script(); "
            "import pandas as pd; from sklearn.preprocessing import StandardScaler; "
            "frame = pd.DataFrame({'flux': [1.0, 2.0]}); "
            "print(seen, StandardScaler().fit(frame).feature_names_in_.tolist())")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    # scikit-learn reads the DataFrame's column names: it recognises pandas
    assert proc.stdout.strip() == "[(True, False)] ['flux']", proc.stdout + proc.stderr


def test_compare_refuses_an_earlier_run_unless_told(tmp_path, capsys):
    """An earlier run's outputs are never mixed with a new report: refused without
    --overwrite; with it, exactly the earlier run's files are removed (a user's file stays)."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.md").write_text("# old\n\n## Files\n\n- `scores.csv`\n- `fig_old.png`\n"
                                   "- `../elsewhere.png`\n- `report.md`\n")
    for name in ("scores.csv", "fig_old.png", "notes.txt"):
        (out / name).write_text("earlier")
    (tmp_path / "elsewhere.png").write_text("not in the folder")
    args = ["compare", *SMALL, "--schemes", "polynomial", "--studies", "none", "-o", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "holds the outputs of an earlier run (3 files" in err and "--overwrite" in err
    assert (out / "fig_old.png").read_text() == "earlier"   # nothing touched
    assert main([*args, "--overwrite"]) == 0
    names = set(os.listdir(out))
    assert "fig_old.png" not in names and {"notes.txt", "report.md", "scores.csv"} <= names
    assert (out / "scores.csv").read_text() != "earlier"
    assert (tmp_path / "elsewhere.png").exists()
    assert "fig_old" not in (out / "report.md").read_text()
