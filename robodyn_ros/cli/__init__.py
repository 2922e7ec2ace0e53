"""``robodyn``: the offline command line (run, check, scenes, and the subcommands added beside them).

Each subcommand is a module here with ``add_parser(subparsers)`` registering its arguments and
a ``main(args) -> int`` function. The list below is the only place that names them.
"""
from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMANDS = ['run', 'check', 'scenes', 'resim', 'replay', 'plot', 'bench', 'advise', 'sweep']


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every available subcommand."""
    from ..version import __version__
    parser = argparse.ArgumentParser(prog='robodyn', description='robodyn_ros offline tools')
    parser.add_argument('--version', action='version', version=f'robodyn_ros {__version__}')
    sub = parser.add_subparsers(dest='command', required=True)
    for name in SUBCOMMANDS:
        try:
            mod = importlib.import_module(f'.{name}', __name__)
        except ModuleNotFoundError as e:
            if e.name == f'{__name__}.{name}':
                continue  # subcommand not built yet
            raise
        p = mod.add_parser(sub)
        p.set_defaults(_main=mod.main)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Print a warning as one line ``robodyn: warning: <message>`` (the default filter prints each once)."""
    print(f'robodyn: warning: {message}', file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    """Entry point of the ``robodyn`` console script; returns the exit status."""
    import warnings
    args = build_parser().parse_args(argv)
    shown, warnings.showwarning = warnings.showwarning, _show_warning
    try:
        return int(args._main(args) or 0)
    finally:
        warnings.showwarning = shown


if __name__ == '__main__':
    sys.exit(main())
