"""Measurement helpers shared by the benchmarks: interleaved per-call timing, RSS, markdown tables.

Timings on a shared machine are noisy, so every comparison is made against references
measured in the same run, interleaved (A, B, C, A, B, C, ...), and reported as the minimum
(the least-disturbed run) with the median beside it where useful. Per-call times are CPU time
of this process (``time.process_time``): the time other processes hold the cores is left out,
which makes them steady on a loaded machine (wall-clock batches are kept for the run figures).
"""
from __future__ import annotations

import os
import resource
import statistics
import time


def calibrate(fn, target=0.02) -> int:
    """Number of calls of ``fn`` that take about ``target`` CPU seconds (at least 1).

    The first call is not timed: it may load or compile code (numba's cache), which would make
    the batches far too small.
    """
    fn()
    n = 1
    while True:
        t0 = time.process_time()
        for _ in range(n):
            fn()
        dt = time.process_time() - t0
        if dt >= target or n >= 1 << 20:
            return max(1, int(n * target / max(dt, 1e-9)))
        n *= 4 if dt < target / 8 else 2


def per_call(fns: dict, repeat=7, target=0.02) -> dict:
    """CPU seconds per call ``{name: (min, median)}`` of argument-less callables, interleaved.

    fns: name -> callable (None entries are skipped and reported as None); repeat: batches
    per callable; target: seconds per batch.
    """
    live = {k: f for k, f in fns.items() if f is not None}
    counts = {k: calibrate(f, target) for k, f in live.items()}
    samples = {k: [] for k in live}
    for _ in range(repeat):
        for k, f in live.items():
            n = counts[k]
            t0 = time.process_time()
            for _ in range(n):
                f()
            samples[k].append((time.process_time() - t0) / n)
    return {k: ((min(samples[k]), statistics.median(samples[k])) if k in samples else None) for k in fns}


def best_of(fn, repeat=3) -> tuple:
    """``(min wall, median wall, min CPU)`` seconds of ``repeat`` calls of ``fn``.

    The CPU time (this process only, ``time.process_time``) leaves out the time other
    processes hold the cores, so it is the steadier figure on a shared machine.
    """
    ts, cs = [], []
    for _ in range(repeat):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return min(ts), statistics.median(ts), min(cs)


def rss_bytes() -> int:
    """Resident set size of this process now (bytes), from /proc/self/statm."""
    try:
        with open('/proc/self/statm') as f:
            return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')
    except OSError:
        return 0


def peak_rss_bytes() -> int:
    """Peak resident set size of this process so far (bytes)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def fmt_time(s) -> str:
    """Seconds as a short human figure (ns/µs/ms/s); '—' for None."""
    if s is None:
        return '—'
    if s < 1e-6:
        return f'{s * 1e9:.0f} ns'
    if s < 1e-3:
        return f'{s * 1e6:.2f} µs'
    if s < 1.0:
        return f'{s * 1e3:.2f} ms'
    return f'{s:.2f} s'


def fmt_ratio(a, b) -> str:
    """``a / b`` with two decimals; '—' when either is missing."""
    if a is None or b is None or b == 0:
        return '—'
    return f'{a / b:.2f}'


def table(header, rows) -> str:
    """A markdown table from a header list and rows of cells (converted with str)."""
    out = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join('---' for _ in header) + '|']
    for r in rows:
        out.append('| ' + ' | '.join(str(c) for c in r) + ' |')
    return '\n'.join(out)


def machine_line() -> str:
    """CPU count, load average and library versions, for the heading of a report."""
    import platform
    import numpy as np
    parts = [f'Python {platform.python_version()}', f'numpy {np.__version__}']
    for mod in ('numba', 'pinocchio', 'mujoco'):
        try:
            m = __import__(mod)
            parts.append(f'{mod} {getattr(m, "__version__", "?")}')
        except ImportError:
            parts.append(f'{mod} absent')
    try:
        load = ', '.join(f'{x:.2f}' for x in os.getloadavg())
    except OSError:
        load = '?'
    return f'{os.cpu_count()} CPUs, load average {load}; ' + ', '.join(parts)
