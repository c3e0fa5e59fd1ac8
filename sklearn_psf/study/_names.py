"""Names shared by the study's stages, report and figures."""

#: The optimal predictor on the same field (:class:`~sklearn_psf.study.compare.FieldOracle`).
ORACLE = "oracle"
#: ``PSFModel()`` with the library's defaults (basis, outliers, interpolator).
DEFAULT_MODEL = "psfmodel-default"
