"""``robodyn``: the offline command line (run, check, scenes, and the subcommands added beside them).

Each subcommand is a module here with ``HELP`` (its line in ``robodyn --help``),
``add_parser(subparsers)`` registering its arguments and a ``main(args) -> int`` function; a
module imports at its top only what describing its options needs (the standard library), so that
``robodyn --help`` and each subcommand start fast. The list below is the only place that names them.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

SUBCOMMANDS = ['run', 'check', 'scenes', 'resim', 'replay', 'plot', 'layout', 'bench', 'advise', 'sweep', 'warm']


class _Version(argparse.Action):
    """``--version``: the installed package's version, read when asked for (reading distribution
    metadata costs more than the rest of ``robodyn --help``)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from ..version import __version__
        print(f'robodyn_ros {__version__}')
        parser.exit()


def build_parser(argv=None) -> argparse.ArgumentParser:
    """The argument parser with every available subcommand.

    argv: the arguments it is about to parse, or None. When given, only the subcommand they name
    is built with its options; the others are listed by name and ``HELP`` line (what
    ``robodyn --help`` shows), so that ``robodyn run`` does not import what ``robodyn bench``
    needs to describe its options.
    """
    chosen = next((a for a in argv if not a.startswith('-')), None) if argv is not None else None
    parser = argparse.ArgumentParser(prog='robodyn', description='robodyn_ros offline tools')
    parser.add_argument('--version', action=_Version, nargs=0, help="show the package's version and exit")
    sub = parser.add_subparsers(dest='command', required=True)
    for name in SUBCOMMANDS:
        try:
            mod = importlib.import_module(f'.{name}', __name__)
        except ModuleNotFoundError as e:
            if e.name == f'{__name__}.{name}':
                continue  # subcommand not built yet
            raise
        p = mod.add_parser(sub) if argv is None or name == chosen else sub.add_parser(name, help=mod.HELP)
        p.set_defaults(_main=mod.main)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Print a warning as one line ``robodyn: warning: <message>`` (the default filter prints each once)."""
    print(f'robodyn: warning: {message}', file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    """Entry point of the ``robodyn`` console script; returns the exit status."""
    import warnings
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(argv).parse_args(argv)
    shown, warnings.showwarning = warnings.showwarning, _show_warning
    try:
        return int(args._main(args) or 0)
    except BrokenPipeError:   # output piped into a reader that stopped (`robodyn run ... | head`): not an error
        try:
            sys.stdout = open(os.devnull, 'w')   # so that the interpreter's final flush stays quiet
        except OSError:
            pass
        return 0
    finally:
        warnings.showwarning = shown


if __name__ == '__main__':
    sys.exit(main())
