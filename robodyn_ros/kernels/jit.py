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
  kernel's Python source in the interpreter (:func:`python_kernel`), and have a child process compile it
  (:class:`_Compiler`), whose machine code the next call loads. The interpreted kernel calls the machine code of
  each kernel it calls once that is in memory or in the cache (:class:`_Hybrid`: after the first, through numba's
  dispatcher, which types the arguments in C), else its Python source, and
  asks the child for it after the call: the child gets the callees before the callers that contain them, those
  an interpreted kernel calls before those Python calls (:class:`_Requests`), so a long first run speeds up as
  the child compiles its loop's pieces, instead of staying interpreted until the whole loop is compiled. The
  interpreter does the same IEEE double operations in the same order (Python floats and numpy scalars
  are doubles, ``math`` is the same C library, numba contracts no multiply-add), so a run's bytes do not
  depend on which calls were interpreted (every bundled scene is recorded both ways in
  ``test/test_cold_start.py``). Where Python raises and compiled code would return inf or nan
  (a division by zero, ``math.sqrt`` of a negative: only on a failing state), the call's arrays are put
  back and it is compiled and run at once. A first run on an empty cache thus starts in about a second
  instead of compiling for a minute; the child keeps compiling when the run ends before it (its cache
  serves the next run) and stops when it has done what was asked;
* ``'python'`` (tests): interpret every miss, load and compile nothing.

Deferred (:data:`DEFERRED`: ``robodyn run``). Importing numba and loading its first cached function costs
about 0.65 s, more than a short run's whole simulation. ``robodyn run`` imports the kernels without numba:
each is a :class:`Deferred` that runs its Python source (as above, the same bytes) and counts the time;
when that passes :data:`INTERPRET_BUDGET`, or the run says it will (:func:`expect`, from its steps and
bodies), :func:`load_numba` imports numba and puts numba's dispatcher of every kernel where the Deferred
one was, between two calls from Python. A 10 ms run thus ends in under half a second, and a long run
loads numba before its first step.
"""
from __future__ import annotations

import importlib.util
import os
import sys
import threading
import time
import types

#: numba is installed (the kernels compile); whether it is loaded yet: :data:`LOADED`
NUMBA = importlib.util.find_spec('numba') is not None
#: ``robodyn run`` imports the kernels with ``$_ROBODYN_DEFER_NUMBA`` set: numba stays unloaded, the kernels run
#: as Python, until the run's interpreted time passes :data:`INTERPRET_BUDGET` (or it is expected to): the
#: deferred tier (:class:`Deferred`, :func:`load_numba`). Any other process loads numba with the kernels.
DEFERRED = NUMBA and os.environ.get('_ROBODYN_DEFER_NUMBA') == '1'
#: numba is imported and every kernel is numba's dispatcher
LOADED = False
#: seconds of interpreted kernel time after which a deferred process loads numba (about a third of what loading
#: it and the cached machine code costs: a run that ends sooner is done before numba would have loaded);
#: ``$ROBODYN_INTERPRET_BUDGET`` sets it (tests)
INTERPRET_BUDGET = float(os.environ.get('ROBODYN_INTERPRET_BUDGET', '0.25'))
#: seconds the deferred kernels have run interpreted so far
SPENT = [0.0]
if NUMBA and not DEFERRED:
    try:
        from numba import njit as _numba_njit
        LOADED = True
    except ImportError:   # installed but broken: the kernels run as Python functions
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


def _is_kernel(obj) -> bool:
    """obj is a kernel: a :class:`Deferred` one, or numba's dispatcher once numba is loaded."""
    if isinstance(obj, Deferred):
        return True
    if not LOADED:
        return False
    from numba.core.dispatcher import Dispatcher
    return isinstance(obj, Dispatcher)


