"""``python -m lokigraph``: the same as the ``lokigraph`` command."""

import sys

from .cli import main

sys.exit(main())
