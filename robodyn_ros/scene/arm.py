"""The ``arm`` part: a kinematic tree from a DH table or explicit (URDF-like) links -> ArmSystem.

Also the link parsers the other arm-like kinds share (``prescribed_arm``, ``kinematic_arm``,
``urdf``): inertial data, joint limits and their eq. (20.2.1) moments, actuated joints.
"""
from __future__ import annotations

import math
import re

import numpy as np

from ..model import JOINT_TYPES, LinkSpec, ModelError, build_model, dh_links, planar_root
from ..spatial import R_to_rpy, rpy_to_R
from ..systems.arm import ArmSystem
from ..validation import SceneContext
from ..validation import key_path as _key
from .part import Part


_DH_ROW_REQUIRED = ('type', 'a', 'alpha', 'd', 'theta', 'mass')
_DH_ROW_OPTIONAL = ('com', 'inertia', 'damping', 'limits', 'effort_limit')
_LINK_REQUIRED = ('name', 'joint', 'parent', 'type')
_LINK_OPTIONAL = ('origin', 'axis', 'mass', 'com', 'inertia', 'damping', 'limits', 'effort_limit')
_LIMIT_KEYS = ('lower', 'upper', 'stiffness', 'damping', 'return')
_ARM_REQUIRED = ('kind', 'name')
_ARM_OPTIONAL = ('mount', 'origin', 'root', 'dh', 'tool', 'links', 'link_names', 'joint_names', 'actuated',
                 'command_interfaces', 'servo')
#: ModelError wording -> the link key it is about (for mapping model errors to key paths)
_MODEL_ERROR_KEYS = (('limit', 'limits'), ('parent', 'parent'), ('mass', 'mass'), ('inertia', 'inertia'),
                     ('principal moments', 'inertia'), ('axis', 'axis'), ('damping', 'damping'),
                     ('origin', 'origin'), ('joint type', 'type'), ('duplicate link name', 'name'))


def _joint_limits(ctx: SceneContext, v, path: str, spherical: bool = False) -> dict:
    """LinkSpec limit fields from ``[lo, hi]`` (reported only) or ``{lower, upper, stiffness, damping,
    return}`` (eq. 20.2.1 moments; a spherical joint's lower/upper are 3-vectors)."""
    if not isinstance(v, dict):
        if spherical:
            ctx.fail(path, 'a spherical joint takes limits: {lower: [3], upper: [3], stiffness, damping, return}')
        return {'limits': ctx.limits(v, path)}
    ctx.mapping(v, path, required=('lower', 'upper'), optional=_LIMIT_KEYS[2:])
    if spherical:
        def vec(k):
            if not isinstance(v[k], list) or len(v[k]) != 3:
                ctx.fail(_key(path, k), f'expected 3 values (one per rotation-vector component), got {v[k]!r}')
            out = []
            for i, x in enumerate(v[k]):
                if isinstance(x, float) and math.isinf(x):
                    out.append(x)
                else:
                    out.append(ctx.number(x, _key(_key(path, k), i)))
            return out
        lo, hi = vec('lower'), vec('upper')
        for i in range(3):
            if not lo[i] < hi[i]:
                ctx.fail(_key(_key(path, 'lower'), i), f'lower limit {lo[i]!r} must be below upper limit {hi[i]!r}')
        lim = tuple(zip(lo, hi))
    else:
        lim = ctx.limits([v['lower'], v['upper']], path)
    return {'limits': lim, **_limit_law(ctx, v, path)}


def _limit_law(ctx: SceneContext, v: dict, path: str) -> dict:
    """LinkSpec fields of the eq. 20.2.1 law from a limits mapping's ``stiffness``, ``damping``,
    ``return`` (a link's ``limits`` and a URDF part's ``position_limits``)."""
    from ..model import LIMIT_RETURNS
    ret = ctx.string(v.get('return', 'spring'), _key(path, 'return'))
    if ret not in LIMIT_RETURNS:
        ctx.fail(_key(path, 'return'), f'unknown return mode {ret!r}; use {" or ".join(LIMIT_RETURNS)}')
    return {'limit_return': ret,
            'limit_stiffness': ctx.number(v.get('stiffness', 0.0), _key(path, 'stiffness'), minimum=0.0),
            'limit_damping': ctx.number(v.get('damping', 0.0), _key(path, 'damping'), minimum=0.0)}


