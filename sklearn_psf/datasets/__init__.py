"""Embedded default data and dataset makers (``make_*`` / ``load_*``).

The default reference basis is documented in
:mod:`sklearn_psf.datasets._make_default_reference` (the script that regenerates it).
"""

from ..simulate import PSFField, make_psf_field, realistic_snr
from ._base import default_reference_path, load_default_reference

__all__ = [
    "PSFField",
    "default_reference_path",
    "load_default_reference",
    "make_psf_field",
    "realistic_snr",
]
