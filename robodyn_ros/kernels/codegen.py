"""Scene-specialised forward dynamics: the "method of Zs" (Kane & Levinson 1983; seed 002).

For one model, the articulated-body algorithm of :mod:`robodyn_ros.kernels.tree` is run once on
*symbols*: every constant of the model (joint axes, tree transforms, inertias, gravity) is a
number, every quantity that depends on the state is a named intermediate ``z<k>``. Arithmetic
on numbers is done at generation time, products with an exact zero vanish and products with
±1 become sign flips, so what is left is straight-line code in which every common
sub-expression is evaluated once per call (the "Zs"). A DH arm's tree transforms are signed
permutations (``α = ±π/2``), so most of the 3x3 products of the generic kernel disappear.

Coefficients within ``SNAP`` (about 4.5 machine epsilon) of 0 or ±1 — the rounding residue of
``cos(π/2)`` in a DH table — are snapped to exactly 0 or ±1 before folding; the result then
differs from the reference by rounding only (tested to 1e-12 with the other kernels).

The generated module (``aba(q, v, tau, qdd)``; ``rnea_bias(q, v, out)`` and ``crba(q, H, G)`` -- the
mass matrix and the gravity stiffness -- for models whose code stays within :data:`MASS_LINES`; and
``arm_rhs``/``arm_bias_mass``/``integrate_arm``/``arm_steps``/``arm_rosenbrock_step`` — the last three
the unchanged source of :mod:`robodyn_ros.kernels.arm`, bound to the generated ``arm_rhs`` and
``arm_bias_mass``) is written once per model to :data:`GENERATED_DIR` under a name made from a
hash of the packed model, this generator and the kernels' source (``tree.py``, ``arm.py``, ...),
and numba caches its machine code beside it, so the second start of the same scene loads it.
Trees with FREE or SPHERICAL joints, with mimic joints (:mod:`robodyn_ros.kernels.coupled`), or
with a joint whose articulated inertia is the constant 0 are not specialised (:func:`specialize`
returns None, or :class:`robodyn_ros.kernels.CompiledModel` does not ask; the generic kernels
handle them).
"""
from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys

import numpy as np

from ..model import FIXED, FREE, PRISMATIC, REVOLUTE, SPHERICAL

#: generated lines of the bias and mass matrix above which a model keeps the generic ones (numba's
#: compile time grows faster than the code: tiago's 16 000 lines took minutes; xarm7's 1 750 seconds)
MASS_LINES = 4000
#: relative distance to 0 or ±1 under which a model coefficient is snapped
SNAP = 1e-15
VERSION = '2'


def _generated_dir() -> str:
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return os.environ.get('ROBODYN_GENERATED_DIR') or os.path.join(base, 'robodyn_ros', 'generated')


#: where generated modules (and numba's cache of them) live; ROBODYN_GENERATED_DIR overrides
GENERATED_DIR = _generated_dir()


def _snap(x: float, scale: float = 1.0) -> float:
    """x with rounding residue removed: exactly 0 or ±1 when within SNAP of them."""
    x = float(x)
    if abs(x) <= SNAP * scale:
        return 0.0
    if abs(x - 1.0) <= SNAP:
        return 1.0
    if abs(x + 1.0) <= SNAP:
        return -1.0
    return x


def _fmt(x) -> str:
    """A value in generated code: a float literal (exact repr) or a name."""
    return repr(x) if isinstance(x, float) else x


