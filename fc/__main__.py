"""``python -m fc``: run the flight-controller process."""

import sys

from fc.cli import main

sys.exit(main())
