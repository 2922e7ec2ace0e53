"""The ``ground`` part: a plane the scene's tree stands on, with compliant contact
(:mod:`robodyn_ros.systems.contact`, law in :mod:`robodyn_ros.kernels.contact`).

Keys (every one optional but the kind)::

    - kind: ground
      name: ground                 # default 'ground'
      height: 0.0                  # m: the plane n·x = height in the world (root) frame
      normal: [0, 0, 1]            # its normal (normalised here; the side bodies stay on)
      stiffness: 3.0e4             # N/m per contact point       } or: time_constant: 0.01 (s)
      dissipation: 5.0             # s/m (Hunt–Crossley)         }     damping_ratio: 1.0
      friction: 0.8                # Coulomb μ >= 0
      slip_speed: 0.005            # m/s: regularisation speed of the friction
      links: [FL_foot, ...]        # optional: only these links' <collision> shapes
      contacts:                    # and/or an explicit list (alone: instead of the <collision> shapes):
        - {link: foot, point: [0.0, 0.0, -0.02]}
        - {link: hand, sphere: {center: [0.0, 0.0, -0.07], radius: 0.04}}

Defaults: :data:`DEFAULTS`, the field defaults of :class:`~robodyn_ros.systems.contact.Ground` (set
there only). ``time_constant`` τ and ``damping_ratio`` ζ (MuJoCo's ``solref``) give the
mode of the tree resting on its points, each carrying an equal share ``m_c = M / N`` of its mass M
(N points): ``k = m_c / (τ ζ)²`` (natural frequency ω = 1/(τ ζ)) and ``d = 2 / (g τ)``, so that the
linearised motion about the rest penetration ``δ0 = m_c g / k`` is ``δ̈ + (2/τ) δ̇ + ω² δ = 0``:
damping rate 2/τ and ratio ζ, MuJoCo's reference acceleration ``−(2/τ) δ̇ − ω² δ`` per unit mass (with
its impedance at 1). It needs gravity; a tree resting on fewer points than it has is softer
(``ω √(N_rest/N)``).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..systems.contact import Ground
from ..validation import SceneContext
from ..validation import key_path as _key
from .part import Part

#: defaults of the ground's law (stiffness per point, Hunt–Crossley dissipation, Coulomb μ, slip speed):
#: :class:`Ground`'s own
DEFAULTS = {f.name: f.default for f in dataclasses.fields(Ground)
            if f.name in ('stiffness', 'dissipation', 'friction', 'slip_speed')}
_KEYS = ('kind', 'name', 'height', 'normal', 'stiffness', 'dissipation', 'time_constant', 'damping_ratio',
         'friction', 'slip_speed', 'links', 'contacts')


def build_ground_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Validate a ``ground`` part (module docstring); its points are made when the scene is assembled
    (:func:`attach_ground`), when the tree they sit on is known."""
    ctx.mapping(spec, path, required=('kind',), optional=_KEYS)
    name = ctx.string(spec.get('name', 'ground'), _key(path, 'name'))
    g = {'height': ctx.number(spec.get('height', 0.0), _key(path, 'height'))}
    n = ctx.vector(spec.get('normal', [0.0, 0.0, 1.0]), _key(path, 'normal'), 3)
    if not np.linalg.norm(n) > 1e-9:
        ctx.fail(_key(path, 'normal'), f'the normal must be a non-zero 3-vector, got {n.tolist()}')
    g['normal'] = tuple(n / np.linalg.norm(n))
    by_k = [k for k in ('stiffness', 'dissipation') if k in spec]
    by_t = [k for k in ('time_constant', 'damping_ratio') if k in spec]
    if by_k and by_t:
        ctx.fail(_key(path, by_t[0]), f'give the compliance as stiffness/dissipation or as time_constant/'
                                      f'damping_ratio, not both ({by_k[0]} is given too)')
    if by_t:
        for k in ('time_constant', 'damping_ratio'):
            if k not in spec:
                ctx.fail(_key(path, k), 'missing: time_constant and damping_ratio go together')
            g[k] = ctx.number(spec[k], _key(path, k), positive=True)
        gn = float(np.linalg.norm(ctx.gravity))
        if not gn > 0.0:
            ctx.fail(_key(path, 'time_constant'), 'time_constant/damping_ratio need gravity (they set the mode of '
                                                  'the tree resting on the ground); give stiffness/dissipation')
        g['gravity'] = gn
    else:
        k = ctx.number(spec.get('stiffness', DEFAULTS['stiffness']), _key(path, 'stiffness'))
        if not k > 0.0:
            ctx.fail(_key(path, 'stiffness'), f'must be > 0 (N/m per contact point), got {k!r}: a ground without '
                                              'stiffness holds nothing')
        g['stiffness'] = k
        g['dissipation'] = ctx.number(spec.get('dissipation', DEFAULTS['dissipation']), _key(path, 'dissipation'),
                                      minimum=0.0)
    g['friction'] = ctx.number(spec.get('friction', DEFAULTS['friction']), _key(path, 'friction'), minimum=0.0)
    g['slip_speed'] = ctx.number(spec.get('slip_speed', DEFAULTS['slip_speed']), _key(path, 'slip_speed'),
                                 positive=True)
    if 'links' in spec:
        g['links'] = ctx.names(spec['links'], _key(path, 'links'))
    if 'contacts' in spec:
        g['contacts'] = _explicit_contacts(ctx, spec['contacts'], _key(path, 'contacts'))
    return Part(name=name, kind='ground', mount='world', system=None, path=path, data=g)


