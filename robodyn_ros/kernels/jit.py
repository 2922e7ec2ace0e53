"""``njit`` of every kernel, and what a kernel does on a cold cache.

Without numba, ``njit`` returns the function unchanged: the same source runs as plain Python (slower, the
same operations). Used by every kernel module; the tree algorithms (:mod:`.tree`), the PFL law
(:mod:`.pfl`), the command profiles (:mod:`.profiles`) and the recorder's loops (:mod:`.records`) run
that way when numba is missing (``ROBODYN_BACKEND=numpy`` turns the compiled systems off; these stay
compiled while numba is installed).

With numba, ``njit`` is numba's, and the dispatcher it makes (:class:`KernelDispatcher`) decides what a
call from Python does when no machine code for its argument types is in memory (:data:`MODE`):

* ``'compile'`` (numba's way, the default): load it from the kernels' cache, else compile it now;
* ``'interpret'`` (``robodyn run`` and the sim node): load it from the cache if it is there; else run the
  kernel's Python source in the interpreter (:func:`python_kernel`: every kernel it calls as Python too)
  and have a child process compile it (:class:`_Compiler`), whose machine code the next call loads. The
  interpreter does the same IEEE double operations in the same order (Python floats and numpy scalars
  are doubles, ``math`` is the same C library, numba contracts no multiply-add), so a run's bytes do not
  depend on which calls were interpreted (every bundled scene is recorded both ways in
  ``test/test_cold_start.py``). Where Python raises and compiled code would return inf or nan
  (a division by zero, ``math.sqrt`` of a negative: only on a failing state), the call's arrays are put
  back and it is compiled and run at once. A first run on an empty cache thus starts in about a second
  instead of compiling for a minute; the child keeps compiling when the run ends before it (its cache
  serves the next run) and stops when it has done what was asked;
* ``'python'`` (tests): interpret every miss, load and compile nothing.
"""
from __future__ import annotations

import os
import sys
import types

try:
    from numba import njit as _numba_njit
    NUMBA = True
except ImportError:   # no numba: the kernels below run as Python functions
    NUMBA = False

#: what a kernel called from Python with new argument types does when their machine code is not in memory:
#: 'compile', 'interpret' or 'python' (module docstring); ``$ROBODYN_COLD_START`` sets it for a process,
#: :func:`set_mode` for the tools
MODE = os.environ.get('ROBODYN_COLD_START', 'compile')
MODES = ('compile', 'interpret', 'python')
#: names every interpreted kernel namespace gets (the intrinsics of :mod:`.treefn` as Python functions)
PY_OVERRIDES: dict = {}


def set_mode(mode: str) -> None:
    """Set :data:`MODE` ('compile' or 'interpret') for this process, unless ``$ROBODYN_COLD_START`` chose."""
    global MODE
    if mode not in MODES:
        raise ValueError(f'cold-start mode must be one of {", ".join(MODES)}, got {mode!r}')
    if not os.environ.get('ROBODYN_COLD_START'):
        MODE = mode


def python_kernel(func, math_module=None, overrides=None):
    """``func`` (a kernel, or a kernel module's plain Python function) as Python: every compiled kernel it
    reaches replaced by its Python source, ``math`` by ``math_module`` (symbols: :mod:`.codegen`), the names
    of :data:`PY_OVERRIDES` and ``overrides`` by their values. The same operations as the compiled code, run
    by the interpreter."""
    import math
    from numba.core.dispatcher import Dispatcher
    spaces: dict = {}
    extra = {**PY_OVERRIDES, **(overrides or {})}

    def space(module_name):
        ns = spaces.get(module_name)
        if ns is None:
            ns = spaces[module_name] = dict(vars(sys.modules[module_name]))
            ns['math'] = math if math_module is None else math_module
            ns.update(extra)
            for name, obj in list(ns.items()):
                if isinstance(obj, Dispatcher):
                    ns[name] = rebound(obj.py_func)
        return ns

    def rebound(py):
        return types.FunctionType(py.__code__, space(py.__module__), py.__name__, py.__defaults__, py.__closure__)

    return rebound(getattr(func, 'py_func', func))


