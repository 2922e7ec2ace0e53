"""Compiled (numba) rigid-body kernels: the fast path beside the numpy reference.

:mod:`robodyn_ros.dynamics` stays the reference; this package computes the same quantities
(tested equal to 1e-12 relative on random trees and every bundled scene) in numba-compiled
code on a packed copy of the model::

    from robodyn_ros import kernels
    if kernels.AVAILABLE:
        km = kernels.CompiledModel(model)
        qdd = km.aba(q, v, tau)              # (nv,)
        tau = km.rnea(q, v, a)               # (nv,)
        M = km.crba(q)                       # (nv, nv)
        qdd, f = km.joint_wrenches(q, v, tau)
        T, V = km.energies(q, v)

Arguments are float64 numpy arrays (1-D slices of a state vector are fine); results are new
arrays. ``AVAILABLE`` is False when numba cannot be imported, and callers (``ArmSystem``) then
use the reference. The fused integrators (:meth:`CompiledModel.integrate_arm`, :meth:`CompiledModel.run_periods`)
run whole publication periods of fixed steps in one compiled call, on the generic kernels or on the model's
generated code (:mod:`.codegen`: the same operations), which a run may take up between two calls. The constrained and floating-base
systems (differential drive, free base in minimal and augmented coordinates, prescribed path)
run on :class:`CompiledSystem`, with the same fused loop (:mod:`robodyn_ros.kernels.fixed_step`).

Layout, mirroring :mod:`robodyn_ros.systems`: :mod:`.tree` (the tree algorithms on packed
arrays), :mod:`.frames` (body frames, velocities, momentum), :mod:`.linalg` (small dense linear
algebra), one module per system (:mod:`.arm`, :mod:`.diffdrive`, :mod:`.freeflyer`,
:mod:`.augmented`, :mod:`.prescribed`), :mod:`.fixed_step` (the constrained systems' fused
loop), :mod:`.profiles` (command profiles), :mod:`.pfl` (the PFL law), :mod:`.outputs` and
:mod:`.records` (the recorder's batches), :mod:`.passive` (joint friction), :mod:`.treefn` (the tree
dynamics behind function addresses) and :mod:`.codegen` (a model's own code for them).

Compilation cache. Every kernel is ``@njit(cache=True)``: the first start of a new install
compiles (a few minutes of CPU for every kernel; ``robodyn warm``, which ``make test`` runs first,
does it for every function the bundled scenes and URDF robots use) and writes the machine code
to ``~/.cache/robodyn_ros/numba/kernels-<fingerprint>``; later starts, of this install or of any other
of the same sources on the machine, load it, for any robot.
Where the cache goes when that directory is not writable, and why any edit of a kernel module
invalidates all of them: :mod:`.cache` (:data:`CACHE_DIR` says where it is). Set
``ROBODYN_BACKEND=numpy`` to switch the compiled path off, ``numba`` to keep an arm on the generic
kernels, ``generated`` to compile its own code (:mod:`robodyn_ros.kernels.codegen`, cached under
``~/.cache/robodyn_ros/generated``) before its first step; ``auto`` (the tools' default) starts on the
generic kernels and takes the model's code up once it is compiled, in a child process
(:data:`GENERATE_AFTER`).
"""
from __future__ import annotations

import os

import numpy as np

from ..model import Model
from . import jit as _jit
from .jit import NUMBA

if NUMBA:
    from . import cache as _cache
    if _jit.LOADED:
        _cache.install()   # before any kernel is defined: where their cache goes, when it is stale
    else:   # deferred (jit.DEFERRED): when numba is loaded, before the kernels are made real
        _jit._BEFORE_LOAD.append(_cache.install)

#: directory holding the compiled kernels' cache (see :mod:`.cache`)
CACHE_DIR = _cache.cache_root() if NUMBA else ''

try:
    if os.environ.get('ROBODYN_BACKEND', '').lower() == 'numpy':
        raise ImportError('ROBODYN_BACKEND=numpy')
    if not NUMBA:
        raise ImportError("No module named 'numba'")
    from . import (arm, augmented, contact, diffdrive, fixed_step, frames, freeflyer, linalg,  # noqa: F401
                   prescribed, profiles, sensors, servo, tree, treefn)
    AVAILABLE = True
    UNAVAILABLE_REASON = ''
except ImportError as _e:  # the compiled path is off: the systems use the numpy reference
    # (the kernels that must run anyway -- tree algorithms for the PFL law, command profiles,
    # the recorder's loops -- import on their own, compiled when numba is there, else plain Python)
    AVAILABLE = False
    UNAVAILABLE_REASON = str(_e)

__all__ = ['AVAILABLE', 'CACHE_DIR', 'CompiledModel', 'CompiledSystem', 'pack_model', 'FUSED_METHODS', 'warmup',
           'start_compiler_if_cold']

