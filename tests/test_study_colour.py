"""The colour study: on a chromatic field the position-only model's size residual follows the
galaxies' true colour dependence (simulation truth), and the colour dimension removes most of
it at no ellipticity cost on the control field."""

import pytest

from sklearn_psf.cli import build_parser
from sklearn_psf.study.colour import colour_report_section, plot_colour_study, \
    run_colour_study, write_colour_report


@pytest.fixture(scope="module")
def result():
    return run_colour_study(n_simulations=1, n_stars=300, n_galaxies=1000,
                            image_shape=(2000, 2000), random_state=0)


def test_what_colour_costs_and_what_the_colour_dimension_gives_back(result):
    row = result.scores[0]
    # the truth: bluer galaxies have larger PSFs (about -1e-3 per magnitude of g-i)
    assert -2e-3 < row["slope_truth"] < -5e-4
    # a model of position only cannot follow it: its paired residual is minus the truth's
    # slope (measured -0.95x on two simulations)
    assert row["slope_position_paired"] == pytest.approx(-row["slope_truth"], rel=0.2)
    # the colour dimension gives most of it back (measured 0.17-0.21x) ...
    assert row["colour_rms_colour"] < 0.5 * row["colour_rms_position"]
    # ... and costs nothing where colour does nothing (measured 1.000-1.007x)
    assert row["e_rms_colour_control"] < 1.02 * row["e_rms_position_control"]


def test_report_figure_and_opt_in(result, tmp_path):
    text = colour_report_section(result)
    assert "(sigma_model - sigma_true) / sigma_true" in text and "per magnitude" in text
    assert "| slope of ds against g-i [1/mag] |" in text and "true PSF size" in text
    path = write_colour_report(result, tmp_path)
    assert path.read_text() == text
    assert (tmp_path / "size_vs_colour.png").stat().st_size > 1000
    assert len(plot_colour_study(result).axes) == 1
    args = build_parser().parse_args(["compare", "-o", str(tmp_path)])
    assert "colour" not in args.studies and "exposures" in args.studies
    args = build_parser().parse_args(["compare", "-o", str(tmp_path), "--studies", "colour"])
    assert args.studies == ["colour"]
