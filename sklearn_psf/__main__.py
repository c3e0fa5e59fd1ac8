"""``python -m sklearn_psf`` is the ``sklearn-psf`` command."""

import sys

from .cli import _console_script

sys.exit(_console_script())
