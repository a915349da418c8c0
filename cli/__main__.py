"""``python -m relight.cli``: the ``relight`` command."""

import sys

from . import main

sys.exit(main())
