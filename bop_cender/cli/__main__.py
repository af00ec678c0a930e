"""``python -m bop_cender.cli``: the ``bop-cender`` command (the launcher re-executes itself this way)."""

import sys

from bop_cender.cli.app import main

sys.exit(main())