def python_kernel(func, math_module=None, overrides=None):
    """``func`` (a kernel, or a kernel module's plain Python function) as Python: every compiled kernel it
    reaches replaced by its Python source, ``math`` by ``math_module`` (symbols: :mod:`.codegen`), the names
    of :data:`PY_OVERRIDES` and ``overrides`` by their values. The same operations as the compiled code, run
    by the interpreter."""
    import math
    spaces: dict = {}
    extra = {**PY_OVERRIDES, **(overrides or {})}

    def space(module_name):
        ns = spaces.get(module_name)
        if ns is None:
            ns = spaces[module_name] = dict(vars(sys.modules[module_name]))
            ns['math'] = math if math_module is None else math_module
            for name, obj in list(ns.items()):
                if _is_kernel(obj) and name not in extra:
                    py = rebound(obj.py_func)
                    ns[name] = py if math_module is not None else _Hybrid(obj, py)
            ns.update(extra)
        return ns

    def rebound(py):
        return types.FunctionType(py.__code__, space(py.__module__), py.__name__, py.__defaults__, py.__closure__)

    return rebound(getattr(func, 'py_func', func))


def njit(*args, **kw):
    """``@njit(...)`` / ``@njit``: numba's, making a :class:`KernelDispatcher`; in a deferred process a
    :class:`Deferred` kernel (numba's once :func:`load_numba` ran); without numba the function itself."""
    if not NUMBA:
        if len(args) == 1 and callable(args[0]):
            return args[0]
        return lambda f: f
    if len(args) == 1 and callable(args[0]) and not kw:
        return _make(args[0], (), {})
    return lambda f: _make(f, args, kw)


def _make(f, args, kw):
    """The kernel of function f with numba options ``args, kw``: numba's dispatcher when numba is loaded."""
    if LOADED:
        return _adopt(_numba_njit(*args, **kw)(f))
    return Deferred(f, lambda: _adopt(_numba_njit(*args, **kw)(f)))


class Deferred:
    """A kernel, or another numba object a kernel module defines (an intrinsic), in a process that has not
    loaded numba yet (:data:`DEFERRED`). Called from Python it runs its function's Python source
    (:func:`run_interpreted`: the operations of the compiled code) and counts the time in :data:`SPENT`; past
    :data:`INTERPRET_BUDGET`, or when anything asks for numba's object (an attribute other than ``py_func``),
    it loads numba (:func:`load_numba`), which replaces every Deferred in the kernel modules' namespaces by
    the real object (:attr:`real`), and it forwards to that from then on."""

    __slots__ = ('py_func', '_make', 'real', '_robodyn_python', '__weakref__')

    def __init__(self, py_func, make):
        self.py_func = py_func
        self._make = make
        self.real = None
        self._robodyn_python = None
        _DEFERRED.append(self)

    def __call__(self, *args):
        if self.real is None and SPENT[0] >= INTERPRET_BUDGET:
            load_numba()
        if self.real is not None:
            return self.real(*args)
        t0 = time.perf_counter()
        try:
            return run_interpreted(self, None, args, fallback=lambda: _loaded(self)(*args))
        finally:
            SPENT[0] += time.perf_counter() - t0

    def __getattr__(self, name):   # numba's dispatcher attributes (compile, overloads, address, ...)
        return getattr(_loaded(self), name)

    def __repr__(self):
        return f'<deferred kernel {self.py_func.__module__}.{self.py_func.__qualname__}>'


#: every :class:`Deferred` made in this process (made real by :func:`load_numba`)
_DEFERRED: list = []
#: functions :func:`load_numba` calls after numba is imported, before any kernel is made (:mod:`.cache`'s install)
_BEFORE_LOAD: list = []


def _loaded(d):
    """Deferred d's real object (numba loaded first)."""
    load_numba()
    return d.real


def load_numba() -> None:
    """Load numba in a deferred process: make every :class:`Deferred` real and put the real objects where the
    Deferred ones were (the globals of every robodyn_ros module, and the tuples and dicts among them), so
    compiled code finds numba's objects. Once; nothing to do in a process that loaded numba at start."""
    global LOADED, _numba_njit
    if LOADED or not NUMBA:
        return
    from numba import njit as _numba_njit
    LOADED = True
    for f in _BEFORE_LOAD:
        f()
    for d in list(_DEFERRED):
        if d.real is None:
            d.real = d._make()
    for name, mod in list(sys.modules.items()):
        if mod is None or not (name.startswith('robodyn_ros') or name.startswith('robodyn_gen_')):
            continue
        ns = vars(mod)
        for key, obj in list(ns.items()):
            if isinstance(obj, Deferred):
                ns[key] = obj.real
            elif isinstance(obj, dict) and any(isinstance(x, (Deferred, tuple)) for x in obj.values()):
                for k, x in list(obj.items()):
                    obj[k] = _real(x)
            elif isinstance(obj, tuple) and any(isinstance(x, Deferred) for x in obj):
                ns[key] = _real(obj)