def _inertial(ctx: SceneContext, row: dict, path: str, spherical: bool = False) -> dict:
    """Mass, com, inertia, damping, limits of a link mapping (shared by DH and explicit links)."""
    out = {}
    if 'mass' in row:
        m = ctx.number(row['mass'], _key(path, 'mass'))
        if m < 0.0:
            ctx.fail(_key(path, 'mass'), f'negative mass {m!r} kg; a mass must be >= 0')
        out['mass'] = m
    if 'com' in row:
        out['com'] = ctx.vector(row['com'], _key(path, 'com'), 3)
    if 'inertia' in row:
        out['inertia'] = ctx.inertia(row['inertia'], _key(path, 'inertia'))
    if 'damping' in row:
        out['damping'] = ctx.number(row['damping'], _key(path, 'damping'), minimum=0.0)
    if 'limits' in row:
        out.update(_joint_limits(ctx, row['limits'], _key(path, 'limits'), spherical))
    if 'effort_limit' in row:  # actuator limit: commands are clamped to ±effort_limit (and counted)
        out['effort_limit'] = ctx.number(row['effort_limit'], _key(path, 'effort_limit'), positive=True)
    return out


def _joint_type(ctx: SceneContext, v, path: str, allowed) -> str:
    jt = ctx.string(v, path)
    if jt not in allowed:
        known = f'; the model also knows {sorted(set(JOINT_TYPES) - set(allowed))} but not in an arm part' \
            if jt in JOINT_TYPES else ''
        ctx.fail(path, f'unknown joint type {jt!r}; valid types here: {", ".join(allowed)}{known}')
    return jt


def _dh_specs(ctx: SceneContext, spec: dict, path: str, root: str):
    """LinkSpecs and per-link key paths of an arm given by a DH table."""
    dh = ctx.mapping(spec['dh'], _key(path, 'dh'), required=('convention', 'links'))
    dpath = _key(path, 'dh')
    convention = ctx.string(dh['convention'], _key(dpath, 'convention'))
    if convention not in ('standard', 'modified'):
        ctx.fail(_key(dpath, 'convention'), f'unknown DH convention {convention!r}; use standard or modified')
    rows_in = ctx.sequence(dh['links'], _key(dpath, 'links'))
    if not rows_in:
        ctx.fail(_key(dpath, 'links'), 'a DH table needs at least one link')
    rows, paths = [], []
    for i, r in enumerate(rows_in):
        rp = _key(_key(dpath, 'links'), i)
        ctx.mapping(r, rp, required=_DH_ROW_REQUIRED, optional=_DH_ROW_OPTIONAL)
        row = {'type': _joint_type(ctx, r['type'], _key(rp, 'type'), ('revolute', 'prismatic'))}
        for k in ('a', 'alpha', 'd', 'theta'):
            row[k] = ctx.number(r[k], _key(rp, k))
        row.update(_inertial(ctx, r, rp))
        rows.append(row)
        paths.append(rp)
    n = len(rows)
    lnames = ctx.names(spec['link_names'], _key(path, 'link_names'), n) if 'link_names' in spec else \
        [f'link{i + 1}' for i in range(n)]
    jnames = ctx.names(spec['joint_names'], _key(path, 'joint_names'), n) if 'joint_names' in spec else \
        [f'joint{i + 1}' for i in range(n)]
    tool = ctx.boolean(spec['tool'], _key(path, 'tool')) if 'tool' in spec else convention == 'standard'
    if tool and convention != 'standard':
        ctx.fail(_key(path, 'tool'), 'the tool frame is only defined for standard DH (it is DH frame n)')
    specs = dh_links(rows, convention=convention, names=list(zip(lnames, jnames)), root=root, tool=tool)
    for sp, row in zip(specs, rows):   # eq. 20.2.1 limit moments of a limits mapping
        for k in ('limit_stiffness', 'limit_damping', 'limit_return'):
            if k in row:
                setattr(sp, k, row[k])
    if tool:
        if 'tool' in lnames or 'tool_joint' in jnames:
            ctx.fail(_key(path, 'link_names'), "'tool'/'tool_joint' are reserved for the standard-DH tool frame")
        paths.append(_key(path, 'tool'))
    return specs, paths


