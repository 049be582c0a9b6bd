"""``python -m rosbag_tools`` runs the ``allo-bag`` command."""

import sys

from rosbag_tools.entry import main

sys.exit(main())
