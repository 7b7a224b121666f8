"""``python -m dolfinx_granular.slope [options]``: the slope benchmark (see ``--help``)."""

import sys

from .cli import main

sys.exit(main(prog="python -m dolfinx_granular.slope"))