class _Zs:
    """Emits ``z<k> = <expression>`` lines; values are floats (known) or names (computed)."""

    def __init__(self):
        self.lines = []
        self.n = 0

    def z(self, expr: str) -> str:
        name = f'z{self.n}'
        self.n += 1
        self.lines.append(f'    {name} = {expr}')
        return name

    def sp(self, terms, const=0.0):
        """``const + Σ coef·a·b`` over ``terms = [(coef, a, b), ...]`` (b may be None), folded.

        Returns a float when everything is known, a name otherwise.
        """
        parts = []
        for coef, a, b in terms:
            factors = [f for f in (a, b) if f is not None]
            for f in list(factors):
                if isinstance(f, float):
                    coef *= f
                    factors.remove(f)
            if coef == 0.0:
                continue
            if not factors:
                const += coef
                continue
            body = ' * '.join(factors)
            if coef == 1.0:
                parts.append(('+', body))
            elif coef == -1.0:
                parts.append(('-', body))
            else:
                parts.append(('+', f'{coef!r} * {body}'))
        if not parts:
            return const
        expr = ('-' if parts[0][0] == '-' else '') + parts[0][1]
        for sign, body in parts[1:]:
            expr += f' {sign} {body}'
        if const != 0.0:
            expr += f' + {const!r}' if const > 0 else f' - {-const!r}'
        return self.z(expr)

    def add(self, a, b):
        return self.sp([(1.0, a, None), (1.0, b, None)])

    def sub(self, a, b):
        return self.sp([(1.0, a, None), (-1.0, b, None)])

    def mul(self, a, b):
        return self.sp([(1.0, a, b)])

    def div(self, a, b):
        if isinstance(a, float) and isinstance(b, float):
            return a / b
        if a == 0.0:
            return 0.0
        return self.z(f'{_fmt(a)} / {_fmt(b)}')


# ----------------------------------------------------------------------------------------------
# symbolic spatial arithmetic (the formulas of tree.py, on lists of values)
# ----------------------------------------------------------------------------------------------
def _cross(Z, a, b):
    """``a × b`` for 3-lists."""
    return [Z.sp([(1.0, a[1], b[2]), (-1.0, a[2], b[1])]), Z.sp([(1.0, a[2], b[0]), (-1.0, a[0], b[2])]),
            Z.sp([(1.0, a[0], b[1]), (-1.0, a[1], b[0])])]


def _mat3_vec(Z, E, x, transpose=False):
    """``E x`` (or ``Eᵀ x``) for a 3x3 list of lists."""
    if transpose:
        return [Z.sp([(1.0, E[k][a], x[k]) for k in range(3)]) for a in range(3)]
    return [Z.sp([(1.0, E[a][k], x[k]) for k in range(3)]) for a in range(3)]


def _xmot(Z, E, r, m):
    """``X m`` (motion): ``[E w; E (u - r × w)]``."""
    w, u = m[:3], m[3:]
    rw = _cross(Z, r, w)
    return _mat3_vec(Z, E, w) + _mat3_vec(Z, E, [Z.sub(u[a], rw[a]) for a in range(3)])


def _xforce_T(Z, E, r, f):
    """``Xᵀ f`` (force, child -> parent): ``[Eᵀ n + r × Eᵀ f; Eᵀ f]``."""
    g = _mat3_vec(Z, E, f[3:], transpose=True)
    n = _mat3_vec(Z, E, f[:3], transpose=True)
    rg = _cross(Z, r, g)
    return [Z.add(n[a], rg[a]) for a in range(3)] + g


def _cross_motion(Z, v, m):
    """``v × m``: ``[w × mw; w × mu + u × mw]``."""
    w, u = v[:3], v[3:]
    a = _cross(Z, w, m[:3])
    b1, b2 = _cross(Z, w, m[3:]), _cross(Z, u, m[:3])
    return a + [Z.add(b1[k], b2[k]) for k in range(3)]


def _cross_force(Z, v, f):
    """``v ×* f``: ``[w × n + u × f; w × f]``."""
    w, u = v[:3], v[3:]
    a1, a2 = _cross(Z, w, f[:3]), _cross(Z, u, f[3:])
    return [Z.add(a1[k], a2[k]) for k in range(3)] + _cross(Z, w, f[3:])


def _mat_vec6(Z, A, x):
    return [Z.sp([(1.0, A[a][b], x[b]) for b in range(6)]) for a in range(6)]


def _etxe(Z, E, X, sym):
    """``Eᵀ X E`` (3x3 lists); only the upper triangle is computed when ``sym``."""
    M = [[Z.sp([(1.0, X[a][k], E[k][b]) for k in range(3)]) for b in range(3)] for a in range(3)]
    out = [[None] * 3 for _ in range(3)]
    for a in range(3):
        for b in range(a if sym else 0, 3):
            out[a][b] = Z.sp([(1.0, E[k][a], M[k][b]) for k in range(3)])
            if sym:
                out[b][a] = out[a][b]
    return out


