"""Embedded default data: the reference bases of the simulations (``load_*``).

:mod:`sklearn_psf.datasets` loads data only and never imports :mod:`sklearn_psf.simulate`
(which builds fields from these bases). The embedded bases are documented in
:mod:`sklearn_psf.datasets._make_default_reference` (the script that regenerates them).
"""

from ._base import default_reference_path, load_default_reference
from ._reference import ReferenceBasis, read_fits_image

__all__ = [
    "ReferenceBasis",
    "default_reference_path",
    "load_default_reference",
    "read_fits_image",
]
