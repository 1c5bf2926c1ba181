"""``python -m tmr.sweep`` (see :mod:`tmr.sweep.cli`)."""

import sys

from tmr.sweep.cli import main

if __name__ == "__main__":
    sys.exit(main())
