"""`python -m skinkit.cli`: the same as the `skinkit` command."""
import sys

from . import main

sys.exit(main())
