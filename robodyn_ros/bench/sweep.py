"""``robodyn bench sweep``: wall time of a Monte Carlo sweep on 1 and 2 Dask workers, and what Dask costs per run.

The sweep is ``config/sweeps/stanford_arm_montecarlo.yaml`` (64 runs of 1 s of stanford_arm, RK4
at 1 ms, each with its DOP853 reference at rtol 1e-10; ``--spec`` for another). It runs through
:func:`robodyn_ros.sweep.run_sweep` into a fresh directory (row files, Parquet table; no plot):

* ``in-process`` — ``workers=0``: the same tasks one after the other in this process, no Dask;
* ``Dask, N worker(s)`` — a ``LocalCluster`` of N processes (one thread each), started and warmed
  up (every worker has run one task, so imports and compiled kernels are loaded) before the
  clock starts; the cluster's start-up is reported on its own.

Overhead per run = (wall on 1 Dask worker − the sum of the runs' own wall times measured inside
the tasks) / runs: the time the one worker was not running a run — submitting, scheduling,
shipping the task and its row, the client's bookkeeping when the worker waits for it; the target
is below 5 % of a run's own time (the mean wall time of a row: the 1 s run and its reference).
The in-process wall is shown beside it (there the client's row writing and the runs take turns;
on Dask they overlap). Speed-up = wall on 1 worker / wall on 2 workers (at most the number of
free cores). Each configuration runs ``--repeat`` times and the fastest counts; wall times on a
shared machine vary with its load (printed with the table).
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time

HELP = 'sweep: wall time of a 64-run stanford_arm Monte Carlo on 1 vs 2 Dask workers, overhead per run'


def _default_spec() -> str:
    """The example Monte Carlo spec (source tree or installed share directory)."""
    here = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), 'config',
                        'sweeps', 'stanford_arm_montecarlo.yaml')
    if os.path.isfile(here):
        return here
    return os.path.join(sys.prefix, 'share', 'robodyn_ros', 'config', 'sweeps', 'stanford_arm_montecarlo.yaml')


def measure(spec_path: str, workers=(1, 2), tmp: str | None = None, repeat: int = 2) -> dict:
    """Run the sweep in process and on each worker count; returns the figures (seconds).

    ``{'runs', 'row_time' (mean wall s of a row in process), 'inline' (wall s), 'dask': {N:
    {'wall', 'startup', 'busy' (sum of the rows' wall times)}}, 'same_rows' (every table equal to
    the in-process one, timing aside)}``; the fastest of ``repeat`` sweeps counts.
    """
    from ..sweep import (TIMING_COLUMNS, Pool, clear_reference_cache, execute_run, expand, load_spec, read_table,
                         run_sweep)
    spec = load_spec(spec_path)
    base = tmp or tempfile.mkdtemp(prefix='robodyn-bench-sweep-')
    first = expand(spec, [0])[0]
    execute_run(first)  # this process: imports, compiled kernels
    inline = float('inf')
    for k in range(repeat):
        clear_reference_cache()  # every repeat runs its references (a process keeps them otherwise)
        t0 = time.perf_counter()
        res = run_sweep(spec, os.path.join(base, f'inline-{k}'), workers=0, plot=False)
        inline = min(inline, time.perf_counter() - t0)
    rows = read_table(res.table)

    def strip(rs):
        return [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rs]
    ref = repr(strip(rows))
    out = {'runs': spec.n_runs, 'inline': inline, 'row_time': sum(r['wall_time'] for r in rows) / len(rows),
           'dask': {}, 'same_rows': True}
    for n in workers:
        t0 = time.perf_counter()
        with Pool(n) as pool:
            startup = time.perf_counter() - t0
            pool.client.run(execute_run, first)  # every worker: imports, compiled kernels
            best = None
            for k in range(repeat):
                pool.client.run(clear_reference_cache)
                t1 = time.perf_counter()
                res = run_sweep(spec, os.path.join(base, f'w{n}-{k}'), plot=False, pool=pool)
                wall = time.perf_counter() - t1
                got = read_table(res.table)
                out['same_rows'] &= repr(strip(got)) == ref
                if best is None or wall < best['wall']:
                    best = {'wall': wall, 'startup': startup, 'busy': sum(r['wall_time'] for r in got)}
        out['dask'][n] = best
    if tmp is None:
        shutil.rmtree(base, ignore_errors=True)
    return out


def report(m: dict) -> str:
    """The markdown table and the overhead line of :func:`measure`'s figures."""
    from .timing import machine_line, table
    n = m['runs']
    rows = [['in-process (no Dask)', f'{m["inline"]:.2f}', f'{m["inline"] / n * 1e3:.1f}', '—', '—']]
    w1 = m['dask'].get(1, {}).get('wall')
    for k, d in m['dask'].items():
        rows.append([f'Dask, {k} worker{"s" if k > 1 else ""}', f'{d["wall"]:.2f}', f'{d["wall"] / n * 1e3:.1f}',
                     f'{w1 / d["wall"]:.2f}' if w1 else '—', f'{d["startup"]:.1f}'])
    lines = [table(['', 'wall (s)', 'per run (ms)', 'speed-up vs 1 worker', 'cluster start (s)'], rows), '']
    if w1:
        d = m['dask'][1]
        over = (d['wall'] - d['busy']) / n
        share = 100 * over / m['row_time']
        lines.append(f'scheduling overhead per run (1 worker): {over * 1e3:.2f} ms = {share:.1f} % '
                     f'of a run ({m["row_time"] * 1e3:.1f} ms: 1 s simulated and its reference; target < 5 %)')
    lines.append(f'tables equal to the in-process one (timing columns aside): {"yes" if m["same_rows"] else "NO"}')
    lines.append(f'machine: {machine_line()}')
    return '\n'.join(lines)


def add_arguments(p):
    """Options of the sweep benchmark."""
    p.add_argument('--spec', default=None, help='sweep spec (default config/sweeps/stanford_arm_montecarlo.yaml)')
    p.add_argument('--workers', type=int, nargs='+', default=[1, 2], help='Dask worker counts (default 1 2)')
    p.add_argument('--repeat', type=int, default=2, help='sweeps per configuration, the fastest counts (default 2)')
    return p


def main(args) -> int:
    """Measure and print the table."""
    m = measure(args.spec or _default_spec(), tuple(args.workers), repeat=max(1, args.repeat))
    print(report(m))
    return 0 if m['same_rows'] else 1
