"""The tree dynamics an arm's compiled loop calls, as C function pointers: one compiled loop for every
implementation of them.

:mod:`robodyn_ros.kernels.arm`'s loops reach the forward dynamics and the bias/mass pass of the linearly
implicit step, and a joint servo's feed-forward its inverse dynamics, through three function addresses,
``dyn = (fd, bm, id, kin, fdx, bmx)`` (int64), instead of calling :func:`~robodyn_ros.kernels.tree.aba_ws` and
its kin directly; on a ground the loop takes the last three (the contacts' code runs between them). Two implementations stand behind them, with the same floating-point operations in the same order:

* the generic ones, :func:`generic_fd`, :func:`generic_bm`, :func:`generic_id`, :func:`generic_kin`,
  :func:`generic_fdx` and :func:`generic_bmx` on the packed model (``mi, mf``), compiled once per install
  (:func:`generic_pointers`);
* a model's generated ones (:mod:`robodyn_ros.kernels.codegen`): these functions traced on that model,
  straight-line code with its constants in place (the first three off a ground, the last four on one; the
  others generic).

So the loop is compiled once whichever runs (a model's own code costs only its own functions), a run can
change from one to the other between two calls of the loop, and its results do not change by a bit.

Signatures (every array C-contiguous float64, mi int64)::

    fd(mi (nb, 5), mf (nb + 1, NF), q (nq,), v (nv,), tau (nv,), qdd (nv,) out, W (nb + 1, NW) work)
    bm(mi, mf, q (nq,), v (nv,), zero (nv,) zeros, bias (nv,) out, H (nv, nv) out, G (nv, nv) out, W work)
    id(mi, mf, q (nq,), v (nv,), qdd (nv,), tau (nv,) out, W work)
    kin(mi, mf, q (nq,), v (nv,), W out)
    fdx(mi, mf, q (nq,), v (nv,), tau (nv,), fext (nb, 6), qdd (nv,) out, W (kin's) work)
    bmx(mi, mf, q (nq,), v (nv,), zero (nv,) zeros, fext (nb, 6), bias (nv,) out, H out, G out, W (kin's) work)

``fd``: ``qdd = ABA(q, v, tau)`` (book Table 7.1) with every body's ``Xup`` formed first (:func:`generic_fd`);
``bm``: ``bias = C(q, v) + g(q)``, ``H = M(q)``, ``G = ∂g/∂q`` (:func:`generic_bm`); ``id``: ``tau = RNEA(q, v,
qdd)`` with every ``Xup`` formed first (:func:`generic_id`). W holds nothing the caller reads afterwards, but
after ``kin``: every body's ``Xup``, root-to-body transform and velocity (:func:`generic_kin`), which the ground
contacts' code reads, and which ``fdx`` and ``bmx`` (ABA, and the bias/mass pass, under the contacts' body forces
fext) read and leave as they were.
Inside compiled code :func:`fd_at`, :func:`bm_at` and :func:`id_at` turn an address into a callable; Python
passes ``cfunc.address`` (a plain int: no per-call unboxing of function objects).

Interpreted (:mod:`.jit`, a cold cache), ``fd_at`` and its kin look the address up in
:data:`PYTHON`: each cfunc's Python source under its address, and Python-only implementations under negative "addresses"
(:data:`GENERIC_TOKENS`, a model's traced code before it is compiled), which only interpreted code is given
(:func:`call`).
"""
from __future__ import annotations

import time

from . import jit
from .jit import njit
from .tree import _JIT, aba_ws, bias_mass_ws, rnea_ws, transforms, workspace, world_kinematics_ws

