"""numba's on-disk cache of the kernels: where it lives, when it is stale, what a process compiled.

Every kernel is ``@njit(cache=True)``: the first start of an install compiles each function for
the argument types it meets and writes the machine code to disk; later starts load it (about
10 ms a function against 0.1-2 s to compile it). ``robodyn warm`` (run once by ``make run``)
fills the cache for every function the bundled scenes and URDF robots use, and the types those
functions take do not depend on the robot (a model is packed into arrays of fixed dtype and
rank), so a robot never seen before loads the same machine code.

**Where.** In the user's cache, ``$XDG_CACHE_HOME/robodyn_ros/numba`` (``~/.cache/robodyn_ros/numba``),
in a directory named after :data:`FINGERPRINT` (``kernels-<16 hex digits>``): every install, venv,
clone or ``colcon build`` of the same kernel sources on this machine shares one compilation, and
installs of other sources keep theirs side by side (the :data:`KEEP` most recently used are kept,
older ones are removed when a new one is made). ``$NUMBA_CACHE_DIR``, when set, takes the place of
``~/.cache/robodyn_ros/numba`` (a benchmark measuring a fresh install points it at an empty
directory); when neither is writable, the package's ``robodyn_ros/kernels/__pycache__`` does. The
machine code of another CPU or another numba is a miss, not an error: numba keys every entry on
both. Only the kernels' functions are located here: other numba users in the same process keep
numba's own rules.

**When it is stale.** numba keys a cached function on the source file it is defined in; a kernel
inlines functions and constants from other kernel modules (``arm.integrate_arm`` calls
``tree.aba_ws``), so an edit of ``tree.py`` alone would leave ``arm.py``'s cached code running
the old ``tree.py``. Here every kernel's freshness stamp is :data:`FINGERPRINT`, a hash of the
source of every module of this package that defines compiled functions, of the joint-type
codes the kernels take from :mod:`robodyn_ros.model` and of the step controller's constants they take from
:mod:`robodyn_ros.integrators`: any edit of a kernel module invalidates
every kernel at once, and the next start compiles them again (numba then replaces the stale
index entries; nothing accumulates). The generated
modules of :mod:`.codegen` (which import ``arm.py``'s forces and the kernels' constants) are
stamped with the fingerprint and their own text.

**Several processes at once.** numba's index of a function (``name.nbi``: signature -> data file)
is read, extended and rewritten by whichever process compiles a new signature. Two processes that
compile different signatures of one function at the same moment (``robodyn warm --jobs 2``, a test
suite starting nodes and CLI children on an empty cache) could both take the same data file name,
and one index would then name the other's machine code. Here every read and write of the kernels'
index and data files holds a lock on the cache directory (:class:`_LockedCacheFile`: exclusive to
write, shared to read), so each entry names its own code.

**What a process compiled.** :func:`compiled_here` lists the kernels this process compiled
rather than loaded: empty after ``robodyn warm`` for any bundled scene or URDF robot (tested).
"""
from __future__ import annotations

import contextlib
import functools
import glob
import hashlib
import os
import re
import sys
import time

#: the directory of the kernel modules
HERE = os.path.dirname(os.path.abspath(__file__))
#: module-name prefixes of the functions whose cache this module locates: the kernels and the
#: generated modules of :mod:`.codegen`
PREFIXES = ('robodyn_ros.kernels.', 'robodyn_gen_')


#: a line that defines a compiled function: what makes a module part of the fingerprint (with
#: ``jit.py``, the decorator they use; not this module, the package's Python side or the code
#: generator, whose generated modules are stamped on their own)
_KERNEL = re.compile(rb'^@(njit|intrinsic)\b', re.MULTILINE)


def _fingerprint(directory: str = HERE) -> str:
    """sha256 of the source of every module in ``directory`` (the kernels) and of the joint-type
    codes and step-controller constants the kernels compile in."""
    from ..integrators import GROW_MAX, H_MIN, SAFETY, SHRINK_MAX
    from ..model import FIXED, FREE, PRISMATIC, REVOLUTE, SPHERICAL
    h = hashlib.sha256(repr((FIXED, FREE, PRISMATIC, REVOLUTE, SPHERICAL)).encode())
    h.update(repr((SAFETY, GROW_MAX, SHRINK_MAX, H_MIN)).encode())   # rosenbrock2's controller (kernels/arm.py)
    for path in sorted(glob.glob(os.path.join(directory, '*.py'))):
        with open(path, 'rb') as f:
            text = f.read()
        name = os.path.basename(path)
        if name == 'jit.py' or (_KERNEL.search(text) and name != 'codegen.py'):   # codegen's are templates
            h.update(os.path.basename(path).encode() + b'\0' + text)
    return h.hexdigest()