#: integrator names the fused loop implements -> method code in :mod:`.fixed_step`
FUSED_METHODS = {'euler': 0, 'semi_implicit_euler': 1, 'rk4': 2, 'rosenbrock2': 3}
#: wall time (s) an arm on backend 'auto' integrates on the generic kernels before it starts compiling its
#: generated code in a child process (a shorter run never pays for it)
GENERATE_AFTER = 0.5
#: the bits of −0.0 read as an int64 (no other double has them): :func:`has_negative_zero`
_NEGATIVE_ZERO_BITS = int(np.iinfo(np.int64).min)
_EMPTY = np.zeros(0)


def start_compiler_if_cold() -> bool:
    """In a process whose kernels run as Python while a child compiles them (``jit.MODE`` 'interpret': ``robodyn
    run`` before it loads numba, the sim node at its start), start that child now when the kernel cache holds no
    compiled kernel (:func:`.cache.holds_no_kernel`): on a first run the child then loads numba and readies its
    compiler while this process loads numba, builds its simulator and makes its first interpreted call, instead
    of after that call. Returns whether it started. A cache with kernels in it starts nothing here (a run loads
    what it uses, and the child starts at a miss, as before)."""
    if not (AVAILABLE and _jit.MODE == 'interpret') or not _cache.holds_no_kernel():
        return False
    _jit.COMPILER.start()
    return True


def has_negative_zero(z) -> bool:
    """True when the float64 array z holds an entry −0.0 (its bits compared as integers: 0.7 µs for a 15-entry
    state against 3.5 µs for ``np.any((z == 0.0) & np.signbit(z))``, asked once per loop call)."""
    return _NEGATIVE_ZERO_BITS in np.asarray(z, dtype=np.float64).view(np.int64).tolist()


def merge_fixed(model: Model) -> dict:
    """The tree with every FIXED non-root body welded into its parent (for ABA/RNEA/CRBA/energy).

    A welded body's inertia is moved into its host body (``Xᵀ I X`` with X the host -> body
    transform) and its children hang from the host with ``Xtree`` composed, so joint-space
    results (``qdd``, ``tau``, ``M``, energies) are unchanged while the loops visit fewer bodies
    (the massless ``tool`` link of a DH arm disappears, as Pinocchio turns it into a frame).
    FIXED roots (welded to the world) stay. Returns the arrays :func:`pack_model` needs, and
    ``host`` (nb,): the merged body each body of the model is welded into, ``Xh`` (nb, 6, 6): the
    motion transform from that host's frame to the body's.
    """
    from ..model import FIXED as _FIXED
    nb = model.nb
    host = list(range(nb))
    Xh = [np.eye(6)] * nb  # motion transform host(i) -> i
    keep, new = [], {}
    for i in range(nb):
        p = int(model.parent[i])
        if model.jtype[i] == _FIXED and p >= 0:
            host[i] = host[p]
            Xh[i] = model.Xtree[i] @ Xh[p]
        else:
            new[i] = len(keep)
            keep.append(i)
    I = {i: model.I[i].copy() for i in keep}
    for i in range(nb):
        if host[i] != i:
            I[host[i]] += Xh[i].T @ model.I[i] @ Xh[i]
    parent, Xtree = [], []
    for i in keep:
        p = int(model.parent[i])
        parent.append(-1 if p < 0 else new[host[p]])
        Xtree.append(model.Xtree[i] if p < 0 else model.Xtree[i] @ Xh[p])
    return {'parent': np.array(parent, dtype=np.int64), 'jtype': model.jtype[keep], 'axis': model.axis[keep],
            'Xtree': np.array(Xtree).reshape(-1, 6, 6), 'I': np.array([I[i] for i in keep]).reshape(-1, 6, 6),
            'q_idx': model.q_idx[keep], 'v_idx': model.v_idx[keep], 'gravity': model.gravity,
            'armature': body_armature(model)[keep],
            'host': np.array([new[host[i]] for i in range(nb)], dtype=np.int64), 'Xh': np.array(Xh).reshape(-1, 6, 6)}


def body_armature(model: Model) -> np.ndarray:
    """Each body's joint armature (nb,) (``Model.armature`` is per velocity coordinate; a joint's
    coordinates share one value; 0 for FIXED and FREE joints)."""
    arm = np.asarray(model.armature, dtype=float)
    return np.array([arm[model.v_idx[i]] if model.nv_j[i] else 0.0 for i in range(model.nb)], dtype=float)