def _explicit_specs(ctx: SceneContext, spec: dict, path: str, root: str, free: bool = False):
    """LinkSpecs and per-link key paths of an arm given by explicit (URDF-like) links."""
    for k in ('link_names', 'joint_names', 'tool'):
        if k in spec:
            ctx.fail(_key(path, k), f"'{k}' applies to a 'dh' table only; explicit links carry their names")
    lpath = _key(path, 'links')
    items = ctx.sequence(spec['links'], lpath)
    if not items:
        ctx.fail(lpath, 'an arm needs at least one link')
    specs, paths = [], []
    for i, r in enumerate(items):
        rp = _key(lpath, i)
        ctx.mapping(r, rp, required=_LINK_REQUIRED, optional=_LINK_OPTIONAL)
        jt = _joint_type(ctx, r['type'], _key(rp, 'type'), ('revolute', 'prismatic', 'fixed', 'planar', 'spherical',
                                                             'free'))
        T = ctx.pose(r['origin'], _key(rp, 'origin')) if 'origin' in r else np.eye(4)
        axis = ctx.vector(r['axis'], _key(rp, 'axis'), 3) if 'axis' in r else np.array([0.0, 0.0, 1.0])
        if jt in ('fixed', 'planar') and any(k in r for k in ('axis', 'limits', 'damping', 'effort_limit')):
            ctx.fail(rp, f'a {jt} joint takes no axis, limits, damping or effort_limit')
        if jt == 'spherical' and 'axis' in r:
            ctx.fail(_key(rp, 'axis'), 'a spherical joint has no axis')
        parent = ctx.string(r['parent'], _key(rp, 'parent'))
        if jt == 'free' and (not free or parent != root):
            ctx.fail(_key(rp, 'type'), f"a free joint joins the tree's root link to the root frame {root!r} of an arm "
                                       "with mount: free")
        if jt == 'free' and any(k in r for k in ('origin', 'axis', 'limits', 'damping')):
            ctx.fail(rp, 'a free joint takes no origin, axis, limits or damping (its pose is in q)')
        inert = _inertial(ctx, r, rp, spherical=jt == 'spherical')
        specs.append(LinkSpec(name=ctx.string(r['name'], _key(rp, 'name')),
                              joint=ctx.string(r['joint'], _key(rp, 'joint')), parent=parent,
                              joint_type=jt, origin_xyz=tuple(T[:3, 3]), origin_R=T[:3, :3],
                              origin_rpy=tuple(R_to_rpy(T[:3, :3])), axis=tuple(axis),
                              mass=inert.get('mass', 0.0), com=tuple(inert.get('com', np.zeros(3))),
                              inertia=inert.get('inertia', np.zeros((3, 3))),
                              damping=inert.get('damping', 0.0), limits=inert.get('limits'),
                              effort_limit=inert.get('effort_limit'),
                              **{k: inert[k] for k in ('limit_stiffness', 'limit_damping', 'limit_return')
                                 if k in inert}))
        paths.append(rp)
    if free and sum(s.joint_type == 'free' for s in specs) != 1:
        ctx.fail(lpath, f"mount: free needs exactly one link with type: free and parent: {root}")
    return specs, paths


def _model_error_path(err: ModelError, specs, paths, fallback: str) -> str:
    """Key path a ModelError is about: the link it names plus the key its wording points to."""
    m = re.match(r"link '([^']+)'", str(err))
    if not m:
        return fallback
    index = {s.name: k for k, s in enumerate(specs)}
    k = index.get(m.group(1))
    if k is None:
        return fallback
    text = str(err)[m.end():]
    for word, key in _MODEL_ERROR_KEYS:
        if word in text:
            return _key(paths[k], key)
    return paths[k]


def moved_visual(visual: str, T0) -> str:
    """A ``<visual>`` element (XML text) with its ``<origin>`` moved by the pose T0 (4, 4): ``T0 · T``, written as
    the shortest text of each double (``repr``); the rest of the element as it was."""
    import xml.etree.ElementTree as ET
    el = ET.fromstring(visual)
    o = el.find('origin')
    if o is None:
        o = ET.Element('origin')
        el.insert(0, o)
    T = np.eye(4)
    T[:3, :3] = rpy_to_R([float(x) for x in (o.get('rpy') or '0 0 0').split()])
    T[:3, 3] = [float(x) for x in (o.get('xyz') or '0 0 0').split()]
    T = np.asarray(T0, dtype=float) @ T
    o.set('xyz', ' '.join(repr(float(x)) for x in T[:3, 3]))
    o.set('rpy', ' '.join(repr(float(x)) for x in R_to_rpy(T[:3, :3])))
    return ET.tostring(el, encoding='unicode')