def _xinertia_T(Z, E, r, A):
    """``Xᵀ A X`` for a symmetric 6x6 list A (see tree.xinertia_T_add for the formulas)."""
    P = _etxe(Z, E, [row[:3] for row in A[:3]], True)
    Q = _etxe(Z, E, [row[3:] for row in A[:3]], False)
    R = _etxe(Z, E, [row[3:] for row in A[3:]], True)
    Zm = [[None] * 3 for _ in range(3)]         # Z = r× R, columns r × R[:, b]
    for b in range(3):
        col = _cross(Z, r, [R[0][b], R[1][b], R[2][b]])
        for a in range(3):
            Zm[a][b] = col[a]
    Y = [_cross(Z, Q[a], r) for a in range(3)]  # rows Q[a] × r
    W = [_cross(Z, Zm[a], r) for a in range(3)]  # rows Z[a] × r
    out = [[None] * 6 for _ in range(6)]
    for a in range(3):
        for b in range(a, 3):
            out[a][b] = out[b][a] = Z.sp([(1.0, P[a][b], None), (-1.0, Y[a][b], None), (-1.0, Y[b][a], None),
                                          (-1.0, W[a][b], None)])
        for b in range(3):
            out[a][3 + b] = out[3 + b][a] = Z.add(Q[a][b], Zm[a][b])
            out[3 + a][3 + b] = R[a][b]
    return out


# ----------------------------------------------------------------------------------------------
# the specialised articulated-body algorithm
# ----------------------------------------------------------------------------------------------
def _joint(Z, jt, k, Et, rt, qk):
    """``(E, r)`` of ``XJ(q) Xtree`` as lists; Rodrigues ``J = k kᵀ + c (1 - k kᵀ) - s k×``."""
    if jt == REVOLUTE:
        c, s = Z.z(f'math.cos({qk})'), Z.z(f'math.sin({qk})')
        kk = np.outer(k, k)
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        al, be, ga = kk @ Et, (np.eye(3) - kk) @ Et, -kx @ Et
        E = [[Z.sp([(_snap(be[a, b]), c, None), (_snap(ga[a, b]), s, None)], _snap(al[a, b])) for b in range(3)]
             for a in range(3)]
        return E, [_snap(x, max(1.0, np.abs(rt).max())) for x in rt]
    E = [[_snap(Et[a, b]) for b in range(3)] for a in range(3)]
    scale = max(1.0, np.abs(rt).max())
    if jt == PRISMATIC:
        d = Et.T @ k
        return E, [Z.sp([(_snap(d[a]), qk, None)], _snap(rt[a], scale)) for a in range(3)]
    return E, [_snap(x, scale) for x in rt]


def _body(Z, a, i):
    """Body i of the merged tree ``a``: ``(E, r)`` of ``Xup(q)`` (its joint's lines emitted), the motion
    subspace S (6-list, None for FIXED), the spatial inertia (6x6 lists, snapped) and the v index."""
    jt = int(a['jtype'][i])
    X = a['Xtree'][i]
    Et = X[:3, :3]
    rx = -(Et.T @ X[3:, :3])
    rt = np.array([rx[2, 1], rx[0, 2], rx[1, 0]])
    k = np.array([_snap(x) for x in a['axis'][i]])
    qi, vi = int(a['q_idx'][i]), int(a['v_idx'][i])
    E, r = _joint(Z, jt, k, Et, rt, f'q[{qi}]' if jt != FIXED else None)
    S = (list(k) + [0.0] * 3 if jt == REVOLUTE else [0.0] * 3 + list(k)) if jt != FIXED else None
    Ii = [[_snap(x, max(1.0, np.abs(a['I'][i]).max())) for x in row] for row in a['I'][i]]
    return E, r, S, Ii, vi


def _merged_or_none(model):
    """The merged tree (:func:`merge_fixed`) of a model without FREE or SPHERICAL joints, else None."""
    from . import merge_fixed
    a = merge_fixed(model)
    if np.any(a['jtype'] == FREE) or np.any(a['jtype'] == SPHERICAL):
        return None  # the generic kernels compute these trees
    return a


