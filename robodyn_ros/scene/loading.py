"""Loading a scene: YAML -> parts (one builder per kind, :data:`PART_KINDS`) -> system, initial
state, scripted commands and settings; where bundled scenes are found.
"""
from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from ..profiles import build_script
from ..validation import SceneContext, SceneError, registered
from ..validation import key_path as _key
from .arm import build_arm_part
from .control import apply_control, build_sensors
from .diff_drive import _assemble_diff_drive, build_diff_drive_part
from .free_base import _assemble_free_base, build_free_base_part
from .ground import attach_ground, build_ground_part
from .kinematic_arm import build_kinematic_arm_part
from .prescribed_arm import build_prescribed_arm_part
from .state import _initial_state, _settings, _stop_condition
from .urdf import build_urdf_part

_TOP_KEYS_REQUIRED = ('name', 'parts')
_TOP_KEYS_OPTIONAL = ('description', 'source', 'gravity', 'initial_state', 'commands', 'simulation', 'stop_when',
                      'sensors')


@dataclass
class Scene:
    """A loaded scene: what to simulate, from where, with which commands and settings.

    name: scene name; path: file it came from; text: the raw YAML (recorded in MCAP metadata);
    data: the parsed mapping; system: the System to integrate (an ArmSystem, a platform, a free base...);
    y0: (ny,) initial state; script: ``script(t, y) -> {port: (size,) array}`` for the
    commanded ports, or None; settings: simulation defaults (integrator, dt, publish_rate,
    duration, and rtol/atol when given); parts: part names in file order; stop: ``stop(t, y) ->
    bool`` from ``stop_when`` (the run ends at the first publication where it is true), or None;
    files: every file the scene references (a ``kind: urdf`` part's ``file``), as written in the
    scene -> its bytes: with the scene text, all a run needs (a sweep ships both to its workers).
    """

    name: str
    path: str
    text: str
    data: dict
    system: object
    y0: np.ndarray
    script: Callable | None
    settings: dict
    parts: list = field(default_factory=list)
    stop: Callable | None = None
    files: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# YAML: YAML 1.2 floats (1e-3 is a number, not a string) and duplicate keys refused
# --------------------------------------------------------------------------------------------
class SceneLoader(yaml.SafeLoader):
    """SafeLoader that reads ``1e-3`` as a float and refuses duplicate mapping keys."""


SceneLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$'),
    list('-+0123456789'))


def _construct_mapping(loader, node, deep=False):
    """Mapping constructor that raises on a repeated key (PyYAML silently keeps the last)."""
    loader.flatten_mapping(node)
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f'duplicate key {key!r}', key_node.start_mark)
        seen.add(key)
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


SceneLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


#: part kind -> builder(spec, path, ctx) -> Part
PART_KINDS: dict[str, Callable] = {'arm': build_arm_part, 'prescribed_arm': build_prescribed_arm_part,
                                   'free_base': build_free_base_part, 'diff_drive': build_diff_drive_part,
                                   'urdf': build_urdf_part, 'kinematic_arm': build_kinematic_arm_part,
                                   'ground': build_ground_part}


def _assemble(ctx: SceneContext, parts: list) -> object:
    """The scene's System from its parts.

    A ``ground`` part is not a system: the others are assembled, then put on it (:func:`attach_ground`).
    """
    grounds = [p for p in parts if p.kind == 'ground']
    if grounds:
        if len(grounds) > 1:
            ctx.fail(_key(grounds[1].path, 'kind'), 'a scene can have one ground part')
        rest = [p for p in parts if p.kind != 'ground']
        if not rest:
            ctx.fail(grounds[0].path, 'a ground needs something to stand on it: add an arm or urdf part')
        return attach_ground(ctx, grounds[0], _assemble(ctx, rest))
    if any(p.kind == 'free_base' for p in parts):
        return _assemble_free_base(ctx, parts)
    if any(p.kind == 'diff_drive' for p in parts):  # the platform, or the mobile manipulator
        return _assemble_diff_drive(ctx, parts)
    if len(parts) != 1:
        ctx.fail('parts', f'a scene of {len(parts)} parts needs a composition of '
                          f'{[p.kind for p in parts]} that is not available yet; use one part')
    p = parts[0]
    if p.mount not in ('world', 'free'):
        ctx.fail(_key(p.path, 'mount'), f"mount {p.mount!r} is not available to part kind '{p.kind}' "
                                        "in a one-part scene; use 'world'")
    return p.system


