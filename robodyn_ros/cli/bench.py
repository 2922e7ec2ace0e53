"""``robodyn bench [speed|precision|...]``: print benchmark tables (see :mod:`robodyn_ros.bench`)."""
from __future__ import annotations

from ..bench import BENCHES

#: one line for ``robodyn --help``
HELP = f'benchmarks: {", ".join(BENCHES)} (default {BENCHES[0]})'


def add_parser(sub):
    """Register ``bench`` with one sub-subcommand per benchmark module."""
    from ..bench import add_subparsers
    p = sub.add_parser('bench', help=HELP,
                       description='Print benchmark tables; without a name, runs the speed benchmark.')
    add_subparsers(p)
    return p


def main(args) -> int:
    """Dispatch to the chosen benchmark."""
    from ..bench import main as bench_main
    return bench_main(args)
