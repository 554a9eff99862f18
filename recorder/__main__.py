"""``python -m recorder``: record a run's traffic into MCAP."""

import sys

from recorder.node import main

sys.exit(main())
