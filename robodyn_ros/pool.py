"""Where many independent tasks run: a Dask cluster (local processes or a remote scheduler) or
this process, behind one :class:`Pool` (the runs of ``robodyn sweep`` and the ladders of
``robodyn bench precision``).
"""
from __future__ import annotations

import os

__all__ = ['ClusterError', 'Pool', 'chunk_size', 'dask_setup']

#: Dask tasks per worker thread a sweep aims at, and the most runs one task carries (a task costs
#: the scheduler, the worker and the client a few ms, more than a tenth of a short run on a busy
#: machine: ``robodyn bench sweep``)
TASKS_PER_THREAD, MAX_CHUNK = 4, 8
#: seconds a sweep on a remote scheduler waits for its first worker
WORKER_WAIT = 60.0


class ClusterError(RuntimeError):
    """The Dask cluster cannot run the sweep (unreachable scheduler, no worker, another version)."""


def _version() -> str:
    from .version import __version__
    return __version__


class Pool:
    """Where tasks run: a Dask ``LocalCluster`` of ``workers`` processes (one thread each), a
    remote scheduler (``scheduler='tcp://host:8786'``), or this process (``workers=0``).

    Use as a context manager; :meth:`run` yields ``(key, result)`` as tasks finish.
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None, check_version: bool = True):
        self.workers = (os.cpu_count() or 1) if workers is None else int(workers)
        if self.workers < 0:
            raise ValueError(f'workers must be >= 0, got {workers}')
        self.scheduler = scheduler
        self.check_version = check_version
        self.client = self.cluster = None

    @property
    def inline(self) -> bool:
        """True when tasks run in this process (no Dask)."""
        return self.scheduler is None and self.workers == 0

    def __enter__(self):
        if self.inline:
            return self
        import logging

        from dask.distributed import Client, LocalCluster
        if self.scheduler:
            try:
                self.client = Client(self.scheduler, timeout='30s')
            except OSError as e:
                raise ClusterError(f'cannot reach the Dask scheduler {self.scheduler}: {e}') from None
            try:
                self.client.wait_for_workers(1, timeout=WORKER_WAIT)
            except TimeoutError:
                self.client.close()
                raise ClusterError(f'no Dask worker has joined the scheduler {self.scheduler} within {WORKER_WAIT:g} s '
                                   f'(start some: dask worker {self.scheduler} --nthreads 1)') from None
        else:
            # preload: dask_setup below runs in every worker process (restarted ones too)
            self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=logging.ERROR,
                                        preload=[__name__])
            self.client = Client(self.cluster)
        if self.check_version:
            self._check_versions()
        return self

    def _check_versions(self):
        seen = self.client.run(_version)
        bad = {w: v for w, v in seen.items() if v != _version()}
        if bad:
            self.__exit__(None, None, None)
            raise ClusterError(f'Dask workers run another robodyn_ros version than this client ({_version()}): '
                               + ', '.join(f'{w}: {v}' for w, v in sorted(bad.items()))
                               + '; install the same version on every worker')

    def __exit__(self, *exc):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None
        return False

    def threads(self) -> int:
        """Worker threads that run tasks now (1 in process)."""
        if self.inline:
            return 1
        return max(1, sum(w.get('nthreads', 1) for w in self.client.scheduler_info()['workers'].values()))

    def run(self, fn, items, name='task', chunk: int = 1):
        """Run ``fn(arg)`` for every ``(key, arg)`` of ``items``; yield ``(key, result)`` as each
        finishes (an exception inside fn is returned as ``{'error': ...}``, see :func:`_run_guarded`).

        chunk: items per Dask task (consecutive items; their results arrive together), so that
        the scheduling cost of a task is shared by several short runs. Dask reruns the task of a
        worker that died (fn must be idempotent); the caller keeps the first result of each key.
        """
        items = list(items)
        if self.inline:
            for key, arg in items:
                yield key, _run_guarded(fn, arg)
            return
        from dask.distributed import as_completed
        token = os.urandom(4).hex()
        chunk = max(1, int(chunk))
        futures = {}
        for k in range(0, len(items), chunk):
            batch = items[k:k + chunk]
            fut = self.client.submit(_run_batch, fn, [arg for _, arg in batch], key=f'{name}-{batch[0][0]}-{token}',
                                     pure=False)
            futures[fut] = [key for key, _ in batch]
        try:
            for fut in as_completed(futures):
                keys = futures[fut]
                try:
                    results = fut.result()
                except Exception as e:  # noqa: BLE001 — a task lost beyond Dask's retries (KilledWorker): rows say so
                    results = [{'error': f'{type(e).__name__}: {e}'}] * len(keys)
                yield from zip(keys, results)
                fut.release()
        finally:
            for fut in futures:
                if not fut.done():
                    fut.cancel()


def dask_setup(worker):
    """Worker preload of the local cluster: Ctrl-C in a terminal reaches every process of the
    group; the workers ignore it and the client, which keeps the finished rows, shuts them down
    (instead of a KeyboardInterrupt traceback from each worker)."""
    import signal
    import threading
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_batch(fn, args) -> list:
    """One Dask task: ``fn`` over several arguments, guarded one by one."""
    return [_run_guarded(fn, a) for a in args]


def chunk_size(runs: int, threads: int) -> int:
    """Runs per Dask task: about ``TASKS_PER_THREAD`` tasks per worker thread (load balance), at
    most ``MAX_CHUNK`` runs each (a lost task is rerun whole, and rows arrive a task at a time)."""
    return max(1, min(MAX_CHUNK, runs // (TASKS_PER_THREAD * max(1, threads))))


def _run_guarded(fn, task):
    """``fn(task)``; an exception becomes ``{'error': 'Type: message'}`` so one broken run does not
    stop a sweep (the caller turns it into a row with status 'error')."""
    try:
        return fn(task)
    except Exception as e:  # noqa: BLE001 — recorded in the row, with its type; the sweep goes on
        import traceback
        where = traceback.extract_tb(e.__traceback__)[-1]
        return {'error': f'{type(e).__name__}: {e} (at {os.path.basename(where.filename)}:{where.lineno})'}