#: options of every cfunc behind an address (generic and generated): numba's numpy error model, as the kernels
CFUNC_OPTIONS = dict(cache=True, error_model='numpy', _nrt=False)
#: ``fd(mi, mf, q, v, tau, qdd, W)``, ``bm(mi, mf, q, v, zero, bias, H, G, W)``, ``id(mi, mf, q, v, qdd, tau, W)``,
#: ``kin(mi, mf, q, v, W)``, ``fdx(mi, mf, q, v, tau, fext, qdd, W)`` and ``bmx(mi, mf, q, v, zero, fext, bias, H, G, W)``
#: as numba signatures, and their first-class function types (made by :func:`_numba_types` when numba is loaded)
FD_SIG = BM_SIG = ID_SIG = KIN_SIG = FDX_SIG = BMX_SIG = None
FD_TYPE = BM_TYPE = ID_TYPE = KIN_TYPE = FDX_TYPE = BMX_TYPE = None
#: the function types by the name of their ``<name>_at`` intrinsic (:func:`_typer`)
_TYPES: dict = {}
#: the six functions' names (a generated module's, and :func:`generic_pointers`' order)
NAMES = ('fd', 'bm', 'rnea', 'kin', 'fdx', 'bmx')


def _numba_types():
    """Set the numba signatures and function types above (numba is loaded)."""
    global FD_SIG, BM_SIG, ID_SIG, KIN_SIG, FDX_SIG, BMX_SIG, FD_TYPE, BM_TYPE, ID_TYPE, KIN_TYPE, FDX_TYPE, BMX_TYPE
    from numba import types
    f1, f2, i2 = types.float64[::1], types.float64[:, ::1], types.int64[:, ::1]
    FD_SIG = ID_SIG = types.void(i2, f2, f1, f1, f1, f1, f2)
    BM_SIG = types.void(i2, f2, f1, f1, f1, f1, f2, f2, f2)
    KIN_SIG = types.void(i2, f2, f1, f1, f2)
    FDX_SIG = types.void(i2, f2, f1, f1, f1, f2, f1, f2)
    BMX_SIG = types.void(i2, f2, f1, f1, f1, f2, f1, f2, f2, f2)
    FD_TYPE, BM_TYPE, ID_TYPE = types.FunctionType(FD_SIG), types.FunctionType(BM_SIG), types.FunctionType(ID_SIG)
    KIN_TYPE, FDX_TYPE, BMX_TYPE = types.FunctionType(KIN_SIG), types.FunctionType(FDX_SIG), types.FunctionType(BMX_SIG)
    _TYPES.update(fd=FD_TYPE, bm=BM_TYPE, id=ID_TYPE, kin=KIN_TYPE, fdx=FDX_TYPE, bmx=BMX_TYPE)


def signatures() -> tuple:
    """The six signatures, in :data:`NAMES`' order (numba is loaded)."""
    if FD_SIG is None:
        _numba_types()
    return FD_SIG, BM_SIG, ID_SIG, KIN_SIG, FDX_SIG, BMX_SIG


def generic_fd(mi, mf, q, v, tau, qdd, W):
    """``qdd (nv,) = ABA(q, v, tau)`` on the packed model: every ``Xup`` (:func:`~robodyn_ros.kernels.tree.transforms`),
    then :func:`~robodyn_ros.kernels.tree.aba_ws` without external forces. What a generated ``fd`` computes."""
    transforms(mi, mf, q, W)
    aba_ws(mi, mf, q, v, tau, W, False, qdd, W)


def generic_bm(mi, mf, q, v, zero, bias, H, G, W):
    """``bias (nv,) = C(q, v) + g(q)`` (:func:`~robodyn_ros.kernels.tree.rnea_ws` at zero acceleration),
    ``H (nv, nv) = M(q)`` (:func:`~robodyn_ros.kernels.tree.crba_ws`) and the gravity stiffness
    ``G (nv, nv) = ∂g/∂q`` (:func:`~robodyn_ros.kernels.tree.gravity_stiffness_ws`, from the CRBA's
    composite inertias) at one transform pass; zero (nv,): zeros. What a generated ``bm`` computes."""
    transforms(mi, mf, q, W)
    bias_mass_ws(mi, mf, q, v, zero, W, False, bias, H, G, W)


def generic_id(mi, mf, q, v, qdd, tau, W):
    """``tau (nv,) = RNEA(q, v, qdd)`` on the packed model: every ``Xup``
    (:func:`~robodyn_ros.kernels.tree.transforms`), then :func:`~robodyn_ros.kernels.tree.rnea_ws` without
    external forces (a joint servo's feed-forward, :mod:`.servo`). What a generated ``id`` computes."""
    transforms(mi, mf, q, W)
    rnea_ws(mi, mf, q, v, qdd, W, False, tau, W)


