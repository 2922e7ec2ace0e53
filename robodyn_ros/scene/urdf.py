"""The ``urdf`` part: a robot description imported by :func:`robodyn_ros.urdf.read_urdf`.
"""
from __future__ import annotations

import os
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..mass_properties import DENSITY
from ..model import ModelError
from ..validation import SceneContext, SceneError, typename
from ..validation import key_path as _key
from .arm import _LIMIT_KEYS, _actuated, _limit_law, build_arm_part
from .part import Part


_URDF_KEYS = ('kind', 'name', 'file', 'urdf', 'mount', 'origin', 'floating', 'locked', 'actuated', 'position_limits',
              'armature', 'density', 'command_interfaces', 'servo')


def _urdf_position_limits(ctx: SceneContext, v, path: str, specs) -> list:
    """``position_limits: {stiffness, damping, return}``: the eq. 20.2.1 joint-limit moments on every
    joint with URDF ``<limit lower upper>`` (revolute, prismatic; continuous and locked joints have none)."""
    ctx.mapping(v, path, optional=_LIMIT_KEYS[2:])
    law = _limit_law(ctx, v, path)
    return [replace(s, **law) if s.limits is not None and s.joint_type in ('revolute', 'prismatic') else s
            for s in specs]


def _armature_key(ctx: SceneContext, v, path: str):
    """``armature``: ``auto``, a number >= 0 (every moving joint), or ``{joint: number >= 0}``."""
    if v == 'auto':
        return v
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            out[str(k)] = ctx.number(x, _key(path, k))
            if not out[str(k)] >= 0.0:
                ctx.fail(_key(path, k), f'expected a number >= 0 (kg·m² or kg), got {x!r}')
        return out
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        ctx.fail(path, f"expected 'auto', a number >= 0 or a mapping joint: number, got {typename(v)} {v!r}")
    x = ctx.number(v, path)
    if not x >= 0.0:
        ctx.fail(path, f'expected a number >= 0 (kg·m² or kg; 0: no armature), got {v!r}')
    return x


def referenced_path(ref: str, scene_file: str) -> Path:
    """Where a file reference of a scene points: ``ref`` itself when absolute, else relative to
    the scene file's directory (to the working directory when ``scene_file`` is no file).
    Path arithmetic only when ``scene_file`` is an absolute path (then no disk access)."""
    src = Path(ref)
    if src.is_absolute():
        return src
    scene = Path(scene_file)
    base = scene.parent if scene.is_absolute() or scene.is_file() else Path.cwd()
    return Path(os.path.abspath(base / src))