# --------------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------------
def parse_scene(text: str, file: str = '<string>', path: str | None = None, files: dict | None = None) -> Scene:
    """Validate scene YAML text and build its :class:`Scene`.

    text: the YAML; file: name used in error messages and the file relative references start
    from; path: file path stored in the Scene (default ``file``); files: the contents of the files
    the scene references (``file`` of a ``kind: urdf`` part, as written -> bytes, e.g. another
    Scene's ``files``): given, they are used instead of the disk, which is then never read
    (a sweep's worker). Raises :class:`SceneError` ``<file>: <key path>: <reason>``.
    """
    ctx = SceneContext(file, files)
    try:
        data = yaml.load(text, Loader=SceneLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, 'problem_mark', None)
        where = f'line {mark.line + 1}, column {mark.column + 1}' if mark is not None else 'YAML'
        ctx.fail(where, f'YAML syntax error: {getattr(e, "problem", None) or e}')
    ctx.mapping(data, '', required=_TOP_KEYS_REQUIRED, optional=_TOP_KEYS_OPTIONAL)
    name = ctx.string(data['name'], 'name')
    for k in ('description', 'source'):
        if k in data:
            ctx.string(data[k], k)
    if 'gravity' in data:
        ctx.gravity = ctx.vector(data['gravity'], 'gravity', 3)
    items = ctx.sequence(data['parts'], 'parts')
    if not items:
        ctx.fail('parts', 'a scene needs at least one part')
    for i, spec in enumerate(items):
        ppath = _key('parts', i)
        builder = registered(ctx, spec, ppath, 'kind', PART_KINDS, 'part kind', 'kinds')
        part = builder(spec, ppath, ctx)
        if any(p.name == part.name for p in ctx.parts):
            ctx.fail(_key(ppath, 'name'), f'duplicate part name {part.name!r}')
        ctx.parts.append(part)
    system = _assemble(ctx, ctx.parts)
    y0 = _initial_state(ctx, data.get('initial_state', {}), system)
    ctx.y0 = y0  # command profiles may start from the initial state (e.g. a posture path)
    settings = _settings(ctx, data.get('simulation', {}))
    apply_control(ctx, system, ctx.parts, y0, settings)   # position/velocity joints: their servo (default gains at y0)
    if 'sensors' in data:
        build_sensors(ctx, data['sensors'], system)
    script = build_script(ctx, data.get('commands', {}), system)
    stop = _stop_condition(ctx, data['stop_when'], system) if 'stop_when' in data else None
    return Scene(name=name, path=path or file, text=text, data=data, system=system, y0=y0, script=script,
                 settings=settings, parts=[p.name for p in ctx.parts], stop=stop, files=dict(ctx.files))


def scene_dirs() -> list:
    """Directories searched for bundled scenes, in order (existing ones only).

    ``<package dir>/../config/scenes`` (source tree), the ament index share directory
    ``robodyn_ros/config/scenes``, then ``<sys.prefix>/share/robodyn_ros/config/scenes``.
    """
    cands = [Path(__file__).resolve().parents[2] / 'config' / 'scenes']
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:  # no ROS installation: the other two places remain
        pass
    else:
        try:
            cands.append(Path(get_package_share_directory('robodyn_ros')) / 'config' / 'scenes')
        except (PackageNotFoundError, OSError):  # not installed, or AMENT_PREFIX_PATH unset
            pass
    cands.append(Path(sys.prefix) / 'share' / 'robodyn_ros' / 'config' / 'scenes')
    out = []
    for c in cands:
        if c.is_dir() and all(c.resolve() != o.resolve() for o in out):
            out.append(c)
    return out


def _bundled() -> dict:
    """name -> path of every bundled scene (the first directory that has a name wins)."""
    found = {}
    for d in scene_dirs():
        for p in sorted(d.glob('*.yaml')):
            found.setdefault(p.stem, p)
    return found


def find_scene(name_or_path) -> Path:
    """Path of a scene given a bundled name or a file path.

    name_or_path: an existing file path, a path ending in .yaml/.yml, or a bundled name.
    Raises :class:`SceneError` when nothing matches.
    """
    s = os.fspath(name_or_path)
    p = Path(s)
    if p.is_file():
        return p
    if p.suffix in ('.yaml', '.yml') or os.sep in s:
        raise SceneError(f'{s}: (file): no such scene file')
    bundled = _bundled()
    if s in bundled:
        return bundled[s]
    raise SceneError(f'{s}: (name): no bundled scene of that name; bundled scenes: {", ".join(sorted(bundled))} '
                     f'(searched {", ".join(str(d) for d in scene_dirs())})')