#: freshness stamp of every cached kernel (see the module docstring)
FINGERPRINT = _fingerprint()


#: kernel cache directories (one per FINGERPRINT) kept in a cache root: the most recently used
KEEP = 4


def user_cache_dir() -> str:
    """``$XDG_CACHE_HOME/robodyn_ros/numba`` (default ``~/.cache/robodyn_ros/numba``)."""
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return os.path.join(base, 'robodyn_ros', 'numba')


def _can_write(path: str) -> bool:
    """True when ``path`` is a writable directory, or could be made (its nearest existing parent is one)."""
    while not os.path.isdir(path):
        parent = os.path.dirname(path)
        if parent == path:
            return False
        path = parent
    return os.access(path, os.W_OK)


def cache_root() -> str:
    """The directory the kernels' cache directories go in (see "Where" in the module docstring)."""
    env = os.environ.get('NUMBA_CACHE_DIR')
    if env:
        return env
    user = user_cache_dir()
    return user if _can_write(user) else os.path.join(HERE, '__pycache__')


def kernel_cache_dir() -> str:
    """The cache directory of the kernels of these sources: ``kernels-<FINGERPRINT[:16]>`` in :func:`cache_root`."""
    return os.path.join(cache_root(), 'kernels-' + FINGERPRINT[:16])


def holds_no_kernel(directory: str | None = None) -> bool:
    """True when the kernel cache directory (default :func:`kernel_cache_dir`) holds no compiled kernel: none
    was compiled for these sources here yet (a new install, an edit of the kernels, an empty ``NUMBA_CACHE_DIR``).
    One directory listing, without numba."""
    try:
        return not any(name.endswith('.nbi') for name in os.listdir(directory or kernel_cache_dir()))
    except OSError:   # (not there yet)
        return True


@functools.lru_cache(maxsize=None)
def _writable(path: str) -> bool:
    """Create ``path`` if needed; True when a file can be written there (checked once per directory).
    A kernel cache directory is marked as used now (its time), and making a new one removes the
    least recently used beyond :data:`KEEP` beside it."""
    import tempfile
    try:
        new = not os.path.isdir(path)
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    if os.path.basename(path).startswith('kernels-'):
        try:
            os.utime(path)
        except OSError:
            pass
        if new:
            prune(os.path.dirname(path))
    return True


def prune(root: str, keep: int = KEEP) -> list:
    """Remove the kernel cache directories of ``root`` beyond the ``keep`` most recently used
    (by their time, which :func:`_writable` sets when a process uses one); the removed ones."""
    import shutil
    try:
        dirs = [(os.stat(os.path.join(root, n)).st_mtime, n) for n in os.listdir(root)
                if n.startswith('kernels-') and os.path.isdir(os.path.join(root, n))]
    except OSError:
        return []
    removed = []
    for _, name in sorted(dirs, reverse=True)[keep:]:
        shutil.rmtree(os.path.join(root, name), ignore_errors=True)
        removed.append(name)
    return removed


def _cache_path(py_file: str) -> str:
    """Cache directory of the functions of ``py_file``: :func:`kernel_cache_dir` for the kernel
    modules; for a generated module, ``__pycache__`` beside it when writable and no
    ``$NUMBA_CACHE_DIR`` is set, else a per-source-directory subdirectory of :func:`cache_root`."""
    from numba.core.caching import _CacheLocator
    src_dir = os.path.dirname(os.path.abspath(py_file))
    if src_dir == HERE:
        return kernel_cache_dir()
    pycache = os.path.join(src_dir, '__pycache__')
    if not os.environ.get('NUMBA_CACHE_DIR') and os.access(pycache if os.path.isdir(pycache) else src_dir,
                                                            os.W_OK):
        return pycache
    return os.path.join(cache_root(), _CacheLocator.get_suitable_cache_subpath(py_file))


@functools.lru_cache(maxsize=None)
def _generated_stamp(py_file: str) -> str:
    with open(py_file, 'rb') as f:
        return hashlib.sha256(FINGERPRINT.encode() + f.read()).hexdigest()


#: directories :func:`_cache_path` gave the kernels (their cache files are locked, see the docstring)
_OURS: set = set()


