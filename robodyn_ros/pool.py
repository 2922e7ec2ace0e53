"""Where many independent tasks run: a Dask cluster (local processes or a remote scheduler) or
this process, behind one :class:`Pool` (the runs of ``robodyn sweep`` and the ladders of
``robodyn bench precision``).
"""
from __future__ import annotations

import os

__all__ = ['ClusterError', 'Pool', 'CtrlC', 'chunk_size', 'dask_setup']

#: Dask tasks per worker thread a sweep aims at, and the most runs one task carries (a task costs
#: the scheduler, the worker and the client a few ms, more than a tenth of a short run on a busy
#: machine: ``robodyn bench sweep``)
TASKS_PER_THREAD, MAX_CHUNK = 4, 8
#: seconds a sweep on a remote scheduler waits for its first worker
WORKER_WAIT = 60.0
#: seconds after a Ctrl-C that reached this process without becoming a KeyboardInterrupt in the main
#: thread before :class:`CtrlC` raises it there again
CTRL_C_RESEND = 1.0


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


class CtrlC:
    """Ctrl-C for a client that waits on Dask workers: SIGINT becomes a KeyboardInterrupt in the main
    thread, whichever thread the signal reached and wherever the main thread waits.

    Python turns SIGINT into KeyboardInterrupt in the main thread; while a Dask client runs, the
    signal usually lands in one of its other threads (the IO loop, the process watchers), and Python
    passes it on. Once, under load, the sweep's client held in its test hook, sleeping in the main
    thread, never raised it: SIGINT had reached the process (the workers of the same process group
    had it), the main thread went on sleeping, and the sweep did not exit (test_sweep's Ctrl-C test).
    So the signal is also written to a wakeup file (``signal.set_wakeup_fd``: written by the C-level
    handler itself, in whichever thread it runs) that a watcher thread reads: it sets
    :attr:`requested` and, while the main thread has not raised, raises it there again every
    :data:`CTRL_C_RESEND` s (``_thread.interrupt_main``). The caller also checks :attr:`requested`
    where it waits (and after each result), so an interrupt that was raised and swallowed is not
    lost either. Use as a context manager in the main thread; elsewhere, or where SIGINT has a
    handler of its own, it does nothing.
    """

    def __init__(self):
        import threading
        self.requested = threading.Event()
        self.raised = False
        self.active = False

    def __enter__(self):
        import signal
        import socket
        import threading
        if threading.current_thread() is not threading.main_thread() or \
                signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
            return self
        self._r, self._w = socket.socketpair()
        self._r.setblocking(False)
        self._w.setblocking(False)
        self._stop = threading.Event()
        self._old_fd = signal.set_wakeup_fd(self._w.fileno(), warn_on_full_buffer=False)
        signal.signal(signal.SIGINT, self._handler)
        self.active = True
        self._thread = threading.Thread(target=self._watch, name='robodyn Ctrl-C', daemon=True)
        self._thread.start()
        return self

    def _handler(self, signum, frame):
        """The SIGINT handler while active: note it, then raise as Python's default handler does."""
        self.requested.set()
        self.raised = True
        raise KeyboardInterrupt

    def _watch(self):
        """Watcher thread: a SIGINT written to the wakeup file sets :attr:`requested`; until the main
        thread has raised, raise it there again every :data:`CTRL_C_RESEND` s."""
        import _thread
        import select
        import signal
        while not self._stop.is_set():
            if not select.select([self._r], [], [], 0.1)[0]:
                continue
            try:
                data = self._r.recv(256)
            except BlockingIOError:
                continue
            if signal.SIGINT in data:
                self.requested.set()
                while not self.raised and not self._stop.wait(CTRL_C_RESEND):
                    _thread.interrupt_main()

    def check(self):
        """Raise KeyboardInterrupt if a Ctrl-C reached this process (the caller's waits call it)."""
        if self.requested.is_set():
            self.raised = True
            raise KeyboardInterrupt

    def __exit__(self, *exc):
        if self.active:
            import signal
            self._stop.set()
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.set_wakeup_fd(self._old_fd)
            self._thread.join()
            self._r.close()
            self._w.close()
            self.active = False
        return False


def dask_setup(worker):
    """Worker preload of the local cluster: Ctrl-C in a terminal reaches every process of the
    group; the workers ignore it and the client, which keeps the finished rows, shuts them down
    (instead of a KeyboardInterrupt traceback from each worker).

    The scheduler of the local cluster lives in the client's process, so when the client closes it
    (Ctrl-C, or the end of a sweep) a worker's heartbeat already on its way finds the connection
    closed and ``distributed.worker`` logs that with a traceback before the worker's own close
    arrives. Seen once in ten Ctrl-C runs on a loaded machine. That one record is dropped
    (:class:`_ClosedSchedulerHeartbeat`); every other worker log passes."""
    import logging
    import signal
    import threading
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.getLogger('distributed.worker').addFilter(_ClosedSchedulerHeartbeat())


class _ClosedSchedulerHeartbeat:
    """Logging filter: drops the heartbeat failure a local worker logs when the scheduler (in the
    client's process) has closed first; other records pass unchanged."""

    def filter(self, record) -> bool:
        return not str(record.msg).startswith('Failed to communicate with scheduler during heartbeat')


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
