"""``python -m thesis_repro``: the command line of :mod:`thesis_repro.cli.commands`."""

import sys

from thesis_repro.cli.commands import main

if __name__ == "__main__":
    sys.exit(main())
