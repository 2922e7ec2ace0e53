"""Small measuring helpers shared by the sweep (:mod:`robodyn_ros.sweep`, a runtime module) and
the benchmarks (:mod:`robodyn_ros.bench`), which may import the runtime but not the reverse:
the final-state error of a run against a reference and the progress bar of long runs.
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np

__all__ = ['state_error', 'Progress']


def state_error(y, y_ref) -> float:
    """Mixed absolute/relative final-state error ``max_i |y_i − y_ref,i| / (1 + |y_ref,i|)``."""
    y, y_ref = np.asarray(y, dtype=float), np.asarray(y_ref, dtype=float)
    if y.shape != y_ref.shape:
        raise ValueError(f'state shapes differ: {y.shape} vs {y_ref.shape}')
    return float(np.max(np.abs(y - y_ref) / (1.0 + np.abs(y_ref)))) if y.size else 0.0


class Progress:
    """Progress bar with rate and ETA on stderr: ``\\r`` updates on a terminal, one line per
    update otherwise (at most every ``interval`` seconds, and at the end); silent if quiet."""

    def __init__(self, total: int, done: int = 0, stream=None, quiet: bool = False, width: int = 30,
                 interval: float = 2.0, label: str = 'sweep'):
        self.total, self.done, self.start_done = max(int(total), 0), int(done), int(done)
        self.stream = stream or sys.stderr
        self.quiet, self.width, self.interval, self.label = quiet, width, interval, label
        self.tty = hasattr(self.stream, 'isatty') and self.stream.isatty()
        self.t0 = time.perf_counter()
        self.last = -math.inf

    def eta(self) -> float:
        """Seconds left at the rate of the runs finished since start (nan before the first)."""
        n = self.done - self.start_done
        if n <= 0:
            return math.nan
        return (time.perf_counter() - self.t0) / n * (self.total - self.done)

    def line(self, text: str = '') -> str:
        """The progress line."""
        frac = self.done / self.total if self.total else 1.0
        bar = '#' * int(round(frac * self.width))
        eta = self.eta()
        eta_s = '--:--' if not math.isfinite(eta) else f'{int(eta) // 60:02d}:{int(eta) % 60:02d}'
        return (f'{self.label} [{bar:<{self.width}}] {self.done}/{self.total} '
                f'{time.perf_counter() - self.t0:6.1f} s, ETA {eta_s} {text}').rstrip()

    def step(self, text: str = ''):
        """Count one finished unit and show the bar."""
        self.done += 1
        if self.quiet:
            return
        now = time.perf_counter()
        if not self.tty and now - self.last < self.interval and self.done < self.total:
            return
        self.last = now
        line = self.line(text)
        if self.tty:
            self.stream.write('\r' + line[:118].ljust(118) + ('\n' if self.done >= self.total else ''))
        else:
            self.stream.write(line + '\n')
        self.stream.flush()
