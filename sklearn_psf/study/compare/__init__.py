"""The paper's comparison of interpolation schemes, as a study over simulated PSF fields.

For every simulation of every configuration, a :class:`~sklearn_psf.model.PSFModel` per
interpolation scheme is fitted on the stars measured from the simulated image (the paper's
pipeline: stamp normalisation, the simulation's own PCA basis, the IQR cut) and evaluated at the
galaxy-PSFs, where the true PSF is known. This is cross-validation with a predefined split
(train = stars, test = galaxy-PSFs): :func:`paper_split` builds that split for
``cross_validate`` and ``GridSearchCV``, and :func:`run_study` runs it over many simulations
with the diagnostics of the paper (residual ellipticities, PCA-coefficient residuals,
ellipticity correlation functions and the implied weak-lensing systematics).

Simulations are reproducible: simulation ``i`` of a study seeded with ``random_state`` uses the
``i``-th child of ``numpy.random.SeedSequence(random_state)``, whatever the configuration,
so that configurations are compared on the same PSF fields, and serial, ``n_jobs`` and Dask
runs give the same tables.

Stages: the schemes and the paper's PSF model (``_schemes``), the simulated configurations
(``_configs``), one simulation evaluated (``_evaluate``), the run over simulations, of one study or several sharing a pool of workers (``_run``),
hyperparameters by cross-validation (``_tuning``) and the optimal predictor on the same field
(``_oracle``).
"""

from .._names import DEFAULT_MODEL, ORACLE
from ._configs import (
    SimulationConfig,
    density_study_configs,
    example_stars,
    outlier_study_configs,
    scale_study_configs,
    snr_study_configs,
)
from ._oracle import FieldOracle, oracle_e_rms_ratio
from ._run import StudyResult, combine_results, run_studies, run_study
from ._schemes import (
    ARCMIN,
    default_schemes,
    make_psf_model,
    paper_split,
    tuned_schemes,
)
from ._tuning import PARAM_GRIDS, tune_schemes

__all__ = [
    "FieldOracle",
    "SimulationConfig",
    "StudyResult",
    "default_schemes",
    "make_psf_model",
    "oracle_e_rms_ratio",
    "paper_split",
    "run_studies",
    "run_study",
    "snr_study_configs",
    "density_study_configs",
    "outlier_study_configs",
]
