"""``python -m robodyn_ros.cli`` = the ``robodyn`` console script."""
import sys

from . import main

if __name__ == '__main__':   # not when a spawned worker process imports it
    sys.exit(main())