def _assign(target: str, value) -> str:
    """A line ``target = value`` of the generated function body."""
    return f'    {target} = {value!r}' if isinstance(value, float) else f'    {target} = {value}'


def bias_source(model) -> str | None:
    """Source of ``rnea_bias(q, v, out)``: ``out = C(q, v) + g(q)`` = RNEA at zero acceleration (book
    Table 5.1, gravity as the base acceleration), specialised to ``model``; None for FREE/SPHERICAL trees."""
    a = _merged_or_none(model)
    if a is None:
        return None
    nb = len(a['parent'])
    Z = _Zs()
    g = a['gravity']
    a0 = [0.0, 0.0, 0.0, -float(g[0]), -float(g[1]), -float(g[2])]
    E, r, S, vb, ab, f = [None] * nb, [None] * nb, [None] * nb, [None] * nb, [None] * nb, [None] * nb
    vidx = [0] * nb
    for i in range(nb):
        jt, p = int(a['jtype'][i]), int(a['parent'][i])
        E[i], r[i], S[i], Ii, vidx[i] = _body(Z, a, i)
        vJ = [Z.mul(S[i][x], f'v[{vidx[i]}]') for x in range(6)] if jt != FIXED else [0.0] * 6
        if p < 0:
            vb[i], ab[i] = vJ, _xmot(Z, E[i], r[i], a0)
        else:
            vm = _xmot(Z, E[i], r[i], vb[p])
            vb[i] = [Z.add(vm[x], vJ[x]) for x in range(6)]
            am = _xmot(Z, E[i], r[i], ab[p])
            cm = _cross_motion(Z, vb[i], vJ)
            ab[i] = [Z.add(am[x], cm[x]) for x in range(6)]
        Ia = _mat_vec6(Z, Ii, ab[i])
        fv = _cross_force(Z, vb[i], _mat_vec6(Z, Ii, vb[i]))
        f[i] = [Z.add(Ia[x], fv[x]) for x in range(6)]
    out = []
    for i in range(nb - 1, -1, -1):
        jt, p = int(a['jtype'][i]), int(a['parent'][i])
        if jt != FIXED:
            out.append(_assign(f'out[{vidx[i]}]', Z.sp([(1.0, S[i][x], f[i][x]) for x in range(6)])))
        if p >= 0:
            fp = _xforce_T(Z, E[i], r[i], f[i])
            f[p] = [Z.add(f[p][x], fp[x]) for x in range(6)]
    head = ['@njit(**_JIT)', 'def rnea_bias(q, v, out):',
            f'    """C(q, v) + g(q) of {model.name!r} (RNEA at zero acceleration): {Z.n} intermediates."""']
    return '\n'.join(head + Z.lines + out) + '\n'


def _gravity_stiffness(Z, a, E, S, IC, vidx) -> dict:
    """``{(i, j): G_ij}`` of ``G = ∂g/∂q`` from the composite inertias IC (6x6 lists), the formulas of
    :func:`robodyn_ros.kernels.tree.gravity_stiffness_ws` on symbols (γ per body, x carried to the root)."""
    nb = len(a['parent'])
    g = [float(x) for x in a['gravity']]
    gb = [None] * nb
    for i in range(nb):
        p = int(a['parent'][i])
        gb[i] = _mat3_vec(Z, E[i], g if p < 0 else gb[p])
    G = {}
    for i in range(nb):
        jt = int(a['jtype'][i])
        if jt not in (REVOLUTE, PRISMATIC):
            continue
        k = S[i][:3] if jt == REVOLUTE else S[i][3:]
        if jt == REVOLUTE:   # IC = [Ī, h×; h×ᵀ, m 1]: h = (−IC[1][5], IC[0][5], −IC[0][4])
            h = [Z.sp([(-1.0, IC[i][1][5], None)]), IC[i][0][5], Z.sp([(-1.0, IC[i][0][4], None)])]
            x = _cross(Z, k, h)
        else:
            x = [Z.mul(k[c], IC[i][3][3]) for c in range(3)]
        j = i
        while j >= 0:
            if int(a['jtype'][j]) == REVOLUTE:
                ax = _cross(Z, S[j][:3], x)
                val = Z.sp([(-1.0, gb[j][c], ax[c]) for c in range(3)])
                for key in {(vidx[i], vidx[j]), (vidx[j], vidx[i])}:
                    G[key] = val if key not in G else Z.add(G[key], val)
            p = int(a['parent'][j])
            if p >= 0:
                x = _mat3_vec(Z, E[j], x, transpose=True)
            j = p
    return G