def njit(*args, **kw):
    """``@njit(...)`` / ``@njit``: numba's, making a :class:`KernelDispatcher`; without numba the function itself."""
    if not NUMBA:
        if len(args) == 1 and callable(args[0]):
            return args[0]
        return lambda f: f
    if len(args) == 1 and callable(args[0]) and not kw:
        return _adopt(_numba_njit(args[0]))
    return lambda f: _adopt(_numba_njit(*args, **kw)(f))


_KD = None


def _adopt(d):
    """d, of class :class:`KernelDispatcher` (numba's dispatcher with the cold-start rule of :data:`MODE`)."""
    global _KD
    if _KD is None:
        _KD = _kernel_dispatcher_class(type(d))
        globals()['KernelDispatcher'] = _KD
    d.__class__ = _KD
    return d


def _kernel_dispatcher_class(base):
    class KernelDispatcher(base):
        """numba's CPU dispatcher; on a miss from Python under MODE 'interpret', interprets (module docstring)."""

        def _compile_for_args(self, *args, **kws):
            if MODE == 'compile' or kws:
                return super()._compile_for_args(*args, **kws)
            from numba.core.dispatcher import OmittedArg
            if any(isinstance(a, OmittedArg) for a in args):
                return super()._compile_for_args(*args, **kws)
            sig = tuple(self.typeof_pyval(a) for a in args)
            if MODE == 'python':
                return lambda *a: run_interpreted(self, sig, a)
            entry = load_cached(self, sig)
            if entry is not None:
                return entry
            COMPILER.request(('kernel', self.py_func.__module__, self.py_func.__name__, sig))
            return lambda *a: run_interpreted(self, sig, a)

        def __reduce__(self):   # pickled (Dask) as numba's own class
            red = super().__reduce__()
            return (red[0], (base,) + tuple(red[1][1:])) if red[1] and red[1][0] is type(self) else red
    return KernelDispatcher


#: ``{(id(dispatcher), signature): generation}`` of cache lookups that found nothing (retried when the
#: compiler child has finished something since)
_MISSES: dict = {}


def load_cached(d, sig):
    """The entry point of kernel d for the argument types sig: in memory, or loaded from the kernels' cache
    (numba's ``Dispatcher.compile`` without its compiling part); None if neither."""
    existing = d.overloads.get(sig)
    if existing is not None:
        return existing.entry_point
    COMPILER.poll()
    key = (id(d), sig)
    if _MISSES.get(key) == COMPILER.generation:
        return None
    from numba.core.compiler_lock import global_compiler_lock
    with global_compiler_lock:
        cres = d._cache.load_overload(sig, d.targetctx)
        if cres is None:
            _MISSES[key] = COMPILER.generation
            return None
        d._cache_hits[sig] += 1
        if not cres.objectmode:
            d.targetctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
        d.add_overload(cres)
        return cres.entry_point


def request_compiled(d, args) -> None:
    """Have the compiler child compile kernel d for the types of args, unless it is in memory or the cache."""
    if MODE != 'interpret':
        return
    sig = tuple(d.typeof_pyval(a) for a in args)
    if load_cached(d, sig) is None:
        COMPILER.request(('kernel', d.py_func.__module__, d.py_func.__name__, sig))


def interpreted(d):
    """Kernel d as Python (:func:`python_kernel`), made once."""
    py = getattr(d, '_robodyn_python', None)
    if py is None:
        py = d._robodyn_python = python_kernel(d)
    return py


def _arrays(x, out):
    """Every numpy array in x (nested tuples)."""
    import numpy as np
    if isinstance(x, np.ndarray):
        out.append(x)
    elif isinstance(x, tuple):
        for y in x:
            _arrays(y, out)
    return out


