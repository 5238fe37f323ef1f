"""``python -m wbmpc.io.rosbag``: see :mod:`wbmpc.io.rosbag.cli`."""

import sys

from wbmpc.io.rosbag.cli import main

sys.exit(main())
