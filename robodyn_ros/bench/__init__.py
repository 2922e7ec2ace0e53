"""Benchmarks that print figures (never asserted by tests): ``robodyn bench [speed|precision|...]``.

Each benchmark is a module here with ``HELP`` (one line), ``add_arguments(parser)`` and
``main(args) -> int``; :data:`BENCHES` is the only place that names them, and a module that does
not exist yet is skipped. ``robodyn bench`` and ``python -m robodyn_ros.bench`` without a
benchmark name run ``speed`` with its defaults.
"""
from __future__ import annotations

import argparse
import importlib

#: benchmark modules, in help order; the first is the default
BENCHES = ('speed', 'precision', 'sweep', 'urdf', 'startup', 'stiff', 'contact', 'live', 'control', 'peers')


def available() -> dict:
    """``{name: module}`` of the benchmarks that exist in this install."""
    out = {}
    for name in BENCHES:
        try:
            out[name] = importlib.import_module(f'.{name}', __name__)
        except ModuleNotFoundError as e:
            if e.name != f'{__name__}.{name}':
                raise
    return out


def add_subparsers(parser: argparse.ArgumentParser) -> None:
    """Register one sub-subcommand per available benchmark on ``parser``."""
    mods = available()
    sub = parser.add_subparsers(dest='bench', metavar='{' + ','.join(mods) + '}',
                                help=f'benchmark to run (default: {BENCHES[0]})')
    for name, mod in mods.items():
        p = sub.add_parser(name, help=mod.HELP, description=mod.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_bench_main=mod.main)


def main(args: argparse.Namespace) -> int:
    """Run the benchmark chosen on the command line (the default one when none was named)."""
    run = getattr(args, '_bench_main', None)
    if run is None:
        default = available()[BENCHES[0]]
        p = argparse.ArgumentParser(prog=f'robodyn bench {BENCHES[0]}')
        default.add_arguments(p)
        args = p.parse_args([])
        run = default.main
    return int(run(args) or 0)


def run_argv(argv=None, prog='python -m robodyn_ros.bench') -> int:
    """Entry point of ``python -m robodyn_ros.bench [NAME] [options]`` (NAME defaults to speed)."""
    import sys
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or (argv[0] not in BENCHES and argv[0] not in ('-h', '--help')):
        argv = [BENCHES[0]] + argv
    parser = argparse.ArgumentParser(prog=prog, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_subparsers(parser)
    return main(parser.parse_args(argv))