def _real(x):
    """x with its Deferred objects (x itself, or the items of a tuple) made real."""
    if isinstance(x, Deferred):
        return x.real
    if isinstance(x, tuple) and any(isinstance(y, Deferred) for y in x):
        return tuple(_real(y) for y in x)
    return x


def expect(seconds: float, before=None) -> None:
    """A deferred process that expects about ``seconds`` of interpreted kernel time loads numba now when
    that is past half of :data:`INTERPRET_BUDGET` (a rough estimate: when in doubt, numba), so a long run pays
    nothing for the deferral. before: called first when numba is to be loaded here (``robodyn run``: start the
    compiler child on a cold cache, :func:`robodyn_ros.kernels.start_compiler_if_cold`)."""
    if DEFERRED and seconds >= 0.5 * INTERPRET_BUDGET:
        if before is not None and not LOADED:
            before()
        load_numba()


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
            if _in_hybrid():
                raise _Miss   # (a _Hybrid looks it up)
            if MODE == 'compile' or kws:
                return super()._compile_for_args(*args, **kws)
            from numba.core.dispatcher import OmittedArg
            if any(isinstance(a, OmittedArg) for a in args):
                return super()._compile_for_args(*args, **kws)
            sig, key = signature_of(self, args)
            if MODE == 'python':
                return lambda *a: run_interpreted(self, sig, a)
            entry = load_cached(self, sig, key)
            if entry is not None:
                return entry
            return lambda *a: _interpret_then_request(self, sig, a)

        def get_call_template(self, args, kws):
            # a call from another kernel: typed by its arguments' plain types, never their literal ones.
            # numba otherwise compiles a kernel again for each constant a caller passes (xmot(W, 12, 12, ...),
            # aba_ws(..., True)): 31 of the 113 signatures a1_stand compiled were such copies. A caller's
            # constant is cast to the plain type at the call; LLVM still sees it once the callee is inlined.
            from numba.core.types import unliteral
            return super().get_call_template(tuple(unliteral(a) for a in args),
                                             {k: unliteral(v) for k, v in kws.items()})

        def __reduce__(self):   # pickled (Dask) as numba's own class
            red = super().__reduce__()
            return (red[0], (base,) + tuple(red[1][1:])) if red[1] and red[1][0] is type(self) else red
    return KernelDispatcher


#: ``{(id(dispatcher), _types_key(args)): (dispatcher, signature)}`` of the calls from Python that missed: a kernel interpreted on
#: a cold cache is called with the same kinds of arguments again and again (xarm7_trajectory's first run: 4939
#: calls), and numba's ``typeof`` of each argument cost more than the call's own bookkeeping (3.3 s of 29 s)
_SIGS: dict = {}


def _types_key(args):
    """What numba's type of each argument depends on, cheap to compute: an array's dtype, dimensions, layout
    (C, F or neither), writeability and alignment; a tuple's items; a Python int's range (int64, uint64); the
    class of what numba types by its class alone (float, bool, None, numpy numbers). None for any
    other argument (its signature is then computed by numba every time)."""
    import numpy as np
    key = []
    for a in args:
        t = type(a)
        if t is np.ndarray:
            f = a.flags
            key.append((a.dtype, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned))
        elif t is tuple:
            k = _types_key(a)
            if k is None:
                return None
            key.append(k)
        elif t is int:   # int64, else uint64, else no numba type
            key.append((int, -2 ** 63 <= a < 2 ** 63, 0 <= a < 2 ** 64))
        elif t is float or t is bool or a is None or isinstance(a, (np.number, np.bool_)):
            key.append(t)
        else:
            return None
    return tuple(key)


def signature_of(d, args):
    """``(signature, key)``: numba's argument types of a call of kernel d with args, and a key that stands for
    them (:func:`_types_key`, else the signature itself), the signature computed once per key (:data:`_SIGS`)."""
    key = _types_key(args)
    known = _SIGS.get((id(d), key)) if key is not None else None
    if known is not None:
        return known[1], (id(d), key)
    sig = tuple(d.typeof_pyval(a) for a in args)
    if key is None:
        return sig, (id(d), sig)
    _SIGS[(id(d), key)] = (d, sig)   # (d kept with it: its id is not reused while it is here)
    return sig, (id(d), key)


