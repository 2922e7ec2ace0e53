"""A model's own dynamics code, with the generic kernels' floating-point operations in their order.

The arm's compiled loop reaches the forward dynamics, the bias/mass pass and (a joint servo's feed-forward)
the inverse dynamics through three function addresses (:mod:`robodyn_ros.kernels.treefn`). For one model,
:func:`trace` runs the generic implementations (:func:`~robodyn_ros.kernels.treefn.generic_fd`,
:func:`~robodyn_ros.kernels.treefn.generic_bm`, :func:`~robodyn_ros.kernels.treefn.generic_id`: their Python
source, the kernels of :mod:`robodyn_ros.kernels.tree`) on *symbols*: the model's packed numbers are floats,
every state-dependent value (q, v, tau and what is computed from them) a named intermediate. Each operation
the generic code performs on a symbol is written down once, in its order, as ``z<k> = a op b``; operations
on two numbers are done at generation time, with the same IEEE-754 double arithmetic the compiled code does.
The result is straight-line code without the generic kernels' loops, index arithmetic, loads from the packed
model and branches on joint types: on stanford_arm the forward dynamics is 2.7x faster per call (`robodyn
bench speed`), with the same results bit for bit.

Only exact identities are folded (Rules). Write ``≈`` for "equal, or both zeros (of either sign)".
For finite operands: ``x · 1 = x``, ``x · (−1) = −x``, ``(−x) · y = −(x · y)``, ``a + (−b) = a − b``,
``(−a) + b = b − a``, ``(−a) − b = −(a + b)``, ``x / 1 = x``, ``0 / x = 0``, ``−(−x) = x`` hold bit
for bit (round-to-nearest is symmetric in sign); ``x · 0 ≈ 0`` and ``a + 0 ≈ a``, ``0 − x ≈ −x``.
``≈`` is kept by every operation that follows (a sum is zero only when its terms are zeros or cancel,
a product is zero when a factor is, cos and sin of ±0 are 1 and ±0, comparisons see −0 = +0), and
common sub-expressions are evaluated once (the same operation on the same operands gives the same
bits; ``a + b = b + a`` and ``a · b = b · a`` exactly). So every value the generated code returns is
≈ the generic one, on every state whose generic intermediates are finite; a division is folded only
for a zero numerator, never by a divisor, and a comparison on a symbol stops the trace (the model
keeps the generic kernels: spherical joints branch on the state). One comparison is written into the code
instead: a Cholesky pivot's root (:func:`~robodyn_ros.kernels.tree.pivot_sqrt`, NaN unless the pivot is
positive), in the 6x6 solve of a free root's ABA.

Why ≈ is enough for the same bytes: the loop adds each result (times the step) to a state entry, and
``x + (±0) = x`` for every x except ``x = −0``; a state entry is −0 only when it starts at −0 and
never changes, so :meth:`robodyn_ros.kernels.CompiledModel.use_generated` keeps the generic kernels
for a state holding a −0 entry. The inverse dynamics (a joint servo's feed-forward) goes into torques
and recorded messages: its caller adds +0.0 to each result (:func:`.servo.servo_feedforward`: a −0 becomes
+0), so both give the same bits. Recordings are compared byte for byte in ``test/test_generated.py``.

The module (``fd``, ``bm``, ``rnea`` as plain functions, made cfuncs of the signatures of
:mod:`~robodyn_ros.kernels.treefn` when loaded) is written once per model to :data:`GENERATED_DIR`
under a name made from a hash of the packed model, this generator and the kernels' fingerprint, and
numba caches its machine code beside it. :func:`specialize` loads (or compiles) it in this process;
on backend auto the compiler child of :mod:`.jit` compiles it while a run goes on, and the run takes it at
the next period boundary (:mod:`robodyn_ros.kernels`, ``CompiledModel.poll_generated``); an interpreted
run (a cold cache) runs its Python text meanwhile (:func:`python_dynamics`). Trees with mimic
joints are not specialised (their loop takes another path); trees whose generated code would exceed
:data:`MAX_LINES` keep the generic kernels (numba's compile time grows with it).

On a ground the loop takes the contact path: ``kin`` (every body's transforms and velocity into W), the
contacts' forces from W (generic code), then ABA (``fdx``) or the bias/mass pass (``bmx``) under those
forces. A tree on a ground has its own module (``trace(model, ground=True)``: ``kin``, ``fdx``, ``bmx`` and
``rnea``; ``fd`` and ``bm`` stay generic, the contact path does not call them). ``fdx`` and ``bmx`` are traced
on the work array ``kin`` leaves (its numbers kept, its symbols loaded from W), so a constant of the
kinematics is folded there too. What the contacts' code reads of W is ≈ the generic kernels' (``kin``'s
outputs), and that code adds, multiplies, compares and divides by norms and positive depths only, which
keep ≈, so their forces, and every value after them, are ≈ too: the recordings of ``a1_stand`` and
``solo12_drop`` are compared byte for byte (``test/test_generated.py``).
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.util
import math
import os
import re
import sys

import numpy as np

from .jit import python_kernel

#: generated lines (the three functions) above which a model keeps the generic kernels: stanford_arm has
#: 4 100, xarm7 6 700; numba compiles about 900 lines per CPU second here
MAX_LINES = 40000
VERSION = '5'


def _generated_dir() -> str:
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return os.environ.get('ROBODYN_GENERATED_DIR') or os.path.join(base, 'robodyn_ros', 'generated')


#: where generated modules (and numba's cache of them) live; ROBODYN_GENERATED_DIR overrides
GENERATED_DIR = _generated_dir()


# ----------------------------------------------------------------------------------------------
# symbols
# ----------------------------------------------------------------------------------------------
class _Unset:
    """A work-array entry the traced code has not written (reading it is an error)."""

    def __repr__(self):
        return '<unset>'


UNSET = _Unset()


class StateBranch(TypeError):
    """The traced code compared a state-dependent value: the model keeps the generic kernels."""


class Sym:
    """A state-dependent double: a name in the generated code. ``negof``: the Sym this one is the
    negation of (folded into the operations that use it); ``nonzero``: never ±0 when finite (``c / x``)."""

    __slots__ = ('name', 'tr', 'nonzero', 'negof')

    def __init__(self, name, tr, nonzero=False, negof=None):
        self.name, self.tr, self.nonzero, self.negof = name, tr, nonzero, negof

    def __repr__(self):
        return self.name

    def __add__(self, o):
        return self.tr.add(self, o)

    def __radd__(self, o):
        return self.tr.add(o, self)

    def __sub__(self, o):
        return self.tr.sub(self, o)

    def __rsub__(self, o):
        return self.tr.sub(o, self)

    def __mul__(self, o):
        return self.tr.mul(self, o)

    def __rmul__(self, o):
        return self.tr.mul(o, self)

    def __truediv__(self, o):
        return self.tr.div(self, o)

    def __rtruediv__(self, o):
        return self.tr.div(o, self)

    def __neg__(self):
        return self.tr.neg(self)

    def __ne__(self, o):   # ``dinv != 0.0`` with dinv = 1/d: true for every finite d
        if not isinstance(o, Sym) and o == 0 and self.nonzero:
            return True
        raise StateBranch(f'{self} != {o!r}')

    def __eq__(self, o):
        if not isinstance(o, Sym) and o == 0 and self.nonzero:
            return False
        raise StateBranch(f'{self} == {o!r}')

    __hash__ = object.__hash__

    def __bool__(self):
        raise StateBranch(f'branch on {self}')

    def _compare(self, o):
        raise StateBranch(f'comparison of {self}')

    __lt__ = __le__ = __gt__ = __ge__ = _compare


def _num(x):
    """A known value as a Python float (exactly the double), or the Sym."""
    if isinstance(x, Sym):
        return x
    if x is UNSET:
        raise TypeError('the traced code read a work-array entry it had not written')
    return float(x)


def _known(x) -> bool:
    return not isinstance(x, Sym)


def _zero(x) -> bool:
    return _known(x) and x == 0.0


def _negated(x) -> bool:
    return isinstance(x, Sym) and x.negof is not None


class Tracer:
    """Records the operations on symbols (see the module docstring for the folding rules)."""

    def __init__(self):
        self.lines = []   # (Sym, op, a, b)
        self.memo = {}
        self.n = 0

    def symbol(self, name: str) -> Sym:
        """An input: ``name`` as written in the generated code (e.g. ``q[2]``)."""
        return Sym(name, self)

    def _emit(self, op, a, b=None, nonzero=False):
        ka = a.name if isinstance(a, Sym) else repr(a)
        kb = b.name if isinstance(b, Sym) else repr(b)
        if op in ('+', '*') and ka > kb:   # commutative: one name for a op b and b op a
            ka, kb = kb, ka
        key = (op, ka, kb)
        hit = self.memo.get(key)
        if hit is None:
            hit = self.memo[key] = Sym(f'z{self.n}', self, nonzero)
            self.n += 1
            self.lines.append((hit, op, a, b))
        return hit

    def neg(self, a):
        a = _num(a)
        if _known(a):
            return -a
        if a.negof is not None:
            return a.negof
        key = ('neg', a.name, '')
        hit = self.memo.get(key)
        if hit is None:
            hit = self.memo[key] = Sym(f'z{self.n}', self, a.nonzero, negof=a)
            self.n += 1
            self.lines.append((hit, 'neg', a, None))
        return hit

    def add(self, a, b):
        a, b = _num(a), _num(b)
        if _known(a) and _known(b):
            return a + b
        if _zero(a):
            return b
        if _zero(b):
            return a
        if _negated(a) and _negated(b):
            return self.neg(self.add(a.negof, b.negof))
        if _negated(b):
            return self.sub(a, b.negof)
        if _negated(a):
            return self.sub(b, a.negof)
        if _known(a) and a < 0.0:
            return self._emit('-', b, -a)
        if _known(b) and b < 0.0:
            return self._emit('-', a, -b)
        return self._emit('+', a, b)

    def sub(self, a, b):
        a, b = _num(a), _num(b)
        if _known(a) and _known(b):
            return a - b
        if _zero(b):
            return a
        if _zero(a):
            return self.neg(b)
        if _negated(b):
            return self.add(a, b.negof)
        if _negated(a):
            return self.neg(self.add(a.negof, b))
        if _known(b) and b < 0.0:
            return self._emit('+', a, -b)
        return self._emit('-', a, b)

    def mul(self, a, b):
        a, b = _num(a), _num(b)
        if _known(a) and _known(b):
            return a * b
        if _zero(a) or _zero(b):
            return 0.0
        sign = False
        if _negated(a):
            a, sign = a.negof, not sign
        if _negated(b):
            b, sign = b.negof, not sign
        for c, x in ((a, b), (b, a)):
            if _known(c):               # a number times a symbol: the sign goes into the number
                c = -c if sign else c
                if c == 1.0:
                    return x
                if c == -1.0:
                    return self.neg(x)
                return self.neg(self._emit('*', -c, x)) if c < 0.0 else self._emit('*', c, x)
        r = self._emit('*', a, b)
        return self.neg(r) if sign else r

    def div(self, a, b):
        a, b = _num(a), _num(b)
        if _known(a) and _known(b):
            return a / b
        if _zero(a):
            return 0.0
        sign = False
        if _negated(a):
            a, sign = a.negof, not sign
        if _negated(b):
            b, sign = b.negof, not sign
        if _known(a) and a < 0.0:
            a, sign = -a, not sign
        if _known(b) and b < 0.0:
            b, sign = -b, not sign
        r = a if (_known(b) and b == 1.0) else self._emit('/', a, b, nonzero=_known(a))
        return self.neg(r) if sign else r

    def call(self, fn: str, a):
        a = _num(a)
        if _known(a):
            return _numeric(fn)(a)
        return self._emit(fn, a)


@functools.lru_cache(maxsize=None)
def _numeric(fn: str):
    """The one-argument function ``fn`` the traced code may call, on numbers: ``math``'s, and for ``psqrt`` the
    Python source of :func:`~robodyn_ros.kernels.tree.pivot_sqrt` (what the compiled code computes)."""
    if fn == 'psqrt':
        from . import tree
        return python_kernel(tree.pivot_sqrt)
    return getattr(math, fn)


#: how the generated code writes each of them (a Cholesky pivot's root keeps its branch: tree.pivot_sqrt)
_WRITTEN = {'cos': 'math.cos({})', 'sin': 'math.sin({})', 'sqrt': 'math.sqrt({})',
            'psqrt': '(math.sqrt({0}) if {0} > 0.0 else math.nan)'}


class _SymMath:
    """``math`` for traced code: cos, sin and sqrt of symbols are written down, of numbers computed."""

    def __init__(self, tr):
        self._tr = tr
        self.pi, self.inf, self.nan = math.pi, math.inf, math.nan

    def cos(self, x):
        return self._tr.call('cos', x)

    def sin(self, x):
        return self._tr.call('sin', x)

    def sqrt(self, x):
        return self._tr.call('sqrt', x)


# ----------------------------------------------------------------------------------------------
# the trace of one model
# ----------------------------------------------------------------------------------------------
def _render(tr, name, args, outputs, doc) -> list:
    """The lines of ``def name(args)`` computing ``outputs`` [(target, value)]: only the operations they need."""
    by = {s.name: (op, a, b) for s, op, a, b in tr.lines}
    need, stack = set(), [v.name for _, v in outputs if isinstance(v, Sym)]
    while stack:
        n = stack.pop()
        if n in need or n not in by:
            continue
        need.add(n)
        _, a, b = by[n]
        stack += [x.name for x in (a, b) if isinstance(x, Sym)]

    def fmt(x):
        return x.name if isinstance(x, Sym) else repr(float(x))
    body = [f'def {name}({args}):', f'    """{doc}"""']
    for s, op, a, b in tr.lines:
        if s.name not in need:
            continue
        if op == 'neg':
            body.append(f'    {s.name} = -{fmt(a)}')
        elif op in _WRITTEN:
            body.append(f'    {s.name} = ' + _WRITTEN[op].format(fmt(a)))
        else:
            body.append(f'    {s.name} = {fmt(a)} {op} {fmt(b)}')
    body += [f'    {t} = {fmt(v)}' for t, v in outputs]
    return _row_views(body)


#: a cell of a 2-D argument at constant indices, as the generated code reads or writes it
_CELL = re.compile(r'\b(W|H|G|fext)\[(\d+), (\d+)\]')


def _row_views(body) -> list:
    """The lines of a generated function with each cell ``X[r, c]`` of its 2-D arguments read and written as
    ``X_r[c]``, ``X_r = X[r]`` a view of row r taken once at the start: the same elements, loaded and stored in
    the same order, so the same numbers. numba lowers a 2-D index into more code than a 1-D one (the strides of
    both axes, each index's wrap-around), which it then types, lowers and LLVM optimises away again at every
    one of the thousands of cells: the A1's ``bmx`` (666 stores and 1600 loads of cells) compiles in 18 s
    instead of 30 (:func:`_zero_runs`: 16 instead of 18). body: the def line, the docstring, then the statements."""
    rows = set()

    def cell(m):
        rows.add((m.group(1), int(m.group(2))))
        return f'{m.group(1)}_{m.group(2)}[{m.group(3)}]'
    statements = _zero_runs([_CELL.sub(cell, line) for line in body[2:]])
    return body[:2] + [f'    {a}_{r} = {a}[{r}]' for a, r in sorted(rows)] + statements


_ZERO = re.compile(r'    (\w+)\[(\d+)\] = 0\.0$')


def _zero_runs(statements) -> list:
    """statements with each run of consecutive lines ``X[i] = 0.0``, ``X[i + 1] = 0.0``, ... written as one
    ``X[i:j] = 0.0``: the same zeros stored into the same elements in the same order (a floating base's mass
    matrix and gravity stiffness are mostly zeros: 416 of the A1's 666 stores, 355 lines fewer to compile)."""
    out, k = [], 0
    while k < len(statements):
        m = _ZERO.match(statements[k])
        j = k + 1
        if m:
            name, i = m.group(1), int(m.group(2))
            while j < len(statements) and statements[j] == f'    {name}[{i + j - k}] = 0.0':
                j += 1
        out.append(statements[k] if j == k + 1 else f'    {name}[{i}:{i + j - k}] = 0.0')
        k = j
    return out


def _traced(generic, tr):
    """The generic kernel as Python on the tracer's symbols: ``math`` and the Cholesky pivot's root written down."""
    return python_kernel(generic, _SymMath(tr), overrides={'pivot_sqrt': lambda s: tr.call('psqrt', s)})


def _kin_inputs(tr, Wk):
    """The work array ``kin`` left (Wk, traced) as another function's inputs: its numbers as they are, its
    symbols as loads of W (named ``W[r, c]``), what it did not write unset."""
    out = np.full(Wk.shape, UNSET, dtype=object)
    for (r, c), x in np.ndenumerate(Wk):
        if isinstance(x, Sym):
            out[r, c] = tr.symbol(f'W[{r}, {c}]')
        elif x is not UNSET:
            out[r, c] = x
    return out


def trace(model, ground: bool = False):
    """The generated functions of ``model``: ``{name: source}`` of plain functions with the arguments of
    :mod:`~robodyn_ros.kernels.treefn`'s signatures, off a ground ``fd``, ``bm`` and ``rnea``, on one (ground:
    its loop takes the contact path) ``rnea``, ``kin``, ``fdx`` and ``bmx``; or None when the generic code
    branches on the state (spherical joints) or divides by a constant zero (a joint with no inertia about its
    axis in any configuration: the generic kernels' caller reports it)."""
    from . import pack_model, tree, treefn
    mi, mf = pack_model(model, merge=True)
    mfo = mf.astype(object)
    nb, nq, nv = mi.shape[0], model.nq, model.nv

    def inputs(tr, name, n):
        return np.array([tr.symbol(f'{name}[{k}]') for k in range(n)], dtype=object)

    def work():
        return np.full((nb + 1, tree.NW), UNSET, dtype=object)

    def forces(tr):
        return np.array([[tr.symbol(f'fext[{i}, {a}]') for a in range(6)] for i in range(nb)], dtype=object)

    def vector_function(generic, fname, given, out, doc):
        """The traced function of (q, v, given (nv,)) with one output (nv,): fd (tau -> qdd), rnea (qdd -> tau)."""
        tr = Tracer()
        res = np.full(nv, UNSET, dtype=object)
        _traced(generic, tr)(mi, mfo, inputs(tr, 'q', nq), inputs(tr, 'v', nv), inputs(tr, given, nv), res, work())
        return _render(tr, fname, f'mi, mf, q, v, {given}, {out}, W', [(f'{out}[{k}]', res[k]) for k in range(nv)],
                       doc)

    def matrices(bias, H, G):
        outs = [(f'bias[{k}]', bias[k]) for k in range(nv)]
        return outs + [(f'{m}[{a}, {b}]', X[a, b]) for m, X in (('H', H), ('G', G)) for a in range(nv)
                       for b in range(nv)]

    def bias_mass(tr, generic, W, fext):
        bias = np.full(nv, UNSET, dtype=object)
        H = np.full((nv, nv), UNSET, dtype=object)
        G = np.full((nv, nv), UNSET, dtype=object)
        zero = np.zeros(nv, dtype=object) + 0.0
        args = (zero, bias, H, G, W) if fext is None else (zero, fext, bias, H, G, W)
        _traced(generic, tr)(mi, mfo, inputs(tr, 'q', nq), inputs(tr, 'v', nv), *args)
        return matrices(bias, H, G)

    name = model.name
    out = {}
    try:
        out['rnea'] = vector_function(treefn.generic_id, 'rnea', 'qdd', 'tau',
                                      f'Inverse dynamics of {name!r} (treefn.generic_id, traced).')
        if not ground:
            out['fd'] = vector_function(treefn.generic_fd, 'fd', 'tau', 'qdd',
                                        f'Forward dynamics of {name!r} (treefn.generic_fd, traced).')
            tr = Tracer()
            out['bm'] = _render(tr, 'bm', 'mi, mf, q, v, zero, bias, H, G, W', bias_mass(tr, treefn.generic_bm, work(), None),
                                f'Bias, mass matrix and gravity stiffness of {name!r} (treefn.generic_bm, traced).')
        else:
            tr = Tracer()
            Wk = work()
            _traced(treefn.generic_kin, tr)(mi, mfo, inputs(tr, 'q', nq), inputs(tr, 'v', nv), Wk)
            out['kin'] = _render(tr, 'kin', 'mi, mf, q, v, W',
                                 [(f'W[{r}, {c}]', x) for (r, c), x in np.ndenumerate(Wk) if x is not UNSET],
                                 f'Transforms, root-to-body transforms and velocities of {name!r} (treefn.generic_kin, '
                                 'traced).')
            tr = Tracer()
            qdd = np.full(nv, UNSET, dtype=object)
            _traced(treefn.generic_fdx, tr)(mi, mfo, inputs(tr, 'q', nq), inputs(tr, 'v', nv), inputs(tr, 'tau', nv),
                                            forces(tr), qdd, _kin_inputs(tr, Wk))
            out['fdx'] = _render(tr, 'fdx', 'mi, mf, q, v, tau, fext, qdd, W', [(f'qdd[{k}]', qdd[k]) for k in range(nv)],
                                 f'Forward dynamics of {name!r} under body forces, after kin (treefn.generic_fdx, traced).')
            tr = Tracer()
            outs = bias_mass(tr, treefn.generic_bmx, _kin_inputs(tr, Wk), forces(tr))
            out['bmx'] = _render(tr, 'bmx', 'mi, mf, q, v, zero, fext, bias, H, G, W', outs,
                                 f'Bias under body forces, mass matrix and gravity stiffness of {name!r}, after kin '
                                 '(treefn.generic_bmx, traced).')
    except (StateBranch, ZeroDivisionError):
        return None
    return {k: '\n'.join(v) + '\n' for k, v in out.items()}


def module_source(model, ground: bool = False) -> str | None:
    """The generated module of ``model`` (on a ground: its functions for the contact path), or None (see
    :func:`trace`, :data:`MAX_LINES`)."""
    src = trace(model, ground)
    if src is None or sum(s.count('\n') for s in src.values()) > MAX_LINES:
        return None
    head = (f'"""Generated by robodyn_ros.kernels.codegen {VERSION} for {model.name!r}{" on a ground" if ground else ""}: '
            'the operations of\nrobodyn_ros.kernels.treefn\'s generic ' + ', '.join(src) + ' on this model, in '
            'their order. Do not edit."""\n'
            'import math\n\n\n')
    return head + '\n\n'.join(src.values())


def _key(model, ground: bool) -> str:
    """Hash of what the generated code depends on: the packed model, on a ground or not, this generator, the
    kernels' fingerprint."""
    from . import cache, pack_model
    mi, mf = pack_model(model, merge=True)
    h = hashlib.sha256()
    with open(__file__, 'rb') as f:
        generator = f.read()
    for part in (mi.tobytes(), mf.tobytes(), VERSION.encode(), cache.FINGERPRINT.encode(), generator,
                 b'ground' if ground else b''):
        h.update(part)
    return h.hexdigest()[:20]


def _file(model, ground: bool) -> str:
    """Where the generated module of ``model`` is (or goes)."""
    return os.path.join(GENERATED_DIR, f'robodyn_gen_{_key(model, ground)}.py')


def written_path(model, ground: bool = False) -> str | None:
    """Path of the generated module of ``model`` when an earlier run has written it, else None (nothing
    generated here)."""
    path = _file(model, ground)
    return path if os.path.exists(path) else None


def module_path(model, ground: bool = False) -> str | None:
    """Path of the generated module of ``model`` (on a ground: its contact path's; written if needed), or None
    when the model keeps the generic kernels or the directory is not writable."""
    path = _file(model, ground)
    if os.path.exists(path):
        return path
    src = module_source(model, ground)
    if src is None:
        return None
    try:
        os.makedirs(GENERATED_DIR, exist_ok=True)
        tmp = f'{path}.{os.getpid()}.tmp'
        with open(tmp, 'w') as f:
            f.write(src)
        os.replace(tmp, path)  # atomic: concurrent starts see a whole file or none
    except OSError as e:  # no writable cache: the generic kernels do the work
        import warnings
        warnings.warn(f'robodyn_ros: cannot write generated kernels to {GENERATED_DIR} ({e}); '
                      'using the generic compiled kernels', RuntimeWarning, stacklevel=2)
        return None
    return path


def _import(path):
    """The generated module at path (its plain functions; nothing compiled)."""
    name = os.path.splitext(os.path.basename(path))[0]
    mod = sys.modules.get(name)
    if mod is None or os.path.abspath(mod.__file__) != os.path.abspath(path):   # (another GENERATED_DIR's copy)
        write_bytecode(path)
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod  # numba's cache finds the module by name
        spec.loader.exec_module(mod)
    return mod


def write_bytecode(path) -> None:
    """Write the bytecode of the generated module at path into its ``__pycache__`` when it is not there, whatever
    ``PYTHONDONTWRITEBYTECODE`` says: the module is this package's cache, as numba's machine code beside it is,
    and Python compiles a generated module's source in 0.15 s (14 000 lines) where it loads the bytecode in 2 ms.
    Nothing is written where the directory refuses it (the import then compiles the source, as before)."""
    import py_compile
    try:
        cfile = importlib.util.cache_from_source(path)
    except NotImplementedError:   # (no cache tag: an interpreter that keeps no bytecode)
        return
    if os.path.exists(cfile):
        return
    try:
        py_compile.compile(path, cfile=cfile, doraise=True)   # (written to a temporary file, then renamed)
    except (OSError, py_compile.PyCompileError):
        pass


def _functions(mod) -> list:
    """``[(index in treefn.NAMES, function)]`` of the generated module mod."""
    from . import treefn
    return [(i, getattr(mod, n)) for i, n in enumerate(treefn.NAMES) if hasattr(mod, n)]


def is_compiled(path) -> bool:
    """True when numba's cache holds the machine code of the functions of the module at path."""
    from . import jit, treefn
    jit.load_numba()   # (treefn's signatures exist once numba is loaded)
    sigs = treefn.signatures()
    return treefn.cached(*[(f, sigs[i]) for i, f in _functions(_import(path))])


_LOADED: dict = {}


def load(path, block: bool = True):
    """The six cfuncs of :mod:`.treefn` (``fd, bm, rnea, kin, fdx, bmx``): those of the generated module at path
    (compiled here if numba's cache lacks them), the generic ones for the functions it does not hold; with
    ``block=False``, None while the generic ones are not compiled (:func:`.treefn.generic_pointers`: the compiler
    child is asked for them)."""
    path = os.path.abspath(path)
    got = _LOADED.get(path)
    if got is None:
        from . import cache, jit, treefn
        jit.load_numba()
        from numba import cfunc
        generic = treefn.generic_pointers(block)
        if generic is None:
            return None
        got = list(generic)
        sigs = treefn.signatures()
        with contextlib.ExitStack() as held:   # one process compiles a module; the others wait, then load it
            try:
                held.enter_context(cache.file_lock(f'{path}.lock', waits=WAITED))
            except OSError:   # a directory that takes no lock: each process compiles, as before
                pass
            for i, f in _functions(_import(path)):
                got[i] = cfunc(sigs[i], **treefn.CFUNC_OPTIONS)(f)
                treefn.register(got[i].address, f)   # what interpreted code runs behind this address
        got = _LOADED[path] = tuple(got)
    return got


#: compiles this process waited for another process to finish (``(lock file, seconds waited)``; tests): a
#: module is compiled under an exclusive lock beside it (:func:`.cache.file_lock`), so that processes that start
#: the same robot at once (a sweep's workers, several runs' compiler children, a test suite's workers) compile it
#: once and the others load its machine code from numba's cache (A1 on a ground: a minute of CPU each otherwise)
WAITED: list = []


_PYTHON: dict = {}


def python_dynamics(model, ground: bool = False):
    """The six tokens (:func:`robodyn_ros.kernels.treefn.register`) of ``model``'s generated code run as Python (the
    generic kernels' Python for the functions it does not hold), for an interpreted loop before it is compiled
    (about 4x faster there than the generic kernels' Python), or None when the model keeps the generic kernels."""
    path = module_path(model, ground)
    if path is None:
        return None
    got = _PYTHON.get(path)
    if got is None:
        from .treefn import GENERIC_TOKENS, register
        got = list(GENERIC_TOKENS)
        for i, f in _functions(_import(path)):
            got[i] = register(None, f)
        got = _PYTHON[path] = tuple(got)
    return got


def specialize(model, ground: bool = False):
    """The six cfuncs of ``model``'s generated code (:func:`load`), compiled in this process if not cached, or None
    (see :func:`module_path`)."""
    path = module_path(model, ground)
    return None if path is None else load(path)
