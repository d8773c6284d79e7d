"""``python -m iwr.study``: the study command on its own (``iwr study`` in the ``iwr`` CLI)."""

import sys

from . import main

sys.exit(main())