#: ``{key: generation}`` of cache lookups that found nothing (retried when the compiler child has finished
#: something since); key: ``(id(dispatcher), signature)`` or the cheaper one of :func:`signature_of`
_MISSES: dict = {}


def load_cached(d, sig, key=None, poll=True):
    """The entry point of kernel d for the argument types sig: in memory, or loaded from the kernels' cache
    (numba's ``Dispatcher.compile`` without its compiling part); None if neither. key: what stands for sig
    (:func:`signature_of`; hashing numba's types costs more than the lookup); poll: read what the compiler
    child has finished first (else what was read last, :meth:`_Compiler.recent_generation`)."""
    if key is None:
        key = (id(d), sig)
    if poll:
        COMPILER.poll()
    if _MISSES.get(key) == COMPILER.generation:   # (a compile in this process clears _MISSES)
        return None
    existing = d.overloads.get(sig)
    if existing is not None:
        return existing.entry_point
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


def request_compiled(d, args, seconds: float) -> None:
    """Have the compiler child compile kernel d for the types of args, unless it is in memory or the cache
    (nothing while numba is not loaded: :data:`DEFERRED`), after an interpreted call that took ``seconds``
    (:func:`request_after`)."""
    if MODE != 'interpret' or isinstance(d, Deferred):
        return
    sig, key = signature_of(d, args)
    if load_cached(d, sig, key) is None:
        request_after(d, sig, seconds)


#: ``{kernel's Python function: what runs in its place while it is not compiled}`` (:func:`interpreted_by`)
_INTERPRETED_BY: dict = {}


def interpreted_by(kernel):
    """``@interpreted_by(kernel)``: the decorated function runs for calls of ``kernel`` from Python while kernel is
    interpreted (a Deferred one, a miss under :data:`MODE` 'interpret' or 'python'), instead of its Python source:
    for a kernel whose loop over every byte of a batch is fast compiled and slow interpreted, and is written as
    well by a few numpy calls (the recorder's rows and record headers, :mod:`.records`), with the same results,
    which a test compares. Returns the function."""
    def register(f):
        _INTERPRETED_BY[getattr(kernel, 'py_func', kernel)] = f
        return f
    return register


def interpreted(d):
    """Kernel d as Python (:func:`python_kernel`, or what :func:`interpreted_by` gave), made once."""
    py = d._robodyn_python if isinstance(d, Deferred) else getattr(d, '_robodyn_python', None)
    if py is None:
        py = d._robodyn_python = _INTERPRETED_BY.get(d.py_func) or python_kernel(d)
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
        _MISSES.clear()   # (what is compiled here is in memory from now on)
        if fallback is not None:
            return fallback()
        d.compile(sig)
        return d(*args)


def _interpret_then_request(d, sig, args):
    """Kernel d run interpreted on args (:func:`run_interpreted`), then the compiler child asked for its machine code
    (:func:`request_after`)."""
    t0 = time.perf_counter()
    try:
        return run_interpreted(d, sig, args)
    finally:
        request_after(d, sig, time.perf_counter() - t0)


#: > 0 inside :func:`quiet`
QUIET = [0]


class quiet:
    """``with quiet():`` interpreted calls ask the compiler child for nothing (a probe, e.g. a loop asked whether it
    takes a system with no periods to run, would put the loop before the callees a real call reaches)."""

    def __enter__(self):
        QUIET[0] += 1

    def __exit__(self, *exc):
        QUIET[0] -= 1


#: ``{(id(kernel), signature): interpreted calls}`` of calls shorter than :data:`SMALL_CALL` not yet requested
_SMALL: dict = {}


def request_after(d, sig, seconds: float) -> None:
    """Ask the compiler child for kernel d's machine code for the argument types sig, after an interpreted call that
    took ``seconds``: after the kernels it called asked for theirs (:class:`_Hybrid`), so that the child compiles the
    callees, which the next interpreted calls take up, before the callers that contain them. A call shorter than
    :data:`SMALL_CALL` asks only at its 100th (a loop's first call with nothing to do, e.g. a block of no periods,
    would put the whole loop before its callees)."""
    if QUIET[0]:
        return
    if seconds < SMALL_CALL:
        k = (id(d), sig)
        n = _SMALL[k] = _SMALL.get(k, 0) + 1
        if n < 100:
            return
    _ask(d, sig)