def crba_source(model) -> str | None:
    """Source of ``crba(q, H)``: the joint-space inertia matrix M(q) (nv, nv) by the composite-rigid-body
    algorithm (book Table 6.2) with the joints' armature on its diagonal, specialised to ``model``; every
    entry written; None for FREE/SPHERICAL trees."""
    a = _merged_or_none(model)
    if a is None:
        return None
    nb = len(a['parent'])
    Z = _Zs()
    E, r, S, IC = [None] * nb, [None] * nb, [None] * nb, [None] * nb
    vidx = [0] * nb
    for i in range(nb):
        E[i], r[i], S[i], Ii, vidx[i] = _body(Z, a, i)
        IC[i] = [list(row) for row in Ii]
    for i in range(nb - 1, -1, -1):
        p = int(a['parent'][i])
        if p >= 0:
            T = _xinertia_T(Z, E[i], r[i], IC[i])
            IC[p] = [[Z.add(IC[p][x][y], T[x][y]) if y >= x else None for y in range(6)] for x in range(6)]
            for x in range(6):
                for y in range(x):
                    IC[p][x][y] = IC[p][y][x]
    H = {}
    for i in range(nb):
        if int(a['jtype'][i]) == FIXED:
            continue
        F = [Z.sp([(1.0, IC[i][x][y], S[i][y]) for y in range(6)]) for x in range(6)]
        H[vidx[i], vidx[i]] = Z.sp([(1.0, S[i][x], F[x]) for x in range(6)], float(a['armature'][i]))
        j = i
        while int(a['parent'][j]) >= 0:
            F = _xforce_T(Z, E[j], r[j], F)
            j = int(a['parent'][j])
            if int(a['jtype'][j]) != FIXED:
                H[vidx[j], vidx[i]] = H[vidx[i], vidx[j]] = Z.sp([(1.0, S[j][x], F[x]) for x in range(6)])
    G = _gravity_stiffness(Z, a, E, S, IC, vidx)
    nv = model.nv
    out = [_assign(f'H[{x}, {y}]', H.get((x, y), 0.0)) for x in range(nv) for y in range(nv)]
    out += [_assign(f'G[{x}, {y}]', G.get((x, y), 0.0)) for x in range(nv) for y in range(nv)]
    head = ['@njit(**_JIT)', 'def crba(q, H, G):',
            f'    """M(q) of {model.name!r} (composite-rigid-body algorithm) and the gravity stiffness G = ∂g/∂q '
            f'(tree.gravity_stiffness_ws): {Z.n} intermediates."""']
    return '\n'.join(head + Z.lines + out) + '\n'


