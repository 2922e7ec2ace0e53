"""Foxglove layouts that fit the robot: ``robodyn layout SCENE|IN.mcap``.

A layout (Foxglove's exported-layout JSON: ``configById`` and a split tree) is made from what a run
of the scene publishes, read either from the scene (its outputs and ``/tf`` at the initial state,
:func:`scene_info`) or from a recording (its channels and first messages, :func:`recording_info`);
both give the same :class:`LayoutInfo` for a recording of the scene, hence the same layout. Panels:

* 3D: ``/robot_description`` switched on (Foxglove hides it until clicked), its STL and OBJ meshes
  read Z-up as ROS writes them (Foxglove's default is Y-up), ``/markers`` too on a ground or with
  sensors, the TF axes hidden (the robot's shapes stand for them), the camera at a distance of about
  four times the robot's size (from ``/tf`` at the start), following the floating base if any;
* plots of the joint positions and efforts (up to :data:`MAX_LINES` joints, labelled by name);
* a plot of the reactions that characterise the system: on a ground the contact forces (``force.z``
  of every ``contact_wrenches/<link>``); else the named contacts and drives (wheel contacts, the
  table's ``base_plane``, ``end_effector_drive``); else the constraint forces at the second and
  third joint wrench (the first carries the whole robot's weight, less telling);
* the relative energy drift from ``diagnostics``;
* for a live run (``--live``), a Publish panel holding a zero command for the first command topic.

Every path names a field the run records, so no panel is empty (``test/test_foxglove_layout.py``
checks every bundled scene against a recording of it).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

__all__ = ['LayoutInfo', 'scene_info', 'recording_info', 'layout', 'layout_text', 'MAX_LINES']

#: most lines in one plot (a human's 48 joint coordinates would be unreadable)
MAX_LINES = 12
#: wrenches that are reactions of contacts and drives, not of joints (their names in constraint_wrenches/)
NAMED_REACTIONS = ('left_wheel_contact', 'right_wheel_contact', 'base_plane', 'end_effector_drive')


@dataclass
class LayoutInfo:
    """What a layout needs to know of a run (topics relative to ``prefix``: '' or a namespace).

    joints: joint_states names; wrenches: constraint wrench names in publication order; contacts:
    links with a ``contact_wrenches`` topic; markers: a ``markers`` topic is recorded; follow: the
    floating base's frame (the odom child) or None; frames: every /tf and /tf_static frame; centre
    (3,), extent (m): where the robot is and how big at the start; commands: ``[(topic, type, n)]``.
    """

    name: str
    joints: list
    wrenches: list = field(default_factory=list)
    contacts: list = field(default_factory=list)
    markers: bool = False
    follow: str | None = None
    frames: list = field(default_factory=list)
    centre: tuple = (0.0, 0.0, 0.0)
    extent: float = 1.0
    commands: list = field(default_factory=list)
    prefix: str = ''


def _geometry(transforms) -> tuple:
    """``(frames, centre, extent)`` of ``[(parent, child, p, q)]``: every frame, the centre of the frame
    origins in the root frame and the largest distance of one from it (m)."""
    parent = {c: (pa, np.asarray(p, dtype=float), np.asarray(q, dtype=float)) for pa, c, p, q in transforms}
    frames = sorted(set(parent) | {pa for pa, _, _, _ in transforms})
    pose = {}

    def world(f, depth=0):
        if f in pose:
            return pose[f]
        if f not in parent or depth > 1000:
            pose[f] = (np.eye(3), np.zeros(3))
            return pose[f]
        pa, p, q = parent[f]
        R0, p0 = world(pa, depth + 1)
        x, y, z, w = q
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        pose[f] = (R0 @ R, p0 + R0 @ p)
        return pose[f]
    pts = np.array([world(f)[1] for f in frames]) if frames else np.zeros((1, 3))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    extent = float(np.max(np.linalg.norm(pts - centre, axis=1)))
    return frames, tuple(float(c) for c in centre), extent


def scene_info(scene) -> LayoutInfo:
    """The :class:`LayoutInfo` of a run of ``scene`` (a loaded :class:`robodyn_ros.scene.Scene`)."""
    from .recording.markers import Markers
    from .tf import TfTree
    s = scene.system
    out = s.outputs(0.0, np.asarray(scene.y0, dtype=float), s.zero_inputs(), wrenches=True)
    tf = TfTree(s)
    trs = [(tr['header']['frame_id'], tr['child_frame_id'], tuple(tr['transform']['translation'].values()),
            tuple(tr['transform']['rotation'].values())) for tr in tf.static_message(0)['transforms']]
    trs += tf.transforms(out.joint_names, out.position, out.odom)
    frames, centre, extent = _geometry(trs)
    from .messages import PORT_TOPICS, TOPIC_TYPES
    commands = [('/' + PORT_TOPICS[p], TOPIC_TYPES[PORT_TOPICS[p]], s.inputs[p].size) for p in s.inputs
                if p in PORT_TOPICS and s.inputs[p].size > 0]
    return LayoutInfo(name=scene.name, joints=list(out.joint_names), wrenches=list(out.wrenches),
                      contacts=list(out.contacts), markers=Markers.of(s) is not None,
                      follow=out.odom_child if out.odom is not None else None, frames=frames, centre=centre,
                      extent=extent, commands=commands)


def recording_info(path) -> LayoutInfo:
    """The :class:`LayoutInfo` of a recording: its topics in the order they were first written, its
    first ``joint_states``, ``odom``, ``/tf``, ``/tf_static`` and command messages, the scene name of
    its ``robodyn`` metadata. Raises ValueError when it has no joint_states."""
    from .messages import PORT_TOPICS
    from .recording import cdr
    from .recording.reader import read_raw_messages, summarize
    summary = summarize(path)
    topics = list(summary['topics'])
    prefix = _prefix(topics)
    rel = {t: _relative(t, prefix) for t in topics}
    command_topics = {'/' + t for t in PORT_TOPICS.values()}
    want = ({'/joint_states', '/odom', '/tf', '/tf_static'} | command_topics) & set(rel.values())
    first = {}
    for topic, type_name, _, data in read_raw_messages(path):
        key = rel.get(topic)
        if key in want and key not in first:
            first[key] = cdr.decode(type_name, data)
            if len(first) == len(want):
                break
    js = first.get('/joint_states')
    if js is None:
        raise ValueError(f'{path}: no joint_states recorded; a layout plots them')
    trs = [(tr['header']['frame_id'], tr['child_frame_id'], tuple(tr['transform']['translation'].values()),
            tuple(tr['transform']['rotation'].values()))
           for key in ('/tf_static', '/tf') for tr in first.get(key, {}).get('transforms', [])]
    frames, centre, extent = _geometry(trs)
    odom = first.get('/odom')
    commands = []
    for t in topics:
        key = rel[t]
        if key in command_topics:
            msg = first[key]
            if 'wrench' in msg:
                n = 6
            elif 'data' in msg:     # Float64MultiArray: effort, voltage, position, velocity commands
                n = len(msg['data']) - msg['layout']['data_offset']
            else:                   # a JointTrajectory: no fixed size (its port's size is 0: no Publish panel)
                n = 0
            if n:
                commands.append((key, summary['topics'][t]['type'], n))
    md = summary.get('metadata', {}).get('robodyn', {})
    return LayoutInfo(name=md.get('scene_name') or str(path), joints=list(js['name']),
                      wrenches=[k[len('/constraint_wrenches/'):] for k in rel.values()
                                if k.startswith('/constraint_wrenches/')],
                      contacts=[k[len('/contact_wrenches/'):] for k in rel.values()
                                if k.startswith('/contact_wrenches/')],
                      markers='/markers' in rel.values(), follow=odom['child_frame_id'] if odom else None,
                      frames=frames, centre=centre, extent=extent, commands=commands, prefix=prefix)


def _prefix(topics) -> str:
    """The namespace the relative topics were recorded under ('' at the root)."""
    for t in topics:
        if t.endswith('/joint_states'):
            return t[:-len('/joint_states')]
    return ''


def _relative(topic: str, prefix: str) -> str:
    """A recorded topic as at the root: ``/ns/joint_states`` -> ``/joint_states`` (``/tf`` stays)."""
    return topic[len(prefix):] if prefix and topic.startswith(prefix + '/') else topic


# -- the layout -------------------------------------------------------------------------------
def _plot(title: str, paths) -> dict:
    """A Plot panel's config: ``paths`` = ``[(message path, label)]`` against the recording's time."""
    return {'foxglovePanelTitle': title,
            'paths': [{'value': v, 'enabled': True, 'timestampMethod': 'receiveTime', 'label': label}
                      for v, label in paths],
            'showXAxisLabels': True, 'showYAxisLabels': True, 'showLegend': True, 'legendDisplay': 'floating',
            'showPlotValuesInLegend': False, 'isSynced': True, 'xAxisVal': 'timestamp', 'sidebarDimension': 240}


def _reactions(info: LayoutInfo, p: str) -> tuple:
    """``(title, paths)`` of the reactions plot (see the module docstring)."""
    if info.contacts:
        return ('ground contact forces, vertical (N, world axes)',
                [(f'{p}/contact_wrenches/{c}.wrench.force.z', c) for c in info.contacts[:MAX_LINES]])
    named = [w for w in info.wrenches if w in NAMED_REACTIONS]
    if named:
        comps = {'left_wheel_contact': 'xz', 'right_wheel_contact': 'xz', 'base_plane': 'z'}
        paths = [(f'{p}/constraint_wrenches/{w}.wrench.force.{a}', f'{w} force.{a}')
                 for w in named for a in comps.get(w, 'xyz')]
        return ('contact and drive forces (N, in their frames)', paths[:MAX_LINES])
    chosen = info.wrenches[1:3] if len(info.wrenches) >= 3 else info.wrenches[:2]
    return (f'constraint forces of {" and ".join(chosen)} (N, child link axes)',
            [(f'{p}/constraint_wrenches/{w}.wrench.force.{a}', f'{w} force.{a}') for w in chosen for a in 'xyz'])


def _zero_command(type_name: str, n: int) -> str:
    """JSON text of a zero command (what a Publish panel starts from)."""
    if type_name.endswith('WrenchStamped'):
        msg = {'header': {'frame_id': 'base_link'}, 'wrench': {'force': {'x': 0, 'y': 0, 'z': 0},
                                                               'torque': {'x': 0, 'y': 0, 'z': 0}}}
    else:
        msg = {'layout': {'dim': [], 'data_offset': 0}, 'data': [0.0] * n}
    return json.dumps(msg, indent=2)


def layout(info: LayoutInfo, live: bool = False) -> dict:
    """The layout (Foxglove's exported-layout JSON as a dict) of a run described by ``info``; live:
    add a Publish panel for the first command topic (a live run takes commands from the viewer)."""
    p = info.prefix
    r = max(info.extent, 0.1)
    distance = round(min(max(4.0 * r, 1.0), 20.0), 2)
    cx, cy, cz = (round(c, 3) for c in info.centre)
    three_d = {
        'foxglovePanelTitle': f'{info.name}: the robot (robot_description on /tf)',
        'cameraState': {'distance': distance, 'perspective': True, 'phi': 60, 'thetaOffset': 45,
                        'target': [0, 0, 0], 'targetOffset': [0, 0, 0] if info.follow else [cx, cy, cz],
                        'targetOrientation': [0, 0, 0, 1], 'fovy': 45, 'near': 0.01, 'far': 1000},
        'followMode': 'follow-position' if info.follow else 'follow-none',
        # URDF meshes are Z-up (ROS REP-103; RViz reads an STL as it is), but Foxglove reads STL and OBJ meshes
        # as Y-up unless told (3D panel > Scene > Mesh up axis; Studio 1.48's DEFAULT_MESH_UP_AXIS = "y_up"):
        # without this an STL robot (xarm7, solo12) is drawn with every link's mesh turned 90° about x
        'scene': {'meshUpAxis': 'z_up', 'transforms': {'showLabel': False, 'axisScale': round(0.2 * r, 3)}},
        'transforms': {f'frame:{f}': {'visible': False} for f in info.frames},
        'topics': {f'{p}/robot_description': {'visible': True},
                   **({f'{p}/markers': {'visible': True}} if info.markers else {})},
        'layers': {'grid': {'visible': True, 'frameLocked': True, 'label': 'Grid', 'instanceId': 'grid',
                            'layerId': 'foxglove.Grid', 'size': 10, 'divisions': 20, 'lineWidth': 1,
                            'color': '#248eff', 'position': [0, 0, 0], 'rotation': [0, 0, 0], 'order': 1}},
        'publish': {'type': 'point', 'poseTopic': '/move_base_simple/goal', 'pointTopic': '/clicked_point',
                    'poseEstimateTopic': '/initialpose', 'poseEstimateXDeviation': 0.5,
                    'poseEstimateYDeviation': 0.5, 'poseEstimateThetaDeviation': 0.26179939},
        'imageMode': {}}
    if info.follow:
        three_d['followTf'] = info.follow
    joints = info.joints[:MAX_LINES]
    more = f' (the first {MAX_LINES} of {len(info.joints)})' if len(info.joints) > MAX_LINES else ''
    title, reactions = _reactions(info, p)
    panels = {
        '3D!robodyn': three_d,
        'Plot!positions': _plot(f'joint positions (rad or m){more}',
                                [(f'{p}/joint_states.position[{k}]', n) for k, n in enumerate(joints)]),
        'Plot!efforts': _plot(f'joint efforts (N m or N){more}',
                              [(f'{p}/joint_states.effort[{k}]', n) for k, n in enumerate(joints)]),
        'Plot!reactions': _plot(title, reactions),
        'Plot!energy': _plot('energy drift, relative to the energy scale (diagnostics)',
                             [(f'{p}/diagnostics.status[:].values[:]{{key=="energy_drift_relative"}}.value',
                               'energy_drift_relative')]),
    }
    view = '3D!robodyn'
    if live and info.commands:
        topic, type_name, n = info.commands[0]
        panels['Publish!command'] = {'topicName': p + topic, 'datatype': type_name,
                                     'buttonText': f'Publish {topic.lstrip("/")}',
                                     'buttonTooltip': 'the command enters the simulation at the next period',
                                     'buttonColor': '#00A871', 'advancedView': True,
                                     'value': _zero_command(type_name, n)}
        view = {'direction': 'column', 'first': '3D!robodyn', 'second': 'Publish!command', 'splitPercentage': 75}
    return {'configById': panels, 'globalVariables': {}, 'userNodes': {}, 'playbackConfig': {'speed': 1},
            'layout': {'direction': 'row', 'first': view,
                       'second': {'direction': 'column',
                                  'first': {'direction': 'column', 'first': 'Plot!positions',
                                            'second': 'Plot!efforts', 'splitPercentage': 50},
                                  'second': {'direction': 'column', 'first': 'Plot!reactions',
                                             'second': 'Plot!energy', 'splitPercentage': 50},
                                  'splitPercentage': 50},
                       'splitPercentage': 55}}


def layout_text(info: LayoutInfo, live: bool = False) -> str:
    """:func:`layout` as the JSON text of a layout file (stable key order, 2-space indent)."""
    return json.dumps(layout(info, live), indent=2) + '\n'