def _ask(d, sig, first: bool = False, spent: float = 0.0):
    """Have the compiler child compile kernel d for the argument types sig (first: before requests not so marked;
    spent: seconds its last interpreted call took beyond its interpreted callees', :meth:`_Compiler.request`).
    Returns the request's number."""
    return COMPILER.request(('kernel', d.py_func.__module__, d.py_func.__name__, sig), first, spent)


#: ``{key of signature_of: entry point}`` of the machine code interpreted kernels' callees found (:class:`_Hybrid`;
#: numba's own lookup hashes its types, which costs more than the call)
_ENTRIES: dict = {}
#: parameter names of the dynamics' addresses (:mod:`.treefn`): a negative one is a Python-only token, which machine
#: code cannot call
_ADDRESS_PARAMETERS = ('dyn', 'fd', 'bm', 'id')


def _token(x) -> bool:
    """x holds a Python-only dynamics token (:data:`.treefn.GENERIC_TOKENS` and kin: a negative int)."""
    if type(x) is int:
        return x < 0
    return type(x) is tuple and any(type(y) is int and y < 0 for y in x)


class _Hybrid:
    """A kernel as interpreted kernels call it (:func:`python_kernel`): under :data:`MODE` ``'interpret'`` its machine
    code when that is in memory or in the kernels' cache for these argument types (loaded, never compiled in this
    process), else its Python source, after which the compiler child is asked for the machine code. The same
    operations either way (module docstring), so a run's bytes do not change; an interpreted run takes up each
    callee's machine code as soon as the child has it, small callees first, instead of only the top kernel's."""

    __slots__ = ('kernel', 'py', 'addresses', 'missed', 'small', 'found', 'asked')

    def __init__(self, kernel, py):
        self.kernel, self.py = kernel, py
        code = kernel.py_func.__code__
        self.addresses = tuple(i for i, n in enumerate(code.co_varnames[:code.co_argcount])
                               if n in _ADDRESS_PARAMETERS)
        self.missed = None   # the compiler's generation when a lookup last found no machine code
        self.small = 0       # > 0: its interpreted call took less than SMALL_CALL; Python for this many more calls
        self.found = False   # its machine code was found for some argument types
        self.asked = None    # the number of its last request to the compiler child

    def __call__(self, *args):
        if self.small:
            self.small -= 1   # (then looked at again: the same kernel may take longer on other arguments)
            return self.py(*args)
        if MODE != 'interpret' or not LOADED:
            return self.py(*args)
        for i in self.addresses:
            if _token(args[i]):
                return self.py(*args)
        d = self.kernel.real if isinstance(self.kernel, Deferred) else self.kernel
        if self.found:
            # numba's dispatcher types the arguments, in C (signature_of, in Python, was a sixth of a cold A1
            # run's CPU time); arguments of types it has no machine code in memory for raise _Miss in
            # KernelDispatcher._compile_for_args, before anything runs, and are looked up below
            _IN_HYBRID.on = True
            try:
                return d(*args)
            except _Miss:
                pass
            finally:
                _IN_HYBRID.on = False
        elif self.missed == COMPILER.recent_generation() and not d.overloads:
            return self._python(args)   # nothing compiled since it found none (the common case: no lookup)
        try:
            sig, key = signature_of(d, args)
        except Exception:   # (an argument numba cannot type: Python only)
            return self.py(*args)
        entry = _ENTRIES.get(key)
        if entry is None:
            entry = load_cached(d, sig, key, poll=False)
        if entry is not None:
            _ENTRIES[key] = entry
            self.found = True
            return entry(*args)
        self.missed = COMPILER.generation
        return self._python(args, d, sig)

    def _python(self, args, d=None, sig=None):
        """The Python source on args, timed: a call shorter than :data:`SMALL_CALL` makes the next
        :data:`SMALL_CALLS` calls Python at once; a longer one asks the compiler child for kernel d's machine code
        for the types sig, marked first (what an interpreted loop calls, before what Python calls once), or, d
        None, adds to the last request's time (:meth:`_Compiler.spend`): what it took beyond its timed
        interpreted callees (which add theirs to it, :data:`_INNER`)."""
        inner = _INNER.times
        inner.append(0.0)
        t0 = time.perf_counter()
        try:
            return self.py(*args)
        finally:
            dt = time.perf_counter() - t0
            own = dt - inner.pop()
            if inner:
                inner[-1] += dt
            if dt < SMALL_CALL:
                self.small = SMALL_CALLS
            elif QUIET[0]:
                pass
            elif d is not None:
                self.asked = _ask(d, sig, first=True, spent=own)
            elif self.asked is not None:
                COMPILER.spend(self.asked, own)


