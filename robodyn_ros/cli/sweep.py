"""``robodyn sweep SPEC.yaml --out DIR``: many runs of a scene on Dask (see :mod:`robodyn_ros.sweep`)."""
from __future__ import annotations

import sys

#: one line for ``robodyn --help``
HELP = 'Monte Carlo / grid sweeps of a scene on Dask (Parquet table + plot)'


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('sweep', help=HELP,
                       description='Run every run of a sweep spec (grid and seeded random draws of scene keys '
                                   'and run settings) on a Dask cluster; rows are kept in DIR as they finish, '
                                   'so re-running the same command resumes. Spec format: robodyn_ros.sweep.')
    p.add_argument('spec', help='sweep spec YAML (e.g. config/sweeps/stanford_arm_montecarlo.yaml)')
    p.add_argument('--out', required=True, help='output directory (row files, results.parquet, summary.png)')
    p.add_argument('--workers', type=int, default=None,
                   help='local worker processes (default: one per core; 0 = in this process, no Dask)')
    p.add_argument('--scheduler', default=None,
                   help='address of a running Dask scheduler (tcp://host:8786) instead of a local cluster')
    p.add_argument('--no-plot', action='store_true', help='no summary.png')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    return p


def main(args) -> int:
    """Run the sweep; 0 when every run has a row, 130 when interrupted (re-run to resume), 2 for a bad
    spec or a DIR of another sweep, 1 when the cluster cannot run it or no run could be made (every
    row invalid or error: the first one's message is printed)."""
    from ..sweep import ClusterError, Progress, SweepError, load_spec, read_table, run_sweep
    try:
        spec = load_spec(args.spec)
    except SweepError as e:
        print(f'robodyn sweep: {e}', file=sys.stderr)
        return 2
    if args.workers is not None and args.workers < 0:
        print(f'robodyn sweep: --workers: must be >= 0, got {args.workers}', file=sys.stderr)
        return 2
    if args.scheduler and args.workers is not None:
        print('robodyn sweep: --workers is ignored with --scheduler (the cluster has its own workers)',
              file=sys.stderr)
    progress = Progress(spec.n_runs, quiet=args.quiet)
    try:
        res = run_sweep(spec, args.out, workers=args.workers, scheduler=args.scheduler, progress=progress,
                        plot=not args.no_plot)
    except SweepError as e:
        print(f'robodyn sweep: {e}', file=sys.stderr)
        return 2
    except ClusterError as e:
        print(f'robodyn sweep: {e}', file=sys.stderr)
        return 1
    if res.interrupted:
        if progress.tty and not args.quiet:
            print(file=sys.stderr)  # end the progress line
        print(f'robodyn sweep: interrupted; {res.skipped + res.executed} of {res.runs} runs are kept in {args.out}; '
              'run the same command again to finish the others', file=sys.stderr)
        return 130
    rows = read_table(res.table)
    status = {}
    for r in rows:
        status[r['status']] = status.get(r['status'], 0) + 1
    print(f'sweep        {spec.scene_name}: {res.runs} runs ({res.executed} run now, {res.skipped} found done) '
          f'in {res.wall:.1f} s wall')
    print('status       ' + ', '.join(f'{k} {v}' for k, v in sorted(status.items())))
    print(f'table        {res.table}' + (f'\nplot         {res.plot}' if res.plot else ''))
    if rows and all(r['status'] in ('invalid', 'error') for r in rows):   # nothing ran: say why
        first = rows[0]
        print(f'robodyn sweep: no run could be made: all {len(rows)} rows are invalid or error; the first '
              f'(run {first["run"]}, {first["status"]}): {first["message"]}', file=sys.stderr)
        return 1
    return 0