def aba_source(model) -> str | None:
    """Python source of ``aba(q, v, tau, qdd)`` specialised to ``model`` (a joint's armature added to its
    ``d``, as in :func:`robodyn_ros.kernels.tree.aba_ws`), or None (FREE or SPHERICAL
    joints, or a joint whose articulated inertia ``d = Sᵀ IA S`` is the constant 0: its mass matrix is
    singular everywhere, which the generic kernels' caller reports)."""
    a = _merged_or_none(model)
    if a is None:
        return None
    nb = len(a['parent'])
    Z = _Zs()
    E, r, vb, c, IA, pA = [None] * nb, [None] * nb, [None] * nb, [None] * nb, [None] * nb, [None] * nb
    S = [None] * nb
    for i in range(nb):                         # pass 1
        jt, p = int(a['jtype'][i]), int(a['parent'][i])
        E[i], r[i], S[i], Ii, vi = _body(Z, a, i)
        vJ = [Z.mul(S[i][x], f'v[{vi}]') for x in range(6)] if jt != FIXED else [0.0] * 6
        if p < 0:
            vb[i], c[i] = vJ, [0.0] * 6
        else:
            vm = _xmot(Z, E[i], r[i], vb[p])
            vb[i] = [Z.add(vm[x], vJ[x]) for x in range(6)]
            c[i] = _cross_motion(Z, vb[i], vJ)
        IA[i] = [list(row) for row in Ii]
        pA[i] = _cross_force(Z, vb[i], _mat_vec6(Z, Ii, vb[i]))
    U, d, u = [None] * nb, [None] * nb, [None] * nb
    for i in range(nb - 1, -1, -1):             # pass 2
        jt, p = int(a['jtype'][i]), int(a['parent'][i])
        if jt == FIXED:
            if p >= 0:
                Ia, pa = IA[i], pA[i]
        else:
            vi = int(a['v_idx'][i])
            U[i] = [Z.sp([(1.0, IA[i][x][y], S[i][y]) for y in range(6)]) for x in range(6)]
            d[i] = Z.sp([(1.0, S[i][x], U[i][x]) for x in range(6)], float(a['armature'][i]))   # + the armature
            if isinstance(d[i], float) and d[i] == 0.0:
                return None  # no inertia about this axis in any configuration: the generic kernels (and the
                #              simulator's preflight, which names the joint) take the model
            u[i] = Z.sp([(-1.0, S[i][x], pA[i][x]) for x in range(6)] + [(1.0, f'tau[{vi}]', None)])
            if p >= 0:
                dinv = Z.div(1.0, d[i])
                Ud = [Z.mul(U[i][x], dinv) for x in range(6)]
                Ia = [[Z.sp([(1.0, IA[i][x][y], None), (-1.0, Ud[x], U[i][y])]) if y >= x else None
                       for y in range(6)] for x in range(6)]
                for x in range(6):
                    for y in range(x):
                        Ia[x][y] = Ia[y][x]
                ud = Z.mul(u[i], dinv)
                pa = [Z.sp([(1.0, pA[i][x], None), (1.0, U[i][x], ud)] + [(1.0, Ia[x][y], c[i][y]) for y in range(6)])
                      for x in range(6)]
        if p >= 0:
            T = _xinertia_T(Z, E[i], r[i], Ia)
            IA[p] = [[Z.add(IA[p][x][y], T[x][y]) if y >= x else None for y in range(6)] for x in range(6)]
            for x in range(6):
                for y in range(x):
                    IA[p][x][y] = IA[p][y][x]
            f = _xforce_T(Z, E[i], r[i], pa)
            pA[p] = [Z.add(pA[p][x], f[x]) for x in range(6)]
    g = a['gravity']
    a0 = [0.0, 0.0, 0.0, -float(g[0]), -float(g[1]), -float(g[2])]
    ab = [None] * nb
    out = []
    for i in range(nb):                         # pass 3
        jt, p = int(a['jtype'][i]), int(a['parent'][i])
        am = _xmot(Z, E[i], r[i], a0 if p < 0 else ab[p])
        ab[i] = [Z.add(am[x], c[i][x]) for x in range(6)]
        if jt != FIXED:
            vi = int(a['v_idx'][i])
            Ua = Z.sp([(1.0, U[i][x], ab[i][x]) for x in range(6)])
            qdd = Z.div(Z.sub(u[i], Ua), d[i])
            out.append(f'    qdd[{vi}] = {qdd!r}' if isinstance(qdd, float) else f'    qdd[{vi}] = {qdd}')
            ab[i] = [Z.sp([(1.0, ab[i][x], None), (1.0, S[i][x], qdd)]) for x in range(6)]
    head = ['@njit(**_JIT)', 'def aba(q, v, tau, qdd):',
            f'    """Forward dynamics of {model.name!r} ({nb} bodies, {model.nv} dof): {Z.n} intermediates."""']
    return '\n'.join(head + Z.lines + out) + '\n'


_RHS = '''

@njit(**_JIT)
def arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, dz, tauv, W, cpl, cs, con, fx, t, srv):
    """``dz/dt`` for ``z = [q, v, W]`` or ``[q, v, W, W_lim]`` with the specialised ``aba`` (see arm.arm_rhs;
    a tree with mimic joints or ground contacts is never specialised, so cpl, cs, con and fx go unused; the
    joint servo srv at time t is arm.py's)."""
    q = z[:nq]
    v = z[nq:nq + nv]
    qdot_into(mi, q, v, dz[:nq])
    P = arm_forces(damping, friction, v_s, lim, tau_app, nq, nv, z, dz, tauv)
    if srv is not None:
        P += servo_forces_add(mi, mf, damping, friction, v_s, srv, t, q, v, tauv, W)
    aba(q, v, tauv, dz[nq:nq + nv])
    dz[nq + nv] = P


'''