#: ``.on``: this thread is in a :class:`_Hybrid`'s call of numba's dispatcher, where a miss raises :class:`_Miss`
class _HybridCall(threading.local):
    on = False


_IN_HYBRID = _HybridCall()


def _in_hybrid() -> bool:
    """This thread is in a :class:`_Hybrid`'s call of numba's dispatcher. (A function: numba's cache pickles the
    closures kernels reach, KernelDispatcher's methods by value, and a thread-local object does not pickle.)"""
    return _IN_HYBRID.on


class _Inner(threading.local):
    """``.times``: per :class:`_Hybrid` call running its Python source on this thread, innermost last, the seconds its
    own such callees took so far (what its call took beyond them is its own: :meth:`_Compiler.request`)."""

    def __init__(self):
        self.times = []


_INNER = _Inner()


class _Miss(Exception):
    """Raised by a kernel called from a :class:`_Hybrid` for argument types it has no machine code in memory for."""


#: an interpreted callee faster than this (s) stays Python (:class:`_Hybrid`): a call of machine code from Python,
#: its arguments typed, costs a few µs
SMALL_CALL = 30e-6
#: calls such a callee then stays Python before it is timed again
SMALL_CALLS = 1000
#: seconds between two looks at what the compiler child has finished, from interpreted callees (:class:`_Hybrid`)
POLL_EVERY = 0.02
#: seconds between two reports to the compiler child of the time spent in interpreted kernels (:meth:`_Compiler._tell`)
TELL_EVERY = 0.1
#: one thread at a time in :class:`_Compiler`: requests and polls come from the run's thread and from the block
#: path's thread computing ahead (a module global, not an attribute: numba's cache pickles what kernels reach)
_COMPILER_LOCK = threading.RLock()