def _explicit_contacts(ctx: SceneContext, items, path: str) -> list:
    """``[(link, point (3,), radius, key path)]`` of a ``contacts`` list."""
    out = []
    seq = ctx.sequence(items, path)
    if not seq:
        ctx.fail(path, 'an empty contacts list: give at least one {link, point | sphere}')
    for i, c in enumerate(seq):
        cp = _key(path, i)
        ctx.mapping(c, cp, required=('link',), optional=('point', 'sphere'))
        link = ctx.string(c['link'], _key(cp, 'link'))
        if ('point' in c) == ('sphere' in c):
            ctx.fail(cp, "give exactly one of 'point' ([x, y, z] in the link frame) or 'sphere' ({center, radius})")
        if 'point' in c:
            out.append((link, ctx.vector(c['point'], _key(cp, 'point'), 3), 0.0, cp))
        else:
            sp = _key(cp, 'sphere')
            s = ctx.mapping(c['sphere'], sp, required=('radius',), optional=('center',))
            center = ctx.vector(s['center'], _key(sp, 'center'), 3) if 'center' in s else np.zeros(3)
            out.append((link, center, ctx.number(s['radius'], _key(sp, 'radius'), positive=True), cp))
    return out


def attach_ground(ctx: SceneContext, ground: Part, system):
    """The scene's system standing on ``ground``: its contact points (explicit, or the tree's
    ``<collision>`` shapes), the law's parameters, attached to the tree (:meth:`ArmSystem.attach_ground`).

    system: the other parts' system; a floating URDF (a free-flyer in free fall) becomes an
    :class:`~robodyn_ros.systems.arm.ArmSystem` on a free root (the same tree), which the ground acts on.
    Returns that system. Errors name the ground's keys."""
    import warnings

    from ..systems.arm import ArmSystem
    from ..systems.contact import ContactPoint, ContactWarning, GroundContact, collision_points
    g, path = ground.data, ground.path
    if type(system).__name__ == 'FreeFlyerSystem' and getattr(system, 'environment', '') in ('free_fall', 'orbit'):
        system = ArmSystem(system.model, actuated=list(system.actuated), backend=system.backend)
    if not isinstance(system, ArmSystem) or type(system) is not ArmSystem:
        ctx.fail(path, f'a ground carries an arm or urdf part (fixed base, mount: free or floating: true); this '
                       f'scene\'s system is a {type(system).__name__}')
    model = system.model
    links = list(model.link_names[:model.nb])
    points = []
    for link, p, r, cp in g.get('contacts', ()):
        if link not in links:
            ctx.fail(_key(cp, 'link'), f'no link {link!r} in this scene\'s tree; links are {links}')
        points.append(ContactPoint(link, tuple(float(x) for x in p), float(r), 'contacts list'))
    if 'links' in g or 'contacts' not in g:   # <collision> shapes: of the links named, or of every link
        chosen = g.get('links', links)
        for k, link in enumerate(chosen):
            if link not in links:
                ctx.fail(_key(_key(path, 'links'), k), f'no link {link!r} in this scene\'s tree; links are {links}')
        specs = {s.name: s for s in model.specs}
        for link in chosen:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter('always', ContactWarning)
                for shape in getattr(specs[link], 'collisions', ()):
                    points += collision_points(link, shape)
            for w in caught:   # once per scene load, with the file named
                warnings.warn(ContactWarning(f'{ctx.file}: {path}: {w.message}'), stacklevel=2)
        if not points:
            where = f'links {chosen}' if 'links' in g else 'the tree'
            ctx.fail(_key(path, 'links') if 'links' in g else path,
                     f'{where} has no <collision> shapes to stand on; give contacts: [{{link, point | sphere}}]')
    if 'time_constant' in g:
        tau, zeta = g['time_constant'], g['damping_ratio']
        m_c = float(sum(model.specs[i].mass for i in range(model.nb))) / len(points)
        stiffness, dissipation = m_c / (tau * zeta) ** 2, 2.0 / (g['gravity'] * tau)
    else:
        stiffness, dissipation = g['stiffness'], g['dissipation']
    law = Ground(normal=g['normal'], height=g['height'], stiffness=stiffness, dissipation=dissipation,
                 friction=g['friction'], slip_speed=g['slip_speed'])
    try:
        system.attach_ground(GroundContact(model, law, points))
    except ValueError as e:
        ctx.fail(path, str(e))
    return system