def pack_model(model: Model, merge: bool = False):
    """The model as two arrays for the kernels: ``(mi (nb, 5) int64, mf (nb + 1, NF) float64)``.

    Column layout in :mod:`robodyn_ros.kernels.tree`: per body parent, joint type, q and v
    index, +z-axis flag; axis, Xtree as (E, r), mass, m·com, rotational inertia about the body
    origin, joint armature; the last row of mf holds gravity. merge: weld FIXED bodies into their parents
    (:func:`merge_fixed`).
    """
    from ..model import PRISMATIC as _PRISMATIC
    from ..model import REVOLUTE as _REVOLUTE
    if merge:
        a = merge_fixed(model)
    else:
        a = {k: getattr(model, k) for k in ('parent', 'jtype', 'axis', 'Xtree', 'I', 'q_idx', 'v_idx', 'gravity')}
        a['armature'] = body_armature(model)
    nb = len(a['parent'])
    mi = np.zeros((nb, 5), dtype=np.int64)
    mi[:, 0] = a['parent']
    mi[:, 1] = a['jtype']
    mi[:, 2] = a['q_idx']
    mi[:, 3] = a['v_idx']
    mi[:, 4] = [int(a['jtype'][i] in (_REVOLUTE, _PRISMATIC) and tuple(a['axis'][i]) == (0.0, 0.0, 1.0))
                for i in range(nb)]
    mf = np.zeros((nb + 1, 29))
    for i in range(nb):
        X = a['Xtree'][i]
        E = X[:3, :3]
        rx = -(E.T @ X[3:, :3])  # X[3:, :3] = -E r×
        I = a['I'][i]
        hx = I[:3, 3:]  # = h× with h = m c
        mf[i, 0:3] = a['axis'][i]
        mf[i, 3:12] = E.reshape(-1)
        mf[i, 12:15] = (rx[2, 1], rx[0, 2], rx[1, 0])
        mf[i, 15] = I[5, 5]
        mf[i, 16:19] = (hx[2, 1], hx[0, 2], hx[1, 0])
        mf[i, 19:28] = I[:3, :3].reshape(-1)
        mf[i, 28] = a['armature'][i]
    mf[nb, 0:3] = a['gravity']
    return np.ascontiguousarray(mi), np.ascontiguousarray(mf)


