"""``python -m depthguard.cli``: the ``depthguard`` command."""

import sys

from depthguard.cli import main

sys.exit(main())
