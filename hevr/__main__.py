"""``python -m hevr``: the command line (see :mod:`hevr.cli`)."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