def load_scene(name_or_path, position_limits: dict | None = None, command_interface: str | None = None,
               sensors=None) -> Scene:
    """Load a bundled scene by name (``stanford_arm``), a scene file by path, or a URDF file.

    name_or_path: name or path (str or PathLike); a path ending in ``.urdf`` is imported as a
    one-part scene (:func:`urdf_scene_text`), with ``position_limits`` (``{stiffness, damping,
    return}``, optional), ``command_interface`` (``effort``, ``position`` or ``velocity`` for every
    actuated joint) and ``sensors`` (the scene's list) as its keys; a scene file gives them itself
    (refused here).
    Returns the validated :class:`Scene`; raises :class:`SceneError` whose message is
    ``<file>: <key path>: <reason>``.
    """
    s = os.fspath(name_or_path)
    if s.lower().endswith('.urdf'):  # a robot description alone: a one-part scene around it
        return parse_scene(urdf_scene_text(s, position_limits=position_limits, command_interface=command_interface,
                                           sensors=sensors), file=s, path=s)
    for key, given, where in (('position_limits', position_limits, 'position_limits on its kind: urdf part'),
                              ('command_interface', command_interface, 'command_interfaces on its part'),
                              ('sensors', sensors, 'a sensors list')):
        if given is not None:
            raise SceneError(f'{s}: ({key}): applies to a URDF file only; a scene file gives {where}')
    p = find_scene(name_or_path)
    try:
        text = p.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f'{p}: (file): cannot read: {e}') from None
    return parse_scene(text, file=str(p), path=str(p))


def urdf_scene_text(urdf_file=None, floating: bool = False, text: str | None = None,
                    position_limits: dict | None = None, command_interface: str | None = None, sensors=None) -> str:
    """Scene YAML of one URDF: ``kind: urdf`` mounted on the world (or ``floating``), no scripted
    commands, default settings. urdf_file: its path (``load_scene('robot.urdf')``, ``robodyn run
    robot.urdf``, the node's ``robot_description_file``), or text: the URDF itself (the node
    reading ``robot_description``). A URDF whose root is a massless ``world`` link with a
    floating joint is floating anyway. position_limits: the part's ``position_limits`` mapping
    (``{stiffness, damping, return}``; None = URDF position limits reported only); command_interface:
    ``effort`` (None: the default), ``position`` or ``velocity`` for every actuated joint (the part's
    ``command_interfaces``); sensors: the scene's ``sensors`` list (None: none)."""
    part = {'kind': 'urdf'}
    if text is None:
        p = Path(urdf_file)
        if not p.is_file():
            raise SceneError(f'{urdf_file}: (file): no such URDF file')
        name, origin, part['file'] = p.stem, str(p.resolve()), str(p.resolve())
    else:
        m = re.search(r'<robot[^>]*\sname="([^"]*)"', text)
        name, origin, part['urdf'] = (m.group(1) if m else 'robot'), 'robot_description', text
    part['name'] = name = re.sub(r'[^A-Za-z0-9_]', '_', name) or 'robot'
    if floating:
        part['floating'] = True
    if position_limits is not None:
        part['position_limits'] = dict(position_limits)
    if command_interface is not None:
        part['command_interfaces'] = command_interface
    scene = {'name': name, 'description': f'imported from {origin}', 'parts': [part]}
    if sensors is not None:
        scene['sensors'] = sensors
    return yaml.safe_dump(scene, sort_keys=False)


def list_scenes() -> list:
    """``[(name, description), ...]`` of the bundled scenes, sorted by name.

    Only the ``description`` is read (quickly, without building the systems); an unreadable
    file is listed with the parse error as its description.
    """
    out = []
    for name, p in sorted(_bundled().items()):
        try:
            data = yaml.load(p.read_text(encoding='utf-8'), Loader=SceneLoader)
            desc = data.get('description', '') if isinstance(data, dict) else ''
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
            desc = f'(unreadable: {e.__class__.__name__})'
        out.append((name, ' '.join(str(desc).split())))
    return out
