"""``python -m hevr``: the command line (see :mod:`hevr.cli.main`)."""

import sys

from .cli.main import main

if __name__ == "__main__":
    sys.exit(main())