@contextlib.contextmanager
def file_lock(lock_path: str, exclusive: bool = True, waits=None):
    """Hold an ``flock`` on the file lock_path (created if missing) while the block runs: exclusive to write,
    shared to read. waits: a list to which ``(lock_path, seconds waited)`` is appended when another process held
    it. Opening the file may raise OSError (a directory removed or not writable): the caller decides what no
    lock means. The kernel releases the lock of a process that dies."""
    try:
        import fcntl
    except ImportError:   # no flock (Windows): one process at a time is the user's to keep
        yield
        return
    mode = fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH
    with open(lock_path, 'a+b') as f:
        try:
            fcntl.flock(f, mode | fcntl.LOCK_NB)
        except OSError:   # held by another process: wait for it
            t0 = time.monotonic()
            fcntl.flock(f, mode)
            if waits is not None:
                waits.append((lock_path, time.monotonic() - t0))
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _dir_lock(path: str, exclusive: bool):
    """Hold ``path/.lock`` (:func:`file_lock`) while the block runs: exclusive to write, shared to read."""
    return file_lock(os.path.join(path, '.lock'), exclusive)


def _locked_cache_file():
    """numba's ``IndexDataCacheFile`` whose save and load hold :func:`_dir_lock` in the kernels' own
    cache directories (other numba users' caches behave as numba's)."""
    from numba.core.caching import IndexDataCacheFile

    class _LockedCacheFile(IndexDataCacheFile):
        """Index and data files read and written under the cache directory's lock."""

        ROBODYN = True

        def save(self, key, data):
            if self._cache_path not in _OURS:
                return super().save(key, data)
            try:
                with _dir_lock(self._cache_path, True):
                    return super().save(key, data)
            except FileNotFoundError:   # the directory was pruned (prune) under a long run: not kept
                return None

        def load(self, key):
            if self._cache_path not in _OURS:
                return super().load(key)
            try:
                with _dir_lock(self._cache_path, False):
                    return super().load(key)
            except FileNotFoundError:   # (pruned): a miss
                return None

    return _LockedCacheFile


def install() -> None:
    """Put the kernels' cache locator first in numba's list and lock their cache files (once;
    before any kernel is defined)."""
    from numba.core import caching
    from numba.core.caching import CacheImpl, _CacheLocator

    if any(getattr(c, 'ROBODYN', False) for c in CacheImpl._locator_classes):
        return
    if not getattr(caching.IndexDataCacheFile, 'ROBODYN', False):
        caching.IndexDataCacheFile = _locked_cache_file()   # read by numba's _Cache at each function

    class KernelCacheLocator(_CacheLocator):
        """numba cache locator of the kernels and generated modules: :func:`_cache_path`, stamped
        with :data:`FINGERPRINT` (generated modules: with their text too)."""

        ROBODYN = True

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._generated = py_func.__module__.startswith('robodyn_gen_')
            self._path = _cache_path(py_file)

        def ensure_cache_path(self):
            if not _writable(self._path):
                raise OSError(f'cannot write the kernel cache to {self._path}')

        def get_cache_path(self):
            return self._path

        def get_source_stamp(self):
            return _generated_stamp(self._py_file) if self._generated else FINGERPRINT

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            if not py_func.__module__.startswith(PREFIXES) or not os.path.exists(py_file):
                return None
            self = cls(py_func, py_file)
            if not _writable(self._path):
                return None   # numba's own locators decide
            _OURS.add(self._path)
            return self

    CacheImpl._locator_classes.insert(0, KernelCacheLocator)


def dispatchers():
    """``{'module.function': dispatcher}`` of every compiled kernel imported in this process."""
    from numba.core.dispatcher import Dispatcher
    out = {}
    for name, mod in list(sys.modules.items()):
        if mod is None or not (name.startswith(PREFIXES) or name == 'robodyn_ros.kernels'):
            continue
        for attr, obj in list(vars(mod).items()):
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name:
                out[f'{name}.{attr}'] = obj
    return out


def compiled_here() -> list:
    """``'module.function(argument types)'`` of every kernel this process compiled instead of
    loading it from the cache (a function compiled for two signatures is listed twice)."""
    return sorted(f'{name}{tuple(str(t) for t in sig)}' for name, d in dispatchers().items()
                  for sig in d.stats.cache_misses)


def loaded_here() -> list:
    """``'module.function'`` of every kernel this process loaded from the cache."""
    return sorted(name for name, d in dispatchers().items() for _ in d.stats.cache_hits)
