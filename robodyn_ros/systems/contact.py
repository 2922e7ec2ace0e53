"""Ground contact of a tree (:class:`robodyn_ros.systems.arm.ArmSystem`): the ground's parameters,
its contact points, their packing for the compiled law (:mod:`robodyn_ros.kernels.contact`) and the
outputs: one wrench per touching link, diagnostics.

**Points per collision primitive** (:func:`collision_points`; a link's ``<collision>`` shapes, or the
scene's explicit ``contacts`` list):

* sphere: itself (its contact point is its lowest point along the normal: exact for a plane);
* capsule: the two spheres at the ends of its segment (exact: a capsule's distance to a plane is that
  of the nearer end sphere);
* box: its 8 corners (exact for the deepest point of a box on a plane; a face resting flat is held
  at its 4 corners);
* cylinder: 8 points on each rim (:data:`RIM_POINTS`): a cylinder on its end is held at the rim's
  points, one lying on its side touches at the rim point nearest the bottom (an octagon's, up to
  ``r (1 − cos 22.5°) = 0.076 r`` above the true bottom line);
* mesh: the sphere that encloses its vertices (:func:`robodyn_ros.meshes.mesh_sphere`), with a warning.

**Outputs.** ``contact_wrenches/<link>`` (:meth:`GroundContact.wrenches`): the resultant force of the
ground on the link's touching points and the moment about their centre of pressure (the mean of the
contact points weighted by their normal forces), both in the world (root) frame's axes; frame_id =
that frame. For a link touching at one point the moment is zero. Diagnostics
(:meth:`GroundContact.diagnostics`): ``contact_active`` (points touching), ``contact_max_penetration``
(m) and ``contact_max_slip_speed`` (m/s) at the published state.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ['Ground', 'ContactPoint', 'GroundContact', 'collision_points', 'RIM_POINTS', 'ContactWarning']

#: points on each rim of a cylinder
RIM_POINTS = 8


class ContactWarning(UserWarning):
    """Contact geometry read approximately (a mesh replaced by its bounding sphere, a mesh not found)."""


@dataclass(frozen=True)
class Ground:
    """A ground plane ``{x : n·x = height}`` in the tree's root (world) frame and its contact law
    (:mod:`robodyn_ros.kernels.contact`, (C1)-(C3)).

    normal (3,): unit normal (the side bodies stay on); height (m); stiffness k (N/m per point);
    dissipation d (s/m, Hunt–Crossley); friction μ (>= 0); slip_speed v_s (m/s) of the regularised
    Coulomb friction. The field defaults are the ``ground`` scene part's defaults (the one place
    they are set; docs/contact.md states them).
    """

    normal: tuple = (0.0, 0.0, 1.0)
    height: float = 0.0
    stiffness: float = 2e4
    dissipation: float = 2.0
    friction: float = 1.0
    slip_speed: float = 1e-2

    def packed(self) -> np.ndarray:
        """``gp`` of :mod:`robodyn_ros.kernels.contact`."""
        from ..kernels.contact import NG
        gp = np.zeros(NG)
        n = np.asarray(self.normal, dtype=float)
        gp[0:3] = n / np.linalg.norm(n)
        gp[3:8] = (self.height, self.stiffness, self.dissipation, self.friction, self.slip_speed)
        return gp


@dataclass(frozen=True)
class ContactPoint:
    """A contact point of a link: ``point`` (3,) in the link frame and ``radius`` (m; 0: a point, > 0: a
    sphere of that radius centred there); ``source``: where it comes from (for messages)."""

    link: str
    point: tuple
    radius: float = 0.0
    source: str = ''


def collision_points(link: str, shape, urdf_dir=None) -> list:
    """The contact points of one :class:`robodyn_ros.model.Collision` of ``link`` (module docstring).

    A mesh that cannot be found or read gives no point and a :class:`ContactWarning`; one that can is
    replaced by its bounding sphere, with a warning saying so."""
    T = np.asarray(shape.origin, dtype=float)
    R, p = T[:3, :3], T[:3, 3]

    def at(local, radius=0.0, what=shape.kind):
        return ContactPoint(link, tuple(float(x) for x in R @ np.asarray(local, dtype=float) + p), float(radius), what)
    if shape.kind == 'sphere':
        return [at((0.0, 0.0, 0.0), shape.size[0])]
    if shape.kind == 'capsule':
        r, L = shape.size
        return [at((0.0, 0.0, s * 0.5 * L), r) for s in (-1.0, 1.0)]
    if shape.kind == 'box':
        h = 0.5 * np.asarray(shape.size, dtype=float)
        return [at(h * np.array([sx, sy, sz])) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    if shape.kind == 'cylinder':
        r, L = shape.size
        a = 2.0 * np.pi * np.arange(RIM_POINTS) / RIM_POINTS
        return [at((r * np.cos(t), r * np.sin(t), s * 0.5 * L)) for s in (-1.0, 1.0) for t in a]
    if shape.kind == 'mesh':
        from ..meshes import MeshError, mesh_sphere
        try:
            c, r = mesh_sphere(shape.mesh, shape.scale, urdf_dir)
        except MeshError as e:
            warnings.warn(ContactWarning(f'link {link!r}: collision mesh left out of the contact geometry: {e}'),
                          stacklevel=3)
            return []
        warnings.warn(ContactWarning(f'link {link!r}: collision mesh {shape.mesh.rsplit("/", 1)[-1]!r} replaced by '
                                     f'its bounding sphere (radius {r:.4g} m) for ground contact'), stacklevel=3)
        return [at(c, r, 'mesh bounding sphere')]
    raise ValueError(f'link {link!r}: unknown collision shape {shape.kind!r}')


class GroundContact:
    """A tree's contact points with a ground, packed for the compiled law, and their outputs.

    model: the tree (:class:`robodyn_ros.model.Model`); ground: :class:`Ground`; points: the
    :class:`ContactPoint` list (each on a link of the model; an unknown link raises ValueError).
    ``con`` is the packed form ``(gp, cg, cgf, cf)`` (:mod:`robodyn_ros.kernels.contact`) on the
    merged tree (fixed joints welded, as the arm's compiled loops integrate it); ``links``: the links
    with points, in model order (one ``contact_wrenches/<link>`` each); ``frame``: the world frame
    (the model's root) in which the ground lies and the wrenches are expressed.
    """

    def __init__(self, model, ground: Ground, points):
        from ..kernels import merge_fixed
        self.model, self.ground = model, ground
        index = {n: i for i, n in enumerate(model.link_names[:model.nb])}
        bad = [p.link for p in points if p.link not in index]
        if bad:
            raise ValueError(f'contact on unknown link {bad[0]!r}; links are {list(index)}')
        if not points:
            raise ValueError('no contact points')
        m = merge_fixed(model)
        host, Xh = m['host'], m['Xh']
        rows = []    # (merged body, link index, point in host coordinates (3), radius)
        for pt in points:
            i = index[pt.link]
            X = Xh[i]                    # host -> link: X = [E 0; −E r× E]
            E = X[:3, :3]
            rx = -(E.T @ X[3:, :3])
            r = np.array([rx[2, 1], rx[0, 2], rx[1, 0]])
            rows.append((int(host[i]), i, r + E.T @ np.asarray(pt.point, dtype=float), float(pt.radius)))
        order = sorted(range(len(rows)), key=lambda k: (rows[k][0], k))   # points grouped by body
        self.points = [points[k] for k in order]
        rows = [rows[k] for k in order]
        cf = np.array([[*r[2], r[3]] for r in rows], dtype=float).reshape(-1, 4)
        groups = []
        for k, r in enumerate(rows):
            if groups and groups[-1][0] == r[0]:
                groups[-1][2] = k + 1
            else:
                groups.append([r[0], k, k + 1])
        cg = np.array(groups, dtype=np.int64).reshape(-1, 3)
        cgf = np.zeros((len(groups), 4))
        for g, (_, a, b) in enumerate(groups):   # a sphere around the group's points (and their spheres)
            P = cf[a:b, :3]
            c = 0.5 * (P.min(axis=0) + P.max(axis=0))
            cgf[g, :3] = c
            cgf[g, 3] = float(np.max(np.linalg.norm(P - c, axis=1) + cf[a:b, 3])) * (1.0 + 1e-9) + 1e-12
        self.con = (ground.packed(), cg, cgf, np.ascontiguousarray(cf))
        self.frame = model.root
        names = [p.link for p in self.points]
        self.links = tuple(n for n in model.link_names[:model.nb] if n in set(names))
        self._link_of = np.array([self.links.index(n) for n in names], dtype=np.int64)
        self._body = np.array([index[n] for n in names], dtype=np.int64)   # each point's body in the full tree
        self.point_rows = (self._body, self._link_of)   # kernels.arm.run_arm_periods: per point its body and link

    def body_forces(self, km, q, P) -> np.ndarray:
        """The ground's forces on the bodies of the full tree (nb, 6), ``[n; f]`` in body coordinates
        about the body origin, each point's force on its own link (a foot welded to a shank carries its
        own; the joint wrenches of fixed joints then include it), from the points' outputs P at q
        (``kernels.contact.point_body_forces``)."""
        from ..kernels.contact import point_body_forces
        fext = np.empty((km.nb, 6))
        point_body_forces(km.mi, km.mf, np.ascontiguousarray(q, dtype=float), P, self._body, fext)
        return fext

    def law_words(self) -> str:
        """The law's parameters in one line (run summaries)."""
        g = self.ground
        return (f'k {g.stiffness:.4g} N/m, d {g.dissipation:.4g} s/m, mu {g.friction:.4g}, v_s {g.slip_speed:.3g} m/s')

    @property
    def n_points(self) -> int:
        return len(self.points)

    def point_outputs(self, km, q, v) -> np.ndarray:
        """(nc, NP) per point (``kernels.contact.contact_points``, columns there) at state (q, v);
        km: the tree's :class:`robodyn_ros.kernels.CompiledModel`."""
        from ..kernels.contact import contact_points
        return contact_points(self.con, km.mi_r, km.mf_r, np.ascontiguousarray(q, dtype=float),
                              np.ascontiguousarray(v, dtype=float))

    def wrenches(self, P) -> np.ndarray:
        """``(len(links), 6)`` ``[moment; force]`` per link from the points' outputs P: the resultant and
        the moment about its centre of pressure (module docstring, ``kernels.contact.link_wrenches``),
        world axes; zeros when not touching."""
        from ..kernels.contact import link_wrenches
        out = np.empty((len(self.links), 6))
        link_wrenches(self.con[0], P, self._link_of, out)
        return out

    def touching(self, P) -> np.ndarray:
        """(n, 6) ``[x_c; F]`` of the points of P that touch (world coordinates; m, N), in point order."""
        from ..kernels.contact import PACTIVE, PF, PX
        on = P[:, PACTIVE] > 0.0
        return np.concatenate([P[on, PX:PX + 3], P[on, PF:PF + 3]], axis=1)

    def diagnostics(self, P) -> dict:
        """``contact_active``, ``contact_max_penetration`` (m, 0 when none) and ``contact_max_slip_speed``
        (m/s) of the points' outputs P."""
        from ..kernels.contact import PACTIVE, PDEPTH, PSLIP
        on = P[:, PACTIVE] > 0.0
        return {'contact_active': int(on.sum()),
                'contact_max_penetration': float(P[on, PDEPTH].max()) if on.any() else 0.0,
                'contact_max_slip_speed': float(P[on, PSLIP].max()) if on.any() else 0.0}