_BIAS_MASS = '''

@njit(**_JIT)
def arm_bias_mass(mi, mf, q, v, zero, bias, H, G, W):
    """``bias = C(q, v) + g(q)``, ``H = M(q)`` and ``G = ∂g/∂q`` with the specialised ``rnea_bias`` and ``crba``
    (see arm.arm_bias_mass)."""
    rnea_bias(q, v, bias)
    crba(q, H, G)


'''


def module_source(model) -> str | None:
    """The whole generated module for ``model`` (None when :func:`aba_source` declines it)."""
    from . import arm
    body = aba_source(model)
    if body is None:
        return None
    mass = bias_source(model) + '\n\n' + crba_source(model)
    if mass.count('\n') <= MASS_LINES:   # else the generic arm_bias_mass (from arm.py) serves
        body += '\n\n' + mass + _BIAS_MASS
    head = (f'"""Generated by robodyn_ros.kernels.codegen {VERSION} for {model.name!r}; do not edit."""\n'
            'import math\n\nimport numpy as np\nfrom numba import njit\n\n'
            '# the fused loops below are the source of arm.py: every name they call comes from there (their own\n'
            '# arm_rhs, arm_bias_mass, integrate_arm, arm_steps, arm_rosenbrock_step, run_arm_periods are here)\n'
            'from robodyn_ros.kernels.arm import *  # noqa: F401,F403\n'
            'from robodyn_ros.kernels.tree import _JIT\n\n\n')
    # the fused loops are arm.py's source, compiled here against the generated aba, bias and crba
    return head + body + _RHS + '\n\n'.join(inspect.getsource(f) for f in (
        arm.integrate_arm, arm.arm_steps, arm.arm_rosenbrock_step, arm.run_arm_periods))


def _key(model) -> str:
    """Hash of everything the generated code depends on: packed model, generator, the kernels it
    imports or copies (tree.py, arm.py, profiles.py, fixed_step.py, coupled.py, passive.py, rosenbrock.py,
    linalg.py, contact.py, servo.py)."""
    from . import arm, contact, coupled, fixed_step, linalg, pack_model, passive, profiles, rosenbrock, servo, tree
    mi, mf = pack_model(model, merge=True)
    h = hashlib.sha256()
    with open(__file__, 'rb') as f:
        generator = f.read()
    for part in (mi.tobytes(), mf.tobytes(), VERSION.encode(), *(inspect.getsource(m).encode() for m in
                                                                  (tree, arm, profiles, fixed_step, coupled,
                                                                   passive, rosenbrock, linalg, contact, servo)),
                 generator):
        h.update(part)
    return h.hexdigest()[:20]


_LOADED: dict = {}


def specialize(model):
    """The generated module for ``model`` (written and compiled on first use), or None.

    Returns None for trees with FREE or SPHERICAL joints. The module has ``aba(q, v, tau, qdd)``,
    ``integrate_arm(mi, mf, damping, friction, v_s, lim, tau_app, nq, method, z, dt, n_full, h_last, cpl,
    con, t0, srv)`` with the arguments of :func:`robodyn_ros.kernels.arm.integrate_arm` (mi/mf: the merged packing) and
    ``run_arm_periods`` with those of :func:`robodyn_ros.kernels.arm.run_arm_periods`.
    """
    key = _key(model)
    if key in _LOADED:
        return _LOADED[key]
    path = os.path.join(GENERATED_DIR, f'robodyn_gen_{key}.py')
    if not os.path.exists(path):
        src = module_source(model)
        if src is None:
            _LOADED[key] = None
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
    name = f'robodyn_gen_{key}'
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # numba's cache re-imports the module by name when it loads
    spec.loader.exec_module(mod)
    _LOADED[key] = mod
    return mod
