"""``python -m sim_bridge``: run the simulator-bridge process."""

import sys

from sim_bridge.cli import main

sys.exit(main())
