"""``python -m robodyn_ros.cli`` = the ``robodyn`` console script."""
import sys

from . import main

sys.exit(main())