def run_interpreted(d, sig, args, fallback=None):
    """Kernel d's Python source on args; where Python raises (ArithmeticError, ValueError) and compiled
    code would return inf or nan, the arrays are put back and the kernel is compiled and run now (or
    ``fallback()`` is returned)."""
    import numpy as np
    arrays = _arrays(tuple(args), [])
    saved = [a.copy() for a in arrays]
    try:
        with np.errstate(all='ignore'):
            return interpreted(d)(*args)
    except (ArithmeticError, ValueError):
        for a, s in zip(arrays, saved):
            a[...] = s
        if fallback is not None:
            return fallback()
        d.compile(sig)
        return d(*args)


class _Compiler:
    """The child process that compiles what interpreted calls asked for (``python -m robodyn_ros.kernels.jit``):
    requests go in on its stdin (one per line), a line per finished request comes back; :attr:`generation`
    counts them. The child is started at the first request; when this process ends it finishes what it was
    given and exits."""

    def __init__(self):
        self.proc = None
        self.sent = set()
        self.generation = 0
        self.done: set = set()

    def request(self, what) -> None:
        """Have the child compile ``what``: ``('kernel', module, function, signature)``, ``('call', module,
        function, *args)`` (a function that compiles, e.g. the cfuncs of :mod:`.treefn`, or a model's generated
        module: ``codegen.load(path)``). The child names no module itself, so this room imports none of them."""
        import base64
        import pickle
        if what in self.sent:
            return
        self.sent.add(what)
        if self.proc is None:
            import subprocess
            env = dict(os.environ, ROBODYN_COLD_START='compile')
            root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
            env['PYTHONPATH'] = root + (os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
            self.proc = subprocess.Popen([sys.executable, '-m', 'robodyn_ros.kernels.jit'], env=env,
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
            os.set_blocking(self.proc.stdout.fileno(), False)
            self._buf = b''
        try:
            self.proc.stdin.write(base64.b64encode(pickle.dumps(what)) + b'\n')
            self.proc.stdin.flush()
        except OSError:   # the child is gone: these calls stay interpreted
            pass

    def poll(self) -> None:
        """Read what the child has finished since the last look (no wait)."""
        if self.proc is None:
            return
        try:
            chunk = self.proc.stdout.read()
        except OSError:
            chunk = None
        if not chunk:
            return
        self._buf += chunk
        *lines, self._buf = self._buf.split(b'\n')
        for line in lines:
            self.done.add(line)
            self.generation += 1

    def wait(self) -> None:
        """Close the child's input and wait until it has compiled everything asked (tests, ``robodyn warm``)."""
        if self.proc is not None:
            self.proc.stdin.close()
            self.proc.wait()
            os.set_blocking(self.proc.stdout.fileno(), True)
            rest = self.proc.stdout.read()
            self._buf += rest or b''
            self.generation += 1
            self.proc = None


#: this process's compiler child
COMPILER = _Compiler()


def main() -> int:
    """The compiler child: compile each request read from stdin, print its line when done."""
    import base64
    import importlib
    import pickle
    from . import AVAILABLE
    if not AVAILABLE:
        return 1
    for line in sys.stdin.buffer:
        what = pickle.loads(base64.b64decode(line.strip()))
        try:
            if what[0] == 'kernel':
                getattr(importlib.import_module(what[1]), what[2]).compile(what[3])
            elif what[0] == 'call':
                getattr(importlib.import_module(what[1]), what[2])(*what[3:])
            status = b'done'
        except Exception as e:   # reported, and the parent keeps interpreting that call
            status = f'failed {type(e).__name__}'.encode()
        try:
            sys.stdout.buffer.write(status + b' ' + line.strip()[:40] + b'\n')
            sys.stdout.buffer.flush()
        except OSError:   # the parent has exited: keep compiling for the next run's cache
            pass
    return 0


__all__ = ['njit', 'NUMBA', 'MODE', 'set_mode', 'python_kernel']

if __name__ == '__main__':
    sys.exit(main())
