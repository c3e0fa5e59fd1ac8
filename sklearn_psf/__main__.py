"""``python -m sklearn_psf`` is the ``sklearn-psf`` command."""

import sys

from .cli import main

sys.exit(main())