class _Compiler:
    """The child process that compiles what interpreted calls asked for (``python -m robodyn_ros.kernels.jit``):
    requests go in on its stdin (one per line), a line per finished request comes back; :attr:`generation`
    counts them. The child is started at the first request, or before it on a cold cache (:meth:`start`); when this
    process ends it finishes what it was given and exits."""

    def __init__(self):
        self.proc = None
        self.generation = 0
        self.done: set = set()
        self._polled = 0.0
        #: ``{request number: seconds}``: the time the interpreted calls of each kernel asked for took beyond their
        #: timed interpreted callees', so far: what its machine code saves (:meth:`request`); requests are numbered
        #: in the order sent
        self.spent: dict = {}
        self._numbers: dict = {}   # {request: its number}: what was sent
        self._told = (0.0, 0.0)

    def request(self, what, first: bool = False, spent: float = 0.0):
        """Have the child compile ``what`` (:meth:`_request`), one thread at a time; first: before the requests
        not so marked that it has not begun. spent: what the call that asks took beyond its interpreted callees
        (:meth:`spend`). Returns the request's number."""
        with _COMPILER_LOCK:
            n = self._request(what, first)
        self.spend(n, spent)
        return n

    @property
    def sent(self):
        """The requests sent to the child (each once)."""
        return self._numbers.keys()

    def spend(self, n, seconds: float) -> None:
        """Add seconds to the time spent in the interpreted calls of request number n (:meth:`request`; None:
        nothing), which the polls send to the child (:meth:`_tell`) to order the requests marked first by
        (:class:`_Requests`). (Without the lock: the time is a hint for the child's order, and a lost addition costs
        nothing.)"""
        if n is not None:
            self.spent[n] = self.spent.get(n, 0.0) + seconds

    def poll(self) -> None:
        """Read what the child has finished since the last look (no wait), one thread at a time."""
        with _COMPILER_LOCK:
            self._poll()

    def recent_generation(self) -> int:
        """:attr:`generation`, read from the child at most every :data:`POLL_EVERY` s (a read is a system call;
        interpreted kernels call their callees many times a step)."""
        now = time.monotonic()
        if now - self._polled >= POLL_EVERY:
            self._polled = now
            self.poll()
        return self.generation

    def _request(self, what, first: bool = False) -> int:
        """Have the child compile ``what``: ``('kernel', module, function, signature)``, ``('call', module,
        function, *args)`` (a function that compiles, e.g. the cfuncs of :mod:`.treefn`, or a model's generated
        module: ``codegen.load(path)``). The child names no module itself, so this room imports none of them.
        first: the child takes it before the requests without (a line starting ``!``). Returns its number."""
        import base64
        import pickle
        n = self._numbers.get(what)
        if n is not None:
            return n
        n = self._numbers[what] = len(self._numbers)
        self._start()
        try:
            self.proc.stdin.write((b'!' if first else b'') + base64.b64encode(pickle.dumps(what)) + b'\n')
            self.proc.stdin.flush()
        except OSError:   # the child is gone: these calls stay interpreted
            pass
        return n

    def start(self) -> None:
        """Start the child now, before any request (one thread at a time): it loads numba and readies its
        compiler (:func:`_ready`) while this process goes on, so that the first request is compiled sooner."""
        with _COMPILER_LOCK:
            self._start()

    def _start(self) -> None:
        if self.proc is None:
            import subprocess
            env = dict(os.environ, ROBODYN_COLD_START='compile', _ROBODYN_DEFER_NUMBA='')
            root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
            env['PYTHONPATH'] = root + (os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
            self.proc = subprocess.Popen([sys.executable, '-m', 'robodyn_ros.kernels.jit'], env=env,
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
            os.set_blocking(self.proc.stdout.fileno(), False)
            self._buf = b''

    def _tell(self) -> None:
        """Send the child the time spent in each requested kernel's interpreted calls (a line ``?`` + the pickled
        :attr:`spent`, a few bytes per request) when it grew, at most every :data:`TELL_EVERY` s."""
        import base64
        import pickle
        now = time.monotonic()
        total = sum(self.spent.values())
        if now - self._told[0] < TELL_EVERY or total == self._told[1]:
            return
        self._told = (now, total)
        try:
            self.proc.stdin.write(b'?' + base64.b64encode(pickle.dumps(self.spent)) + b'\n')
            self.proc.stdin.flush()
        except OSError:
            pass

    def _poll(self) -> None:
        if self.proc is None:
            return
        self._tell()
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
        with _COMPILER_LOCK:
            self._wait()

    def _wait(self) -> None:
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


class _Requests:
    """The compiler child's requests not yet begun: those marked first (a line starting ``!``: an interpreted
    kernel's callees) before the others. Among those marked first, the one whose machine code saves most per second
    of compiling: the seconds the parent has spent in its interpreted calls so far (a line ``?``,
    :meth:`_Compiler._tell`, by the requests' numbers in the order they came) over ``cost(line)`` (what compiling
    it takes, in any unit; 1 without cost); the one that came first among equals (none spent: the order they came).
    The others in the order they came.

    A kernel compiled late costs the parent its interpreted calls meanwhile; of two, the one with the larger
    interpreted time per compile time goes first: a cold A1 run interprets its implicit step's Cholesky factor at
    0.36 ms a call, which compiles in 0.2 s, and ABA at 0.11 ms a call beyond its callees, which takes 3.5 s."""

    def __init__(self, cost=None):
        self.first, self.rest = [], []   # (number, line) each
        self.spent: dict = {}
        self.cost = cost
        self.count = 0

    def add(self, line: bytes) -> None:
        if line.startswith(b'?'):
            import base64
            import pickle
            self.spent = pickle.loads(base64.b64decode(line[1:].strip()))
            return
        (self.first if line.startswith(b'!') else self.rest).append((self.count, line))
        self.count += 1

    def _gain(self, n: int, line: bytes) -> float:
        spent = self.spent.get(n, 0.0)
        return spent / self.cost(line.strip().lstrip(b'!')) if spent and self.cost is not None else spent

    def take(self):
        """The next request to compile (its line), or None when there is none."""
        if self.first:
            return self.first.pop(max(range(len(self.first)), key=lambda k: self._gain(*self.first[k])))[1]
        return self.rest.pop(0)[1] if self.rest else None


def _code_size(what) -> float:
    """What compiling request ``what`` takes, roughly: the bytecode size of the kernel and of the kernels it reaches
    that have no machine code in this process yet (numba compiles them with it), plus :data:`COMPILE_OVERHEAD`; a
    cold A1 run's callees took 0.6–1.8 ms of compiling per bytecode instruction beyond a constant of about 0.1 s."""
    import importlib
    if what[0] != 'kernel':
        return COMPILE_OVERHEAD
    try:
        k = getattr(importlib.import_module(what[1]), what[2])
    except Exception:
        return COMPILE_OVERHEAD
    seen = set()
    size = COMPILE_OVERHEAD
    if what[3] not in getattr(k, 'overloads', {}):
        size += len(k.py_func.__code__.co_code)
    todo = [k.py_func]
    while todo:
        f = todo.pop()
        g = f.__globals__
        for name in f.__code__.co_names:
            o = g.get(name)
            if o is not None and _is_kernel(o) and id(o) not in seen:
                seen.add(id(o))
                pf = getattr(o, 'py_func', None)
                if pf is None:
                    continue
                todo.append(pf)
                if not getattr(o, 'overloads', None):
                    size += len(pf.__code__.co_code)
    return float(size)


def _line_cost(key: bytes) -> float:
    """:func:`_code_size` of the request whose line (without its mark) is key; a line it cannot read costs the fixed
    cost (the child then reports that request failed, where it compiles it)."""
    import base64
    import pickle
    try:
        return _code_size(pickle.loads(base64.b64decode(key)))
    except Exception:
        return float(COMPILE_OVERHEAD)


#: bytecode bytes that stand for a compile's fixed cost in :func:`_code_size` (about 0.1 s; an instruction is about
#: 4 bytes of CPython 3.11's code, with its caches)
COMPILE_OVERHEAD = 400


def _requests(stream, cost=None):
    """The requests of stream (the child's stdin), one line each, in :class:`_Requests`' order among those that have
    come in; read by a thread, so that a request marked first overtakes those waiting."""
    pending = _Requests(cost)
    more = threading.Condition()
    ended = []

    def read():
        for line in stream:
            with more:
                pending.add(line)
                more.notify()
        with more:
            ended.append(True)
            more.notify()
    threading.Thread(target=read, daemon=True).start()
    while True:
        with more:
            line = pending.take()
            while line is None and not ended:
                more.wait()
                line = pending.take()
        if line is None:
            return
        yield line


def _ready() -> None:
    """Compile a one-line function, cached nowhere: a process's first compilation also sets up numba's typing and
    LLVM's target (about 0.3 s on a 2-core machine), which the child then does before its first request comes."""
    try:
        _numba_njit(lambda x: x + 1.0)(1.0)
    except Exception:   # (only ever a head start: the first request would set them up anyway)
        pass


def main() -> int:
    """The compiler child: compile each request read from stdin (:func:`_requests`), print its line when done."""
    import base64
    import importlib
    import pickle
    from . import AVAILABLE
    if not AVAILABLE:
        return 1
    log = os.environ.get('ROBODYN_COMPILE_LOG')
    start = time.monotonic()
    _ready()

    for line in _requests(sys.stdin.buffer, _line_cost):
        what = pickle.loads(base64.b64decode(line.strip().lstrip(b'!')))
        t0 = time.monotonic()
        try:
            if what[0] == 'kernel':
                getattr(importlib.import_module(what[1]), what[2]).compile(what[3])
            elif what[0] == 'call':
                getattr(importlib.import_module(what[1]), what[2])(*what[3:])
            status = b'done'
        except Exception as e:   # reported, and the parent keeps interpreting that call
            status = f'failed {type(e).__name__}'.encode()
        if log:   # when each request began and how long it took, for a person measuring
            with open(log, 'a') as f:
                f.write(f'{t0 - start:8.2f} {time.monotonic() - t0:6.2f} {status.decode()} {what[:3]}\n')
        try:
            sys.stdout.buffer.write(status + b' ' + line.strip()[:40] + b'\n')
            sys.stdout.buffer.flush()
        except OSError:   # the parent has exited: keep compiling for the next run's cache
            pass
    return 0


__all__ = ['njit', 'NUMBA', 'LOADED', 'DEFERRED', 'MODE', 'set_mode', 'python_kernel', 'load_numba', 'expect']

if __name__ == '__main__':
    sys.exit(main())
