"""``python -m hevr.cli``: the command line (same as ``python -m hevr`` and ``hevr``)."""

import sys

from .main import run

if __name__ == "__main__":
    sys.exit(run())