def generic_kin(mi, mf, q, v, W):
    """Every body's ``Xup`` (:func:`~robodyn_ros.kernels.tree.transforms`), root-to-body transform and velocity
    (:func:`~robodyn_ros.kernels.tree.world_kinematics_ws`) into W: what the ground contacts' code reads. What a
    generated ``kin`` computes."""
    transforms(mi, mf, q, W)
    world_kinematics_ws(mi, mf, v, W)


def generic_fdx(mi, mf, q, v, tau, fext, qdd, W):
    """``qdd (nv,) = ABA(q, v, tau, fext)`` (:func:`~robodyn_ros.kernels.tree.aba_ws` under the external body forces
    fext (nb, 6)) on the ``Xup`` of :func:`generic_kin` in W. What a generated ``fdx`` computes."""
    aba_ws(mi, mf, q, v, tau, fext, True, qdd, W)


def generic_bmx(mi, mf, q, v, zero, fext, bias, H, G, W):
    """:func:`generic_bm` under the external body forces fext (nb, 6) (``bias = C + g`` minus their generalised
    force), on the ``Xup`` of :func:`generic_kin` in W. What a generated ``bmx`` computes."""
    bias_mass_ws(mi, mf, q, v, zero, fext, True, bias, H, G, W)


#: the generic implementations, in :data:`NAMES`' order
GENERIC = (generic_fd, generic_bm, generic_id, generic_kin, generic_fdx, generic_bmx)


def _function_at(ftype, context, builder, addr):
    """The first-class function value of type ``ftype`` at the C address addr (an LLVM int64)."""
    from numba.core import cgutils
    f = cgutils.create_struct_proxy(ftype)(context, builder)
    vp = context.get_value_type(jit_types().voidptr)
    f.c_addr = builder.inttoptr(addr, vp)
    f.py_addr = cgutils.get_null_value(vp)   # never called back through Python
    f.jit_addr = cgutils.get_null_value(vp)  # called through the C wrapper at c_addr
    return f._getvalue()


def jit_types():
    """numba's ``types`` module (numba is loaded)."""
    from numba import types
    return types


def _typer(name: str):
    """The typer of ``<name>_at(addr)``: the ``name`` function (``fd``, ``bm``, ``id``, ``kin``, ``fdx``, ``bmx``) at
    that address (int64), callable in compiled code."""
    def typer(typingctx, addr):
        if isinstance(addr, jit_types().Integer):
            ftype = _TYPES[name]
            return ftype(addr), lambda context, builder, sig, args: _function_at(ftype, context, builder, args[0])
        return None
    typer.__name__ = typer.__qualname__ = f'{name}_at'
    return typer


def _intrinsic(typer):
    """numba's ``@intrinsic`` of typer (made when numba is loaded: :class:`.jit.Deferred`)."""
    def make():
        from numba.extending import intrinsic
        if FD_SIG is None:
            _numba_types()
        return intrinsic(typer)
    return make() if jit.LOADED else jit.Deferred(typer, make)


#: ``fd_at(addr)`` / ``bm_at`` / ``id_at`` / ``kin_at`` / ``fdx_at`` / ``bmx_at`` (intrinsics): the function at that
#: address, in compiled code
fd_at, bm_at, id_at, kin_at, fdx_at, bmx_at = (_intrinsic(_typer(n)) for n in ('fd', 'bm', 'id', 'kin', 'fdx', 'bmx'))


@njit(**_JIT)
def call_fd(fd, mi, mf, q, v, tau, qdd):
    """``qdd (nv,) = fd(q, v, tau)`` for a call from Python: the fd at address fd, with its own work array."""
    fd_at(fd)(mi, mf, q, v, tau, qdd, workspace(mi.shape[0]))


_GENERIC: list = []
_GENERIC_MISS = [None]   # the compiler generation at which the cache last lacked the generic cfuncs


