"""``python -m sklearn_psf`` is the ``sklearn-psf`` command."""

import sys

from .cli import command

sys.exit(command())
