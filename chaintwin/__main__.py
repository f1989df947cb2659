"""``python -m chaintwin``: the same as the ``chaintwin`` command."""

import sys

from chaintwin.cli.app import main

sys.exit(main())
