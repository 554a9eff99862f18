"""``python -m testbed.cli``: the ``formation`` command."""

import sys

from testbed.cli import main

sys.exit(main())
