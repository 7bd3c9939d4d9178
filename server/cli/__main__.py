"""``python -m server.cli``: the ``modsat`` command line (the console script runs the same ``main``)."""

import sys

from . import main

sys.exit(main())