def build_arm_part(spec: dict, path: str, ctx: SceneContext, specs=None, root_visuals=None) -> Part:
    """Build an ``arm`` part: a kinematic tree from a DH table or explicit links -> ArmSystem.

    spec: the part mapping (see the module docstring for its keys); path: its key path
    ('parts[0]'); ctx: validation context (file name, gravity); root_visuals: ``<visual>`` elements (XML
    text) of the root link (an imported URDF's), in its frame (moved with the joints by ``origin``; on a
    platform or a free base they are drawn on its link), or None (shapes drawn). Model errors are re-raised
    as :class:`SceneError` with the key path of the offending link.
    """
    ctx.mapping(spec, path, required=_ARM_REQUIRED, optional=_ARM_OPTIONAL)
    name = ctx.string(spec['name'], _key(path, 'name'))
    mount = ctx.string(spec.get('mount', 'world'), _key(path, 'mount'))
    free = mount == 'free'
    root = ctx.string(spec.get('root', 'odom' if free else 'base_link'), _key(path, 'root'))
    if specs is not None:  # built elsewhere (an imported URDF): (LinkSpecs, key paths)
        specs, paths = specs
    elif ('dh' in spec) == ('links' in spec):
        ctx.fail(path, "give exactly one of 'dh' (a DH table) or 'links' (explicit links)")
    elif 'dh' in spec:
        if free:
            ctx.fail(_key(path, 'mount'), "mount: free needs explicit 'links' (one of them with type: free)")
        specs, paths = _dh_specs(ctx, spec, path, root)
    else:
        specs, paths = _explicit_specs(ctx, spec, path, root, free)
    if 'origin' in spec:  # the mount pose: compose it into the joints that hang from the root
        T0 = ctx.pose(spec['origin'], _key(path, 'origin'))
        root_visuals = None if root_visuals is None else [moved_visual(v, T0) for v in root_visuals]
        for s in specs:
            if s.parent in (None, root):
                T = np.eye(4)
                T[:3, :3] = s.origin_R if s.origin_R is not None else rpy_to_R(s.origin_rpy)
                T[:3, 3] = s.origin_xyz
                T = T0 @ T
                s.origin_R, s.origin_xyz, s.origin_rpy = T[:3, :3], tuple(T[:3, 3]), tuple(R_to_rpy(T[:3, :3]))
    try:
        model = build_model(specs, gravity=ctx.gravity, name=name, root=root, root_visuals=root_visuals)
    except ModelError as e:
        ctx.fail(_model_error_path(e, specs, paths, path), str(e))
    planar = planar_root(model) is not None
    actuated = _actuated(ctx, spec, path, model, planar=planar)
    try:
        if planar:  # a tree in free flight in the x-z plane (systems.planar)
            from ..systems.planar import PlanarBaseSystem
            system = PlanarBaseSystem(model, actuated=actuated)
        else:
            system = ArmSystem(model, actuated=actuated)
    except ValueError as e:   # e.g. spherical joints on the numpy backend
        ctx.fail(path, str(e))
    from .control import part_control
    return Part(name=name, kind='arm', mount=mount, system=system, path=path, control=part_control(ctx, spec, path))


def _actuated(ctx: SceneContext, spec: dict, path: str, model, planar: bool = False):
    """The part's ``actuated`` joint names, each a 1-DOF joint or a spherical joint component of
    ``model`` (not a planar root joint when ``planar``); None when not given."""
    if 'actuated' not in spec:
        return None
    dof = list(model.state_joint_names)[3:] if planar else list(model.state_joint_names)
    apath = _key(path, 'actuated')
    actuated = ctx.names(spec['actuated'], apath)
    for i, j in enumerate(actuated):
        if j not in dof:
            ctx.fail(_key(apath, i), f'{j!r} is not a 1-DOF joint (or a spherical joint component) of this arm; '
                                     f'joints are {dof}' + (' (the planar root joints are never actuated)' if planar else ''))
    return actuated


def _refuse_limit_moments(ctx: SceneContext, part, host: str):
    """Joint-limit moments act in :class:`ArmSystem` only (fixed or free root): refuse them on an
    arm that rides on a ``free_base`` or ``diff_drive`` platform rather than drop them silently."""
    bad = [s.joint for s in part.system.model.specs if s.limit_stiffness or s.limit_damping]
    if bad:
        ctx.fail(part.path, f'joint {bad[0]!r}: joint-limit moments (limits with stiffness/damping, URDF '
                            f'position_limits) are not computed for an arm on a {host} platform; give limits: '
                            '[lower, upper] (reported only), or mount the arm on the world (or mount: free)')
