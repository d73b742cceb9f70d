"""``python -m hevr``: the command line (see :mod:`hevr.cli.main`)."""

import sys

from .cli.main import run

if __name__ == "__main__":
    sys.exit(run())
