"""``python -m iwr``: the ``iwr`` command line."""

import sys

from .cli import main

sys.exit(main())
