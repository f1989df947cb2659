"""``python -m chaintwin``: the same as the ``chaintwin`` command."""

import sys

from chaintwin.cli import main

sys.exit(main())
