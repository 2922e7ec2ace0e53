"""Mass properties of solid shapes at a uniform density: what a URDF link without ``<inertial>`` weighs.

A kinematic-only URDF (many industrial arms' descriptions) gives its links geometry but no
``<inertial>``. MuJoCo's compiler then infers each body's mass and inertia from its geoms
(``inertiafromgeom``, density 1000 kg/m³ unless told otherwise); :func:`robodyn_ros.urdf.read_urdf`
does the same here, from a link's ``<collision>`` shapes (else its ``<visual>`` shapes), each a solid
of :data:`DENSITY` (water), summed as rigid bodies (overlaps counted twice, as MuJoCo does):

* box ``(x, y, z)``: ``m = ρ x y z``, ``I = m/12 diag(y² + z², x² + z², x² + y²)``;
* cylinder ``(r, L)`` along z: ``m = ρ π r² L``, ``I = diag(m (3 r² + L²)/12, same, m r²/2)``;
* sphere ``(r,)``: ``m = ρ 4/3 π r³``, ``I = 2/5 m r² 1``;
* capsule ``(r, L)`` along z (L between the end spheres' centres): the cylinder plus two hemispheres
  of total mass ``m_s = ρ 4/3 π r³``, each hemisphere's centroid ``3 r / 8`` beyond its flat face:
  ``I_zz = m_c r²/2 + 2/5 m_s r²``, ``I_xx = m_c (3 r² + L²)/12 + m_s (2 r²/5 + L²/4 + 3 r L/8)``;
* mesh: the solid convex hull of its vertices (MuJoCo's ``<mesh inertia="convex">``, its recommended
  mode; a closed non-convex part then weighs more than it does, never less), its vertices read by
  :func:`robodyn_ros.meshes.mesh_vertices`, times the mesh's scale. The hull is cut into tetrahedra
  from an interior point; a tetrahedron of volume V with vertices ``v_k`` has the second moment
  ``∫ x xᵀ dV = V/20 (Σ v_k v_kᵀ + s sᵀ)``, ``s = Σ v_k`` (Tonon 2004).

Frames: a shape's properties are in its own frame (centred; cylinder and capsule along z); its
``<origin>`` places it in the link frame. Results are ``(mass kg, com (3,) m, inertia (3, 3) kg·m²
about the com)``.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['DENSITY', 'shape_properties', 'hull_properties', 'combine']

#: kg/m³ of the solids inferred for links without ``<inertial>`` (water; MuJoCo's default geom density)
DENSITY = 1000.0


def shape_properties(kind: str, size, density: float = DENSITY, vertices=None):
    """``(m, c (3,), I (3, 3) about c)`` of one primitive in its own frame (module docstring).

    kind: 'box' | 'cylinder' | 'sphere' | 'capsule' | 'mesh'; size: the URDF sizes (box edges, radius,
    length); vertices: (n, 3) of a mesh (already scaled). Raises ValueError for a mesh whose hull has
    no volume (fewer than 4 points off a plane).
    """
    rho = float(density)
    if kind == 'box':
        x, y, z = (float(s) for s in size)
        m = rho * x * y * z
        return m, np.zeros(3), m / 12.0 * np.diag([y * y + z * z, x * x + z * z, x * x + y * y])
    if kind == 'cylinder':
        r, L = (float(s) for s in size)
        m = rho * math.pi * r * r * L
        t = m * (3.0 * r * r + L * L) / 12.0
        return m, np.zeros(3), np.diag([t, t, 0.5 * m * r * r])
    if kind == 'sphere':
        r = float(size[0])
        m = rho * 4.0 / 3.0 * math.pi * r ** 3
        return m, np.zeros(3), 0.4 * m * r * r * np.eye(3)
    if kind == 'capsule':
        r, L = (float(s) for s in size)
        mc = rho * math.pi * r * r * L
        ms = rho * 4.0 / 3.0 * math.pi * r ** 3
        t = mc * (3.0 * r * r + L * L) / 12.0 + ms * (0.4 * r * r + 0.25 * L * L + 0.375 * r * L)
        return mc + ms, np.zeros(3), np.diag([t, t, 0.5 * mc * r * r + 0.4 * ms * r * r])
    if kind == 'mesh':
        return hull_properties(vertices, rho)
    raise ValueError(f'no mass properties for a {kind!r} shape')


def hull_properties(vertices, density: float = DENSITY):
    """``(m, c (3,), I (3, 3) about c)`` of the solid convex hull of ``vertices`` (n, 3) at ``density``.

    Raises ValueError when the hull has no volume."""
    from scipy.spatial import ConvexHull, QhullError
    v = np.asarray(vertices, dtype=float).reshape(-1, 3)
    v = v[np.all(np.isfinite(v), axis=1)]
    if len(v) < 4:
        raise ValueError(f'{len(v)} vertices span no volume')
    o = v.mean(axis=0)
    try:
        hull = ConvexHull(v - o)
    except QhullError as e:
        raise ValueError(f'its vertices span no volume ({str(e).splitlines()[0][:80]})') from None
    p = hull.points
    inside = p[hull.vertices].mean(axis=0)   # interior: the mean of the hull's vertices
    a, b, c = (p[hull.simplices[:, k]] - inside for k in range(3))
    vol = np.abs(np.einsum('ij,ij->i', a, np.cross(b, c))) / 6.0
    V = float(vol.sum())
    if not V > 0.0:
        raise ValueError('its vertices span no volume')
    s = a + b + c                                     # the 4th vertex is the origin (the interior point)
    cen = (vol[:, None] * s / 4.0).sum(axis=0) / V   # volume-weighted tetrahedron centroids
    C = np.einsum('t,tij->ij', vol / 20.0, np.einsum('ti,tj->tij', a, a) + np.einsum('ti,tj->tij', b, b)
                  + np.einsum('ti,tj->tij', c, c) + np.einsum('ti,tj->tij', s, s))
    m = density * V
    C = density * C - m * np.outer(cen, cen)          # second moment about the centroid
    I = np.trace(C) * np.eye(3) - C
    return m, cen + inside + o, 0.5 * (I + I.T)


def combine(parts):
    """``(m, c (3,), I (3, 3) about c)`` of rigid parts ``[(m, c, I, R (3, 3), p (3,))]``, each given
    in its own frame placed at ``(R, p)`` in the common frame (parallel-axis theorem)."""
    M = sum(float(m) for m, *_ in parts)
    if not M > 0.0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    cw = [np.asarray(R) @ np.asarray(c) + np.asarray(p) for _, c, _, R, p in parts]
    com = sum(float(m) * x for (m, *_), x in zip(parts, cw)) / M
    I = np.zeros((3, 3))
    for (m, _, Ic, R, _), x in zip(parts, cw):
        d = x - com
        I += np.asarray(R) @ np.asarray(Ic) @ np.asarray(R).T + float(m) * (d @ d * np.eye(3) - np.outer(d, d))
    return M, com, 0.5 * (I + I.T)
