"""``python -m worker``: one worker (the same as ``modsat worker``)."""

import sys

from .main import main

if __name__ == "__main__":
    sys.exit(main())