def generic_pointers(block: bool = True):
    """``(fd, bm, id, kin, fdx, bmx)``: the generic implementations as numba cfuncs, their ``.address`` what the loops take;
    compiled, or loaded from the kernels' cache, on first use. ``block=False`` (interpreting, :mod:`.jit`):
    None when the cache lacks them, and the compiler child is asked for them."""
    if not _GENERIC:
        if not block and (jit.MODE == 'python' or not jit.LOADED):   # (not loaded: numba deferred, jit.DEFERRED)
            return None
        jit.load_numba()
        if not block:
            if _GENERIC_MISS[0] == jit.COMPILER.generation:
                jit.COMPILER.poll()
                if _GENERIC_MISS[0] == jit.COMPILER.generation:
                    return None
            if not cached(*zip(GENERIC, signatures())):
                _GENERIC_MISS[0] = jit.COMPILER.generation
                jit.COMPILER.request(('call', __name__, 'generic_pointers'))
                return None
        from numba import cfunc
        for f, sig in zip(GENERIC, signatures()):
            c = cfunc(sig, **CFUNC_OPTIONS)(f)
            register(c.address, f)
            _GENERIC.append(c)
    return tuple(_GENERIC)


_ADDRESSES: list = []


def generic_addresses() -> tuple:
    """``(fd, bm, id, kin, fdx, bmx)`` addresses of :func:`generic_pointers` (compiled or loaded on first use), read once."""
    if not _ADDRESSES:
        _ADDRESSES.append(tuple(f.address for f in generic_pointers()))
    return _ADDRESSES[0]


def cached(*funcs) -> bool:
    """True when the kernels' cache holds machine code of every ``(python function, cfunc signature)``."""
    jit.load_numba()
    from numba.core.caching import FunctionCache
    from numba.core.registry import cpu_target
    return all(FunctionCache(f).load_overload(sig, cpu_target.target_context) is not None for f, sig in funcs)


#: ``{address: Python function}`` behind the addresses an interpreted loop may be given (:func:`register`)
PYTHON: dict = {}
#: the generic implementations (:data:`GENERIC`) as Python, for interpreted code before their cfuncs exist
GENERIC_TOKENS = (-1, -2, -3, -4, -5, -6)
_NEXT_TOKEN = [-7]


def register(address: int, func) -> int:
    """Put ``func`` (a plain function of the fd, bm or id signature) behind ``address`` (its cfunc's, or None for a
    new negative token) for interpreted code; returns the address."""
    if address is None:
        address = _NEXT_TOKEN[0]
        _NEXT_TOKEN[0] -= 1
    PYTHON[address] = jit.python_kernel(func)
    return address


def python_function(address):
    """The Python function behind an address (``fd_at`` / ``bm_at`` / ``id_at`` in interpreted code)."""
    f = PYTHON.get(address)
    if f is None and address in GENERIC_TOKENS:
        generic = GENERIC[GENERIC_TOKENS.index(address)]
        f = PYTHON[address] = jit.python_kernel(generic)
    return f


jit.PY_OVERRIDES.update(fd_at=python_function, bm_at=python_function, id_at=python_function, kin_at=python_function,
                        fdx_at=python_function, bmx_at=python_function)


def call(d, args: list, dyn_index: int, tokens: bool):
    """Kernel d on args whose entry ``dyn_index`` is a dynamics address (or the six addresses): as any
    kernel (compiled, or interpreted on a miss) when they are cfuncs' addresses; with ``tokens`` (Python-only
    implementations, :func:`register`) always interpreted, for compiled code cannot call them. Where the
    interpreter raises (a failing state: :func:`.jit.run_interpreted`) it is run compiled on the generic
    cfuncs."""
    if not tokens:
        return d(*args)

    def compiled():
        generic = generic_addresses()
        real = list(args)
        real[dyn_index] = generic[0] if isinstance(args[dyn_index], int) else generic
        return d(*real)
    t0 = time.perf_counter()
    try:
        return jit.run_interpreted(d, None, args, fallback=compiled)
    finally:   # (tokens type as addresses: the child compiles what the next call takes, after the callees it asked for)
        jit.request_compiled(d, args, time.perf_counter() - t0)
