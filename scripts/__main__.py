"""``python -m swarmslam``: the same as the ``swarmslam`` command."""

import sys

from swarmslam.cli import main

sys.exit(main())