def build_urdf_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``urdf`` part: a robot description imported by :func:`robodyn_ros.urdf.read_urdf`.

    Keys: ``file`` (path, relative to the scene file, or ``package://<package>/<path>``: a ROS
    package's file, found as :func:`robodyn_ros.meshes.resolve_uri` finds meshes, e.g.
    ``package://example-robot-data/robots/...``) or ``urdf`` (inline URDF text), exactly one;
    ``mount: world | <diff_drive part> | <free_base part>`` (default world; the URDF's root link is
    then the frame it hangs from, placed by ``origin``); ``floating`` (default false: the root link
    is welded to the mount; true: it is a free 6-DOF base in the scene's gravity, environment
    ``free_fall`` — on a scene's ``ground`` part, if it has one — or ``orbit`` with zero gravity);
    ``locked: {joint: position}`` freezes joints (gripper fingers, ``<mimic>`` joints);
    ``actuated`` as for an arm (default every 1-DOF joint); ``position_limits: {stiffness,
    damping, return}`` (optional; absent = URDF position limits reported only) enforces every
    joint's ``<limit lower upper>`` with the joint-limit moments of Huston eq. (20.2.1), as a
    ``limits`` mapping does for an arm link (world-mounted, non-floating robots); ``armature``
    (``auto``, the default: the smallest stated rotor inertia on the joints of a mass matrix singular
    at q = 0, none elsewhere; a number >= 0 for every moving joint, 0 = none; or ``{joint: value}``,
    kg·m² or kg, :mod:`robodyn_ros.armature`); ``density`` (kg/m³, default 1000; 0 = none) of the
    solids inferred for moving links without ``<inertial>`` from their geometry. The part is an
    arm (its kind is ``arm`` once built) so it mounts wherever an arm does.
    """
    from ..urdf import UrdfError, UrdfText, read_urdf
    ctx.mapping(spec, path, required=('kind', 'name'), optional=_URDF_KEYS)
    name = ctx.string(spec['name'], _key(path, 'name'))
    mount = ctx.string(spec.get('mount', 'world'), _key(path, 'mount'))
    floating = ctx.boolean(spec.get('floating', False), _key(path, 'floating'))
    if ('file' in spec) == ('urdf' in spec):
        ctx.fail(path, "give exactly one of 'file' (a URDF file) or 'urdf' (the URDF text)")
    alone, label, base_dir = False, None, None   # (the scene is this URDF alone; its name; its mesh directory)
    if 'file' in spec:
        where = _key(path, 'file')
        ref = ctx.string(spec['file'], where)
        if ref.startswith('package://'):   # e.g. package://example-robot-data/robots/...: a ROS package's file
            from ..meshes import MeshError, resolve_uri
            try:
                file = resolve_uri(ref)
            except MeshError as e:
                ctx.fail(where, str(e))
        else:
            file = referenced_path(ref, ctx.file)
        label = str(file)
        if ctx.given_files is not None:   # the file's bytes came with the scene text: no disk access
            if ref not in ctx.given_files:
                ctx.fail(where, f'{ref!r} is not among the files given with the scene text '
                                f'({", ".join(map(repr, sorted(ctx.given_files))) or "none"})')
            src, base_dir = ctx.given_files[ref], file.parent
        elif not file.is_file():
            ctx.fail(where, f'no such URDF file {label!r} (relative paths start at the scene file)')
        else:
            try:
                src = file.read_bytes()
            except OSError as e:
                ctx.fail(where, f'cannot read the URDF file {label!r}: {e.strerror or e}')
            base_dir = file.resolve().parent
            alone = Path(ctx.file).resolve() == file.resolve()
        ctx.files[ref] = src
    else:
        src = UrdfText(ctx.string(spec['urdf'], _key(path, 'urdf')))
        where = _key(path, 'urdf')
    lpath = _key(path, 'locked')
    given = spec.get('locked', {})
    if not isinstance(given, dict):
        ctx.fail(lpath, f'expected a mapping joint: position, got {typename(given)} {given!r}')
    locked = {k: ctx.number(v, _key(lpath, k)) for k, v in given.items()}
    armature = _armature_key(ctx, spec.get('armature', 'auto'), _key(path, 'armature'))
    density = DENSITY
    if 'density' in spec:
        density = ctx.number(spec['density'], _key(path, 'density'))
        if not density >= 0.0:
            ctx.fail(_key(path, 'density'), f'expected a number >= 0 (kg/m³; 0: infer no mass), got {density!r}')
    try:
        robot = read_urdf(src, floating=floating, locked=locked, file=ctx.file if alone else label,
                          base_dir=base_dir, density=density, armature=armature)
    except UrdfError as e:
        m = re.match(r"(locked|armature) joint '([^']+)'", e.where)
        if m:
            ctx.fail(_key(_key(path, m.group(1)) if m.group(1) == 'armature' else lpath, m.group(2)), e.reason)
        if alone:  # its errors are the URDF's: '<file>: <link/joint>: <reason>'
            raise SceneError(str(e)) from None
        ctx.fail(where, str(e))
    specs = robot.specs
    floating = floating or robot.floating   # the URDF may say so itself (a massless world link, a floating joint)
    if floating and (mount != 'world' or 'origin' in spec):
        ctx.fail(_key(path, 'floating'), 'a floating URDF base stands on its own: no mount or origin')
    if any(s.mimic is not None for s in specs) and (floating or mount != 'world'):
        j = next(s.joint for s in specs if s.mimic is not None)
        ctx.fail(where, f"joint {j!r}: <mimic> joints are supported for a URDF mounted on the world only (lock them "
                        "with locked: {joint: position}, or use mount: world)")
    if any(s.friction > 0.0 for s in specs) and (floating or mount != 'world'):
        j = next(s.joint for s in specs if s.friction > 0.0)
        ctx.fail(where, f"joint {j!r}: Coulomb <dynamics friction> is supported for a URDF mounted on the world "
                        "only (set friction=\"0\" or mount: world)")
    if 'position_limits' in spec:
        ppath = _key(path, 'position_limits')
        if floating or mount != 'world':
            ctx.fail(ppath, 'joint-limit moments are supported for a URDF mounted on the world only '
                            '(not floating, not on a platform); remove position_limits or use mount: world')
        specs = _urdf_position_limits(ctx, spec['position_limits'], ppath, specs)
    if floating:
        from ..systems import freeflyer as ff
        env = 'orbit' if not np.any(ctx.gravity) else 'free_fall'
        try:
            model = ff.free_flyer_model(specs[0], specs[1:], gravity=ctx.gravity, name=name)
        except ModelError as e:
            ctx.fail(where, str(e))
        system = ff.FreeFlyerSystem(model, actuated=_actuated(ctx, spec, path, model), environment=env)
        from .control import part_control
        return Part(name=name, kind='free_base', mount='world', system=system, path=path,
                    control=part_control(ctx, spec, path))
    root = robot.root
    host = next((p for p in ctx.parts if p.name == mount and p.kind == 'free_base'), None)
    if host is not None:  # hang from the free base's link
        specs = [replace(s, parent=host.system.base_link) if s.parent == root else s for s in specs]
        root = host.system.base_link
    arm_spec = {'kind': 'arm', 'name': name, 'mount': mount, 'root': root,
                **{k: spec[k] for k in ('origin', 'actuated', 'command_interfaces', 'servo') if k in spec}}
    return build_arm_part(arm_spec, path, ctx, specs=(specs, [where] * len(specs)), root_visuals=robot.root_visuals)