class CompiledModel:
    """A model packed for the compiled kernels, with the reference functions' signatures.

    model: the kinematic tree. All methods take float64 arrays of the reference shapes
    (q (nq,), v/a/tau (nv,), f_ext (nb, 6) in body coordinates) and return new arrays.
    Joint-space results use the tree with FIXED bodies welded into their parents
    (``mi_r, mf_r``, :func:`merge_fixed`); per-body results (wrenches) and external forces
    use the full tree (``mi, mf``). specialize: False (the generic kernels), True (the model's own
    code for the fused loops' dynamics, :mod:`robodyn_ros.kernels.codegen`, loaded or compiled now) or
    ``'auto'`` (generic, and the model's own code taken up once a child process has compiled it:
    :meth:`poll_generated`). Both compute the same bits; trees the generator declines (spherical joints,
    mimic joints) stay generic (``gen`` None). A tree put on a ground (:meth:`on_ground`) takes its contact path's
    generated functions.
    """

    def __init__(self, model: Model, specialize: bool = False):
        if not AVAILABLE:
            raise RuntimeError(f'compiled kernels unavailable: {UNAVAILABLE_REASON}')
        self.model = model
        self.mi, self.mf = pack_model(model)
        self.mi_r, self.mf_r = pack_model(model, merge=True)
        self.nb, self.nq, self.nv = model.nb, model.nq, model.nv
        self.damping = np.ascontiguousarray(model.damping, dtype=float).reshape(self.nv)
        from ..model import COULOMB_VELOCITY
        self.friction = np.ascontiguousarray(model.friction, dtype=float).reshape(self.nv)
        self.v_s = float(COULOMB_VELOCITY)   # regularisation speed of the Coulomb friction (kernels.passive)
        from ..model import limit_table
        self.lim = limit_table(model)   # joint-limit moments (Huston eq. 20.2.1), 0 rows = none
        self._zf = np.zeros((self.nb, 6))
        from ..model import mimic_table
        self.mimic = mimic_table(model)  # joints following others (URDF <mimic>): the coupled dynamics
        self.coupled = None
        self.cpl = None   # the fused loop's coupling argument: (mimic table, col, mul) of a coupled tree
        if self.mimic.shape[0]:
            from . import coupled
            self.coupled = coupled
            self.col, self.mul, self.nr = coupled.coupling(self.mimic, self.nv)
            self.cpl = (self.mimic, self.col, self.mul)
        self.con = None   # the packed ground contacts (kernels.contact), set by systems.contact
        self.cpo = None   # their points' (body, link) rows (kernels.arm.run_arm_periods), set with con
        self.gen = None   # the generated (fd, bm, rnea) cfuncs in use (kernels.codegen), or None
        self._auto = specialize == 'auto' and self.coupled is None
        self._requested = None    # the generated module the compiler child was asked for (backend 'auto')
        self._spent = 0.0         # wall time integrated on the generic kernels (backend 'auto')
        self._ros = None          # the linearly implicit step's work arrays (arm.rosenbrock_work)
        self._pygen = False       # interpreting: the generated code's Python tokens (None: none), once asked
        self._gen_dyn = (None, None)   # (gen, the addresses of its cfuncs)
        self._looked = False      # backend 'auto': whether the first poll has looked for compiled code on disk
        self._eager = specialize is True and self.coupled is None   # a coupled tree stays on the generic kernels
        if self._eager:
            from . import codegen
            self.gen = codegen.specialize(model)

    def on_ground(self):
        """The tree was put on a ground (``con`` set): its loop takes the contact path, whose generated functions
        (``kin``, ``fdx``, ``bmx``: :mod:`.treefn`) are another module's; what was taken up or asked for is
        forgotten."""
        self.gen = None
        self._pygen = False
        self._looked = False
        self._requested = None
        self._gen_dyn = (None, None)
        if self._eager:
            from . import codegen
            self.gen = codegen.specialize(self.model, ground=True)

    def poll_generated(self):
        """Backend 'auto': take up the model's generated code at the first call when an earlier run left it
        compiled in the cache, else once the compiler child (:mod:`.jit`) has it there; ask the child for it once
        :data:`GENERATE_AFTER` seconds were integrated here (called between loop calls, so the code changes at a
        period boundary). Interpreting, the generic cfuncs a module leaves to the generic kernels are not compiled
        here: until the child has them (it is asked), the run stays on the generic kernels."""
        if not self._auto or self.gen is not None:
            return
        from . import codegen, jit
        block = jit.MODE == 'compile'
        if not self._looked:   # code an earlier run had compiled: taken up at the first period boundary
            self._looked = True
            path = codegen.written_path(self.model, self.con is not None) if jit.LOADED else None   # (a deferred run is short)
            if path is not None and codegen.is_compiled(path):
                self._requested = path
                self._seen = jit.COMPILER.generation
                self.gen = codegen.load(path, block)
                return
        if self._requested is None:
            if self._spent < GENERATE_AFTER:
                return
            self._requested = codegen.module_path(self.model, self.con is not None)
            if self._requested is None:
                self._auto = False
                return
            if not codegen.is_compiled(self._requested):   # else another run compiled it
                jit.COMPILER.request(('call', codegen.__name__, 'load', self._requested))
                self._seen = jit.COMPILER.generation
                return
        else:
            jit.COMPILER.poll()
            if jit.COMPILER.generation == self._seen:
                return
            self._seen = jit.COMPILER.generation
            if not codegen.is_compiled(self._requested):
                return
        self.gen = codegen.load(self._requested, block)

    def dynamics(self, z):
        """``(dyn, tokens)``: the addresses of the forward dynamics, bias/mass pass and inverse dynamics the loop
        takes for state z (:mod:`.treefn`): the generated code's, or the generic kernels' while there is none or
        while z holds an entry −0.0 (the one state whose bits a folded zero could change: :mod:`.codegen`).
        Interpreting (:mod:`.jit`) while the generic cfuncs are not compiled: Python-only tokens (``tokens`` True: the
        model's generated code as Python, else the generic kernels' Python), for interpreted calls only."""
        from . import jit
        signed_zero = has_negative_zero(z)
        gen = self.gen
        if gen is not None and not signed_zero:
            if self._gen_dyn[0] is not gen:   # (the addresses of the cfuncs in use, read once)
                self._gen_dyn = (gen, tuple(f.address for f in gen))
            return self._gen_dyn[1], False
        if jit.MODE == 'compile':
            return treefn.generic_addresses(), False
        generic = treefn.generic_pointers(block=False)
        if generic is not None:
            return treefn.generic_addresses(), False
        pygen = self._python_tokens()
        return (pygen if pygen is not None and not signed_zero else treefn.GENERIC_TOKENS), True

    def _python_tokens(self):
        """The model's generated code as Python tokens (:func:`.codegen.python_dynamics`), or None (no generated
        code: a tree with mimic joints, or one that branches on the state)."""
        if self._pygen is False:
            from . import codegen
            self._pygen = codegen.python_dynamics(self.model, self.con is not None) if self.coupled is None else None
        return self._pygen

    def aba(self, q, v, tau, f_ext=None):
        """Forward dynamics ``qdd`` (nv,) by the articulated-body algorithm (a tree with mimic joints:
        the coupled dynamics of :mod:`robodyn_ros.kernels.coupled`; external forces not supported there)."""
        qdd = np.empty(self.nv)
        if self.coupled is not None:
            if f_ext is not None:
                raise NotImplementedError('external forces on a tree with mimic joints')
            self.coupled.coupled_fd_into(self.mi_r, self.mf_r, self.col, self.mul, self.nr, q, v, tau, qdd)
        elif f_ext is None:   # (the operations of the loops' generic fd, treefn.generic_fd, without its Python detour)
            tree.aba_into(self.mi_r, self.mf_r, q, v, tau, qdd)
        else:
            tree.aba_fext_into(self.mi, self.mf, q, v, tau, np.ascontiguousarray(f_ext, dtype=float), qdd)
        return qdd

    def _fd(self, q, v, tau, qdd, generic):
        """qdd through an fd of :mod:`.treefn` (the generic one, or the one the loops take now)."""
        from . import jit
        c = np.ascontiguousarray
        if generic:
            fd, tokens = treefn.generic_pointers(block=jit.MODE == 'compile'), False
            dyn = (fd[0].address,) if fd is not None else None
            if dyn is None:
                dyn, tokens = treefn.GENERIC_TOKENS, True
        else:
            dyn, tokens = self.dynamics(np.zeros(0))
        treefn.call(treefn.call_fd, [dyn[0], self.mi_r, self.mf_r, c(q, dtype=float), c(v, dtype=float),
                                     c(tau, dtype=float), qdd], 0, tokens)

    def forward(self, q, v, tau):
        """Forward dynamics ``qdd`` (nv,) through the fused loops' ``fd`` (:mod:`.treefn`): the generated code
        when it is in use (the same bits as :meth:`aba`'s, but for the sign of zeros), else the generic one."""
        qdd = np.empty(self.nv)
        if self.gen is not None:   # (what _fd does then, without its Python detour: a call from Python costs ~1 µs)
            c = np.ascontiguousarray
            treefn.call_fd(self.gen[0].address, self.mi_r, self.mf_r, c(q, dtype=float), c(v, dtype=float),
                           c(tau, dtype=float), qdd)
        else:
            self._fd(q, v, tau, qdd, generic=False)
        return qdd

    def rnea(self, q, v, a, f_ext=None):
        """Inverse dynamics ``tau = M a + h`` (nv,)."""
        if f_ext is None:
            tau = np.empty(self.nv)
            tree.rnea_into(self.mi_r, self.mf_r, q, v, a, tau)
            return tau
        return tree.rnea(self.mi, self.mf, q, v, a, np.ascontiguousarray(f_ext, dtype=float), True)[0]

    def rnea_wrenches(self, q, v, a, f_ext=None):
        """``(tau (nv,), f (nb, 6))``: inverse dynamics and the joint wrenches (parent on child)."""
        fe, has = (self._zf, False) if f_ext is None else (np.ascontiguousarray(f_ext, dtype=float), True)
        return tree.rnea(self.mi, self.mf, q, v, a, fe, has)

    def crba(self, q):
        """Joint-space inertia matrix ``M(q)`` (nv, nv)."""
        H = np.zeros((self.nv, self.nv))
        tree.crba_into(self.mi_r, self.mf_r, q, H)
        return H

    def joint_wrenches(self, q, v, tau, f_ext=None):
        """``(qdd (nv,), f (nb, 6))`` under applied forces tau (see ``dynamics.joint_wrenches``); a
        tree with mimic joints: at its coupled accelerations (:meth:`coupled_wrenches`)."""
        if self.coupled is not None:
            return self.coupled_wrenches(q, v, tau, f_ext)[:2]
        fe, has = (self._zf, False) if f_ext is None else (np.ascontiguousarray(f_ext, dtype=float), True)
        return tree.joint_wrenches(self.mi, self.mf, q, v, tau, fe, has)

    def coupled_wrenches(self, q, v, tau, f_ext=None):
        """``(qdd (nv,), f (nb, 6), λ (nv,))`` of a tree with mimic joints (``coupled.coupled_wrenches``):
        λ is the coupling's generalised force, the effort a following joint transmits."""
        if f_ext is not None:
            raise NotImplementedError('external forces on a tree with mimic joints')
        return self.coupled.coupled_wrenches(self.mi, self.mf, self.col, self.mul, self.nr,
                                             np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float),
                                             np.ascontiguousarray(tau, dtype=float))

    def couple(self, q, v):
        """Set the following joints of q and v in place from their sources (``coupled.couple_into``)."""
        if self.coupled is not None:
            self.coupled.couple_into(self.mimic, q, v)

    def energies(self, q, v):
        """``(kinetic, potential)`` energy (J)."""
        return tree.energies(self.mi_r, self.mf_r, q, v)

    def kinetic_energy(self, q, v):
        """Kinetic energy (J)."""
        return tree.energies(self.mi_r, self.mf_r, q, v)[0]

    def potential_energy(self, q):
        """Gravitational potential energy (J), zero at the root origin."""
        return tree.energies(self.mi_r, self.mf_r, q, np.zeros(self.nv))[1]

    def body_poses(self, q):
        """World poses of the body frames ``(R (nb, 3, 3), p (nb, 3))`` (``dynamics.body_poses``)."""
        return frames.poses(self.mi, self.mf, np.ascontiguousarray(q, dtype=float))

    def momentum(self, q, v):
        """``(p (3,), L (3,), c (3,))``: linear momentum, angular momentum about the centre of mass
        and the centre of mass, world coordinates (``freeflyer.momentum_about_com``)."""
        return frames.momentum(self.mi, self.mf, np.ascontiguousarray(q, dtype=float),
                                    np.ascontiguousarray(v, dtype=float))

    def limit_forces(self, q, v):
        """Joint-limit generalised forces (nv,) of Huston eq. (20.2.1) at (q, v) (``tree.limit_forces_add``)."""
        return tree.limit_forces(self.lim, np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float),
                                 self.nv)

    def qdot(self, q, v):
        """Configuration rate ``dq/dt`` (nq,) (quaternion-aware)."""
        return tree.qdot(self.mi, q, v)

    def normalize(self, q):
        """q with free- and spherical-joint quaternions renormalised (a new array)."""
        q = np.array(q, dtype=float)
        tree.normalize_into(self.mi, q)
        return q

    def integrate_arm(self, method: str, z, tau_app, dt, n_full, h_last, t0=0.0, srv=None, tol=None) -> int:
        """Fused fixed-step integration of ``z = [q, v, W]`` in place (see ``arm.arm_steps``): one period
        of :meth:`run_periods`, the applied forces given.

        method: a key of :data:`FUSED_METHODS`; z (nq + nv + 1,) float64, modified in place;
        tau_app (nv,) = B u held over the call; dt, n_full, h_last: the step grid; t0: the time of
        its first step (s); srv: None, or a joint servo (:mod:`.servo`) evaluated at every stage; tol:
        None, or ``(rtol, atol)`` or ``(rtol, atol, most steps)`` for rosenbrock2 under error control
        (``arm.arm_controlled_steps``; dt its largest step, :meth:`control_counts` what it did). Returns the index of the first non-finite step or -1.
        """
        e2 = np.zeros((0, 0))
        out = self.run_periods(method, e2, z, dt, np.array([float(t0)]), np.array([int(n_full)], dtype=np.int64),
                               np.array([float(h_last)]), None, np.ascontiguousarray(tau_app, dtype=np.float64),
                               np.empty((1, z.shape[0])), np.empty((1, self.nv)), np.empty((1, self.nv)),
                               np.empty((0, self.nb, 6)), False, np.full(self.nv, np.inf), np.empty((1, 0, 6)),
                               np.array([float(t0)]), srv, np.empty((1, 0, 6)), tol)
        return out[2]

    def control_counts(self) -> dict:
        """What the error-controlled rosenbrock2 steps of the last :meth:`run_periods` call did
        (``arm.arm_controlled_steps``): ``{accepted, rejected, h_min (s), underflow, budget (bools),
        done (s from its start)}``."""
        ctl = self._ros[4]
        return {'accepted': int(ctl[arm.CTL_ACCEPTED]), 'rejected': int(ctl[arm.CTL_REJECTED]),
                'h_min': float(ctl[arm.CTL_H_MIN]), 'underflow': bool(ctl[arm.CTL_UNDERFLOW]),
                'budget': bool(ctl[arm.CTL_BUDGET]), 'done': float(ctl[arm.CTL_DONE])}

    def run_periods(self, method: str, B, z, dt, t_start, n_full, h_last, program, u, Zs, Us, TAUs, Fs, want_f,
                    ulim, Cs, t_end, srv=None, SVs=None, tol=None, CPs=None):
        """K publication periods in one compiled call (``arm.run_arm_periods``, the loops' one entry): the
        per-period path (:meth:`integrate_arm`) and the block path (``ArmSystem.fused_periods``). program:
        a compiled command profile ``(kind, P, times, values, BT, Bq)`` or None (u held); B (nv, nu), or no
        rows (u is τ_app); t_end (K,) the periods' ends; srv: None, or a joint servo (:mod:`.servo`), whose
        outputs go to SVs (K, ns, 6) when it has rows; tol: see :meth:`integrate_arm`; CPs (K, np, NP): every
        contact point's outputs at each period's end, when it has rows (None: not kept). Returns ``(k, code,
        step)``. Between two calls a run on backend 'auto' takes up the
        model's generated code (:meth:`poll_generated`)."""
        import time
        self.poll_generated()
        if program is None:
            e2 = np.zeros((0, 0))
            program = (profiles.CMD_NONE, e2, np.zeros(0), e2, e2, e2)
        kind, P, times, values, BT, Bq = program
        if SVs is None:
            SVs = np.empty((t_start.shape[0], 0, 6))
        if CPs is None:
            CPs = np.empty((t_start.shape[0], 0, contact.NP))
        ros = None
        if method == 'rosenbrock2':
            if self._ros is None:
                self._ros = arm.rosenbrock_work(self.nv, self.nr if self.coupled is not None else self.nv)
            ros = self._ros
            ctl = ros[4]
            ctl[:] = 0.0
            ctl[arm.CTL_H_MIN] = np.inf
            if tol is not None:   # rosenbrock2 under error control (arm.arm_controlled_steps)
                ctl[arm.CTL_RTOL], ctl[arm.CTL_ATOL] = float(tol[0]), float(tol[1])
                ctl[arm.CTL_MAX_STEPS] = float(tol[2]) if len(tol) > 2 and tol[2] is not None else 0.0
        generic = self.gen is None
        dyn, tokens = self.dynamics(z)
        t0 = time.perf_counter()
        out = treefn.call(arm.run_arm_periods, [
            self.mi, self.mf, self.mi_r, self.mf_r, self.damping, self.friction, self.v_s, self.lim, B, self.nq,
            FUSED_METHODS[method], z, float(dt), t_start, n_full, h_last, kind, P, times, values, BT, Bq, u, Zs, Us,
            TAUs, Fs, bool(want_f), ulim, self.con, self.cpo, Cs, CPs, t_end, srv, SVs, self.cpl, ros, dyn], 38,
            tokens)
        if generic:
            self._spent += time.perf_counter() - t0
        return out

    def servo_state(self, srv, t, q, v):
        """``(out (ns, 6), power)``: the joint servo (:mod:`.servo`) at time t and (q, v): per servo joint
        q*, q̇*, q̈*, the feed-forward torque, the applied torque and its saturation flag
        (``servo.servo_state``), and its power (W). The feed-forward's inverse dynamics is the one the loops take
        (:meth:`dynamics`; generic and generated give the same bits there)."""
        out = np.empty((srv[0].shape[0], 6))
        W = tree.workspace(self.nb)
        dyn, tokens = self.dynamics(_EMPTY)
        P = treefn.call(servo.servo_state, [self.mi_r, self.mf_r, self.damping, self.friction, self.v_s, srv,
                                            float(t), np.ascontiguousarray(q, dtype=float),
                                            np.ascontiguousarray(v, dtype=float), W, out, dyn], 11, tokens)
        return out, P

    def sensor_readings(self, q, v, qdd, imu, ft, f_ext=None):
        """``(imu (ni, 15), ft (nf, 6))``: IMU and force-torque readings at (q, v, q̈) (``sensors.sensor_readings``;
        imu (ni,) body indices of the full tree, ft (nf, 2) [joint's body, frame body]; f_ext (nb, 6) the
        external body forces of the dynamics, e.g. a ground's)."""
        fe, has = (self._zf, False) if f_ext is None else (np.ascontiguousarray(f_ext, dtype=float), True)
        imu = np.ascontiguousarray(imu, dtype=np.int64)
        ft = np.ascontiguousarray(ft, dtype=np.int64).reshape(-1, 2)
        out_imu = np.empty((imu.shape[0], sensors.NIMU))
        out_ft = np.empty((ft.shape[0], 6))
        sensors.sensor_readings(self.mi, self.mf, np.ascontiguousarray(q, dtype=float),
                                np.ascontiguousarray(v, dtype=float), np.ascontiguousarray(qdd, dtype=float), fe,
                                has, imu, ft, out_imu, out_ft)
        return out_imu, out_ft

    def passive_jacobian(self, q, v, h=None, t=0.0, srv=None):
        """``(D, K)`` (nv, nv) of the linearly implicit step at (q, v), tangent coordinates, as
        ``arm.arm_rosenbrock_step`` assembles them: the damping ``−∂τ_p/∂v`` and stiffness ``−∂τ_p/∂q`` of the
        passive forces (``arm.passive_jacobian``: damping, friction slope, joint-limit moments on their
        branches at (q, v)), on a ground the contacts' ``D_c, K_c`` (``contact.contact_jacobian``, as
        ``arm.contact_bias_mass`` adds them) and, with a step h (s), the gravity stiffness ``∂g/∂q`` of the
        1-DOF joints (``tree.gravity_stiffness_ws``); with a joint servo srv (:mod:`.servo`), its kp, kd on
        the joints it does not saturate at time t (``servo.servo_jacobian_add``)."""
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        if self.con is not None:
            from . import contact
            D, K = contact.contact_jacobian(self.con, self.mi_r, self.mf_r, q, v)
        else:
            D = np.zeros((self.nv, self.nv))
            K = np.zeros((self.nv, self.nv))
        arm.passive_jacobian(self.damping, self.friction, self.v_s, self.lim, q, v, q, False, D, K)
        if srv is not None:
            out, _ = self.servo_state(srv, t, q, v)
            servo.servo_jacobian_add(srv, np.ascontiguousarray(out[:, 5]), D, K)
        if h is not None:
            G = np.empty((self.nv, self.nv))
            tree.gravity_stiffness_into(self.mi_r, self.mf_r, q, G)
            K += G
        return D, K


