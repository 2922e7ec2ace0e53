"""``python -m robodyn_ros.bench [speed|precision|...] [options]``."""
import sys

from . import run_argv

sys.exit(run_argv())
