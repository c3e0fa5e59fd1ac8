"""The multi-exposure study: pooled beats per-exposure at 10 exposures, figure, verdict."""

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from astropy.table import Table

from sklearn_psf.metrics import survey_table
from sklearn_psf.study.exposures import (
    ExposureStudyResult,
    cheapest_configuration,
    exposure_report_section,
    plot_sigma_sys_vs_exposures,
    run_exposure_study,
    write_exposure_report,
)

SMALL = dict(n_galaxies=150, image_shape=(1000, 1000), dither=80.0, theta_bins=(0.3, 3.0, 5))


@pytest.fixture(scope="module")
def small_study():
    return run_exposure_study((1, 10), (40,), n_simulations=3, n_jobs=2, **SMALL)


def test_pooled_below_per_exposure_at_ten_exposures(small_study):
    s = small_study.scores
    assert len(s) == 3 * 2 * 2
    ten = s[s["n_exposures"] == 10]
    pooled, per = ten[ten["scheme"] == "pooled"], ten[ten["scheme"] == "per-exposure"]
    pooled.sort("simulation")
    per.sort("simulation")
    # paired over simulations: the averaged residual and its sigma_sys^2
    assert np.all(pooled["e_rms_averaged"] < per["e_rms_averaged"])
    assert np.median(pooled["sigma_sys2"] / per["sigma_sys2"]) < 1
    # averaging over exposures lowers the residual of both schemes
    one = s[s["n_exposures"] == 1]
    for scheme in ("pooled", "per-exposure"):
        assert (np.median(ten[ten["scheme"] == scheme]["e_rms_averaged"])
                < np.median(one[one["scheme"] == scheme]["e_rms_averaged"]))
    # one exposure: the pooled model is the single-exposure model
    np.testing.assert_allclose(one[one["scheme"] == "pooled"]["sigma_sys2"],
                               one[one["scheme"] == "per-exposure"]["sigma_sys2"], rtol=1e-10)


def test_study_is_reproducible_and_parallel_invariant(small_study):
    serial = run_exposure_study((1, 10), (40,), n_simulations=1, n_jobs=1, **SMALL)
    first = small_study.scores[small_study.scores["simulation"] == 0]
    np.testing.assert_allclose(serial.scores["sigma_sys2"], first["sigma_sys2"], rtol=1e-10)


def test_report_and_figure(small_study, tmp_path):
    path = write_exposure_report(small_study, tmp_path)
    text = path.read_text()
    assert "Verdict" in text and "paired over simulations" in text
    assert "3 simulations per configuration" in text and "multipoles 10-20000" in text
    assert (tmp_path / "sigma_sys_vs_exposures.png").stat().st_size > 10_000
    fig = plot_sigma_sys_vs_exposures(small_study)
    ax = fig.axes[0]
    levels = sorted(line.get_ydata()[0] for line in ax.get_lines()
                    if len(set(line.get_ydata())) == 1 and len(line.get_ydata()) == 2)
    np.testing.assert_allclose(levels, sorted(survey_table()["sigma_sys2"]))


def _result(values):
    rows = [(sch, m, n, v) for (sch, m), series in values.items() for n, v in series.items()]
    return ExposureStudyResult(Table(rows=rows, names=["scheme", "n_stars", "n_exposures",
                                                       "sigma_sys2"]), Table(), None)


def test_cheapest_configuration_and_shortfall():
    req = 1e-7
    met = cheapest_configuration(_result({
        ("pooled", 60): {1: 5e-6, 5: 2e-7, 10: 0.9e-7},
        ("pooled", 120): {1: 3e-6, 5: 0.8e-7, 10: 0.5e-7},
        ("per-exposure", 120): {1: 3e-6, 5: 5e-7, 10: 4e-7}}), requirement=req)
    assert met["met"]
    assert (met["best"]["scheme"], met["best"]["n_stars"], met["best"]["n_exposures"]) == (
        "pooled", 120, 5)
    short = cheapest_configuration(_result({("pooled", 60): {1: 1e-5, 2: 4e-6, 8: 1e-6}}),
                                   requirement=req)
    assert not short["met"]
    (s,) = short["shortfalls"]
    assert s["factor"] == pytest.approx(10.0)
    # medians fall as N^-1 from N = 2: 1e-7 is reached at N = 80
    assert s["slope"] == pytest.approx(-1.0) and s["n_needed"] == pytest.approx(80.0)
    text = exposure_report_section(_result({("pooled", 60): {1: 1e-5, 2: 4e-6, 8: 1e-6}}))
    assert "No configuration" in text and "times the requirement" in text