class CompiledSystem:
    """A constrained or floating-base system packed for its kernels (:mod:`robodyn_ros.kernels.fixed_step`).

    kind: ``fixed_step.DIFFDRIVE | FREEFLYER | AUGMENTED | PRESCRIBED``; ip, fp: the system's
    parameters in the layout of that kind; model: its kinematic tree (None for the augmented
    formulation, which has its own kinematics); nq: configuration size of the system's state.
    ``km`` is the :class:`CompiledModel` of the tree (or None). The system builds the input
    vector ``u`` of its layout once per call.
    """

    def __init__(self, kind: int, ip, fp, model: Model | None, nq: int):
        if not AVAILABLE:
            raise RuntimeError(f'compiled kernels unavailable: {UNAVAILABLE_REASON}')
        self.kind = int(kind)
        self.ip = np.ascontiguousarray(ip, dtype=np.int64)
        self.fp = np.ascontiguousarray(fp, dtype=np.float64)
        self.nq = int(nq)
        self.km = CompiledModel(model) if model is not None else None
        if self.km is not None:
            self.tree = (self.km.mi, self.km.mf, self.km.mi_r, self.km.mf_r)
        else:
            mi, mf = np.zeros((1, 5), dtype=np.int64), np.zeros((2, 29))
            self.tree = (mi, mf, mi, mf)
        self.stat = np.zeros(4)
        self._evaluate, self._project, self._integrate = fixed_step.ENTRY_POINTS[self.kind]
        #: integrator names its fused loop runs: the linearly implicit one only where the kind has a
        #: passive Jacobian (the differential drive's motors); elsewhere rosenbrock2 takes the generic path
        self.methods = tuple(m for m in FUSED_METHODS if m != 'rosenbrock2' or self.kind == fixed_step.DIFFDRIVE)

    def evaluate(self, t, y, u):
        """``[dy/dt; input power]`` (ny + 1,) at (t, y) under the input vector u.

        Raises ``numpy.linalg.LinAlgError`` when a mass matrix is not positive definite.
        """
        z = np.empty(y.shape[0] + 1)
        z[:-1] = y
        z[-1] = 0.0
        dz = np.empty_like(z)
        if self._evaluate(self.ip, self.fp, *self.tree, u, self.nq, float(t), z, dz, self.stat) != linalg.OK:
            raise np.linalg.LinAlgError('mass matrix is not positive definite')
        return dz

    def project(self, y):
        """The system's projection of y (ny,) in place; returns y."""
        if self._project(self.ip, self.fp, *self.tree, self.nq, y) != linalg.OK:
            raise np.linalg.LinAlgError('mass matrix is not positive definite')
        return y

    def integrate(self, method: str, z, u, t0, dt, n_full, h_last) -> int:
        """Fused fixed-step integration of ``z = [y, W]`` in place (``fixed_step.integrate_<kind>``).

        Returns its code: -1, the first non-finite step, or ``-2 - k`` for a singular mass
        matrix in step k. ``stat`` (4,) collects the prescribed-path singularity counters.
        """
        return self._integrate(self.ip, self.fp, *self.tree, u, self.nq, FUSED_METHODS[method], z, float(t0),
                               float(dt), int(n_full), float(h_last), self.stat)


def warmup(model: Model | None = None) -> float:
    """Load (or compile, on a cold cache) every kernel by calling it once; returns seconds taken."""
    import time
    from ..model import random_tree
    t0 = time.perf_counter()
    if not AVAILABLE:
        return 0.0
    if model is None:
        model = random_tree(3, np.random.default_rng(0))
    km = CompiledModel(model)
    q = model.neutral()
    v = np.zeros(model.nv)
    km.aba(q, v, v)
    km.aba(q, v, v, np.zeros((model.nb, 6)))
    km.rnea(q, v, v)
    km.rnea_wrenches(q, v, v)
    km.rnea(q, v, v, np.zeros((model.nb, 6)))
    km.crba(q)
    km.joint_wrenches(q, v, v)
    from .outputs import joint_wrenches_many   # the recorder's batches
    joint_wrenches_many(km, q[None], v[None], v[None])
    km.energies(q, v)
    km.qdot(q, v)
    km.normalize(q)
    for m in FUSED_METHODS:   # (the per-period path; the block path passes the same argument types)
        z = np.concatenate([q, v, [0.0]])
        km.integrate_arm(m, z, v, 1e-3, 2, 0.0)
    return time.perf_counter() - t0
