"""The exported ``robot_description``: every number at full precision, Pinocchio rebuilt from a
recording holds the simulator's conservation, and the drawn shapes fit their links.

* Numbers: every inertial value, axis, limit and damping of the URDF parses back to the model's
  double bit for bit, and joint origins to round-off (they are recovered from ``Xtree``), on every
  bundled scene and on random trees with 17-digit values.
* ``huston_human17`` recorded headless (RK4 at 0.1 ms): Pinocchio built from the recording's
  ``robot_description`` alone (its free-flyer root, the three revolute joints per spherical joint)
  has the scene's masses, CoMs and inertias exactly, and the momentum it computes from the
  recorded ``odom`` and ``joint_states`` stays constant to the integrator's round-off (1e-10).
* Shapes (the rule is documented in docs/urdf.md): every link has a visual except the massless
  frames between the joints of a compound joint; a link with mass and child joints draws nothing
  that passes its key points (origin, child joint origins, CoM c and 2c) by more than the margin
  along the directions they span. The Stanford arm's boom no longer sticks out of both ends.
"""
from __future__ import annotations

import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from pin_helpers import centroidal_momenta
from robodyn_ros.model import FREE, SPHERICAL, random_tree, to_urdf
from robodyn_ros.scene import list_scenes, load_scene
from robodyn_ros.spatial import rpy_to_R

BUNDLED = [n for n, _ in list_scenes()]
NUMBER = re.compile(r'^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$')


def _vec(s):
    return np.array([float(x) for x in s.split()]) if s else np.zeros(3)


def _links_and_joints(text):
    root = ET.fromstring(text)
    return {lk.get('name'): lk for lk in root.findall('link')}, {j.get('name'): j for j in root.findall('joint')}


# ------------------------------------------------------------------------------------------------
# numbers: full precision
# ------------------------------------------------------------------------------------------------
def _models():
    out = [(n, load_scene(n).system.model) for n in BUNDLED]
    rng = np.random.default_rng(31)
    out += [(f'random{k}', random_tree(6, rng, spherical_fraction=0.3 * (k % 2), free_root=k == 2)) for k in range(3)]
    return out


@pytest.mark.parametrize('label,model', _models(), ids=[lbl for lbl, _ in _models()])
def test_every_exported_number_parses_back_to_the_models_double(label, model):
    text = to_urdf(model)
    root = ET.fromstring(text)
    # an imported URDF's <visual> elements are exported as written (model.LinkSpec.visuals): not the model's numbers
    copied = {id(el) for vis in root.iter('visual') for el in vis.iter()} if any(
        s.visuals for s in model.specs) else set()
    tokens = [t for el in root.iter() if id(el) not in copied for k, v in el.attrib.items()
              if k in ('xyz', 'rpy', 'value', 'ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz', 'lower', 'upper', 'effort',
                       'velocity', 'damping', 'friction', 'radius', 'length', 'size') for t in v.split()]
    assert len(tokens) > 20 and all(NUMBER.match(t) for t in tokens), label
    # every number is repr(double), the shortest text that reads back to the same bits (or a
    # constant integer literal of the format: '0 0 0', '1e6')
    odd = [t for t in tokens if repr(float(t)) != t and float(t) != int(float(t))]
    assert not odd, odd[:5]
    links, joints = _links_and_joints(text)
    checked = 0
    for i, s in enumerate(model.specs):
        if s.mass > 0:
            inn = links[s.name].find('inertial')
            assert float(inn.find('mass').get('value')) == float(s.mass)
            assert tuple(_vec(inn.find('origin').get('xyz'))) == tuple(float(c) for c in s.com)
            Ic = np.asarray(s.inertia, dtype=float)
            got = [float(inn.find('inertia').get(k)) for k in ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz')]
            assert got == [Ic[0, 0], Ic[0, 1], Ic[0, 2], Ic[1, 1], Ic[1, 2], Ic[2, 2]], (label, s.name)
            checked += 1
        jt = int(model.jtype[i])
        if jt == SPHERICAL:
            j = joints[s.joint + '_x']
        else:
            j = joints[s.joint]
        o = j.find('origin')
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = rpy_to_R(_vec(o.get('rpy'))), _vec(o.get('xyz'))
        E = model.Xtree[i][:3, :3]
        np.testing.assert_allclose(T[:3, :3], E.T, rtol=0, atol=4e-16)
        np.testing.assert_allclose(T[:3, 3], np.asarray(s.origin_xyz, dtype=float), rtol=1e-15, atol=1e-16)
        if jt not in (SPHERICAL, FREE) and j.find('axis') is not None:
            assert tuple(_vec(j.find('axis').get('xyz'))) == tuple(model.axis[i])
            if s.damping:
                assert float(j.find('dynamics').get('damping')) == float(s.damping)
            if s.limits is not None:
                lim = j.find('limit')
                assert (float(lim.get('lower')), float(lim.get('upper'))) == tuple(float(x) for x in np.ravel(s.limits))
    assert checked > 0


@pytest.fixture(scope='module')
def human17_recording(tmp_path_factory):
    """huston_human17, 0.5 s headless, RK4 at 0.1 ms (the integrator's own momentum drift is then
    at round-off), decoded by the mcap readers."""
    out = tmp_path_factory.mktemp('h17') / 'h17.mcap'
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', 'huston_human17', '--duration', '0.5',
                        '--integrator', 'rk4', '--dt', '1e-4', '--record', str(out)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    msgs = {}
    with open(out, 'rb') as f:
        for _, channel, message, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            msgs.setdefault(channel.topic, []).append((message.log_time, msg))
    return msgs


def test_pinocchio_from_the_recorded_description_has_the_scenes_inertias(human17_recording):
    urdf = human17_recording['/robot_description'][0][1].data
    pm = pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer())
    specs = {s.name: s for s in load_scene('huston_human17').system.model.specs}
    seen = 0
    for jid in range(1, pm.njoints):
        body = [f.name for f in pm.frames if f.parentJoint == jid and f.type == pin.FrameType.BODY]
        inert = pm.inertias[jid]
        if inert.mass == 0.0:
            continue
        s = specs[body[-1]]
        assert inert.mass == s.mass and tuple(inert.lever) == tuple(float(c) for c in s.com), s.name
        # Pinocchio sums each body's inertia into its joint's (the massless links of the spherical
        # joints add zeros): equal to 1 ulp
        np.testing.assert_allclose(inert.inertia, np.asarray(s.inertia, dtype=float), rtol=3e-16, atol=1e-19)
        seen += 1
    assert seen == 17


def test_momentum_rebuilt_from_the_recording_is_conserved_to_round_off(human17_recording):
    """Pinocchio's centroidal momentum from the recorded messages alone (the method of
    test_node_human17, there at RK4 1 ms where the integrator drifts ~1e-7) is constant to 1e-10
    relative over 0.5 s: measured 2e-12 (p) and 3e-13 (L)."""
    msgs = human17_recording
    pm = pin.buildModelFromXML(msgs['/robot_description'][0][1].data, pin.JointModelFreeFlyer())
    ps, Ls, _ = centroidal_momenta(pm, msgs)
    assert len(ps) == 51 and np.linalg.norm(ps[0]) > 10 and np.linalg.norm(Ls[0]) > 10
    dp = np.linalg.norm(ps - ps[0], axis=1).max() / np.linalg.norm(ps[0])
    dL = np.linalg.norm(Ls - Ls[0], axis=1).max() / np.linalg.norm(Ls[0])
    print(f'momentum from the recording: |dp|/|p| {dp:.1e}, |dL|/|L| {dL:.1e}')
    assert dp < 1e-10 and dL < 1e-10


# ------------------------------------------------------------------------------------------------
# drawn shapes fit their links
# ------------------------------------------------------------------------------------------------
MARGIN, FRACTION, MIN_SIZE = 0.06, 0.3, 0.01   # the rule's numbers, as docs/urdf.md states them


def _extreme_points(visual):
    """The extreme points (k, 3) of a box, cylinder or sphere visual, in its link's frame."""
    o = visual.find('origin')
    R, p = rpy_to_R(_vec(o.get('rpy'))), _vec(o.get('xyz'))
    g = visual.find('geometry')[0]
    if g.tag == 'box':
        local = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * _vec(g.get('size')) / 2
    elif g.tag == 'cylinder':
        r, h = float(g.get('radius')), float(g.get('length'))
        a = np.linspace(0, 2 * np.pi, 64, endpoint=False)
        local = np.array([(r * np.cos(t), r * np.sin(t), z) for t in a for z in (-h / 2, h / 2)])
    else:
        assert g.tag == 'sphere', g.tag
        local = np.vstack([np.eye(3), -np.eye(3)]) * float(g.get('radius'))
    return p + local @ R.T


def _fit_excess(points, key):
    """How far (m) the points pass the key points' range, beyond the margin, along the directions
    the key points span (> 0: does not fit)."""
    _, _, Vt = np.linalg.svd(key - key.mean(axis=0))
    worst = -np.inf
    for u in Vt:
        k, x = key @ u, points @ u
        e = k.max() - k.min()
        if e > MIN_SIZE:
            pad = max(MARGIN, FRACTION * e)
            worst = max(worst, k.min() - pad - x.min(), x.max() - k.max() - pad)
    return worst


@pytest.mark.parametrize('scene', BUNDLED)
def test_every_link_has_a_visual_that_fits_it(scene):
    system = load_scene(scene).system
    text = system.urdf()
    # an imported URDF's links keep their own <visual> elements, or none (exported as written): not drawn here
    specs = system.model.specs
    imported = {s.name for s in specs} if any(s.visuals for s in specs) else set()
    links, joints = _links_and_joints(text)
    children = {}
    parent_type = {}
    for j in joints.values():
        children.setdefault(j.find('parent').get('link'), []).append(_vec(j.find('origin').get('xyz')))
        parent_type[j.find('child').get('link')] = j.get('type')
    roots = [n for n in links if n not in parent_type]
    checked = 0
    for name, lk in links.items():
        if name in imported:
            continue
        vis = lk.findall('visual')
        inn = lk.find('inertial')
        mass = float(inn.find('mass').get('value')) if inn is not None else 0.0
        kids = children.get(name, [])
        if not vis and mass == 0.0 and name in roots and name not in {s.name for s in specs}:
            continue  # the fixed world frame the export adds above an imported robot's own root (no body)
        if not vis:   # only a massless frame between the joints of a compound joint
            assert mass == 0.0 and name not in roots and kids and all(np.linalg.norm(p) < MIN_SIZE for p in kids), \
                (scene, name)
            continue
        if mass > 0.0 and kids and parent_type.get(name) not in (None, 'floating'):
            c = _vec(inn.find('origin').get('xyz'))
            key = np.vstack([np.zeros(3), c, 2 * c] + kids)
            for v in vis:
                assert _fit_excess(_extreme_points(v), key) <= 1e-12, (scene, name, ET.tostring(v)[:200])
            checked += 1
    assert checked >= 1 or scene in ('betancur_platform', 'betancur_platform_turn') or imported


def test_stanford_arm_boom_base_and_tool_are_drawn_where_they_are():
    """The boom (link3, whose inertia is a uniform rod of 2.66 m) is drawn from the wrist back to
    twice its CoM (1.29 m), not through both ends of the base; base_link shows the 0.412 m
    pedestal to joint1 and the tool point a small sphere."""
    links, joints = _links_and_joints(load_scene('stanford_arm').system.urdf())
    boom = np.vstack([_extreme_points(v) for v in links['link3'].findall('visual')])
    assert -1.29 - 0.04 < boom[:, 2].min() < -1.29 + 0.04 and boom[:, 2].max() < 0.04
    base = np.vstack([_extreme_points(v) for v in links['base_link'].findall('visual')])
    assert abs(base[:, 2].max() - 0.412) < 1e-9 and abs(base[:, 2].min()) < 1e-9
    tool = links['tool'].findall('visual')
    assert len(tool) == 1 and tool[0].find('geometry/sphere') is not None


def test_drawn_shapes_do_not_change_the_dynamics_pinocchio_reads():
    """Visuals only: the stanford_arm URDF with and without them gives Pinocchio the same model."""
    text = load_scene('stanford_arm').system.urdf()
    bare = re.sub(r'<visual>.*?</visual>', '', text)
    a, b = pin.buildModelFromXML(text), pin.buildModelFromXML(bare)
    q = np.array([0.3, 1.0, 0.8, 0.3, 0.8, 0.2])
    assert np.array_equal(pin.crba(a, a.createData(), q), pin.crba(b, b.createData(), q))


def test_names_with_xml_special_characters_are_escaped_and_read_back():
    """Link and joint names with ``&``, ``<``, ``>`` and ``"`` (legal in a URDF as escaped attribute
    text): the export escapes them; our reader and Pinocchio's (urdfdom) read the same names back."""
    import pinocchio as pin

    from robodyn_ros.model import LinkSpec, build_model, to_urdf
    from robodyn_ros.urdf import read_urdf
    odd = ['arm & "hand"', 'j<1>', 'tool&>']
    links = [LinkSpec(name=odd[0], joint=odd[1], parent=None, axis=(0, 1, 0), mass=1.0, com=(0.2, 0, 0),
                      inertia=np.diag([1e-3, 2e-3, 2e-3]), limits=(-1.0, 1.0)),
             LinkSpec(name='tip', joint=odd[2], parent=odd[0], origin_xyz=(0.4, 0, 0), axis=(0, 0, 1), mass=0.5,
                      com=(0.1, 0, 0), inertia=np.diag([1e-3] * 3), mimic=(odd[1], 0.5, 0.0))]
    text = to_urdf(build_model(links, name='a<b>&"c"'))
    r = read_urdf(text)
    assert r.name == 'a<b>&"c"'
    assert [s.name for s in r.specs if s.joint_type != 'fixed'] == [odd[0], 'tip']
    assert [s.joint for s in r.specs if s.joint_type != 'fixed'] == [odd[1], odd[2]]
    assert r.specs[-1].mimic[0] == odd[1]
    pm = pin.buildModelFromXML(text)
    assert list(pm.names)[1:] == [odd[1], odd[2]]


def test_a_fixed_base_urdfs_root_link_keeps_its_visuals_moved_by_the_mount_pose():
    """The root link of a URDF on a fixed base is no body of the model, but it is drawn: panda_link0's mesh (its
    base) is in the exported description, as the file has it; with the part's ``origin``, the visual moves with
    the joints that hang from it: its exported origin is the mount pose times the file's (composed here with
    scipy's rotations, not the package's). Every other link keeps its visuals too."""
    from robodyn_ros.scene import parse_scene
    from robodyn_ros.urdf import example_robot_data_dir
    path = example_robot_data_dir() / 'panda_description' / 'urdf' / 'panda.urdf'
    source = ET.parse(path).getroot()
    original = {lk.get('name'): lk.findall('visual') for lk in source.iter('link')}
    assert len(original['panda_link0']) == 1
    mesh = original['panda_link0'][0].find('geometry/mesh').get('filename')

    def exported(extra=''):
        text = f'name: p\nparts:\n  - kind: urdf\n    name: panda\n    file: {path}\n{extra}'
        return {lk.get('name'): lk.findall('visual') for lk in ET.fromstring(parse_scene(text, file='p.yaml')
                                                                             .system.urdf()).iter('link')}

    plain = exported()
    for name, visuals in original.items():
        assert [v.find('geometry/mesh').get('filename') for v in plain[name]] == \
               [v.find('geometry/mesh').get('filename') for v in visuals], name
    xyz, rpy = [0.3, -0.2, 0.1], [0.1, -0.2, 0.7]
    moved = exported(f'    origin: {{xyz: {xyz}, rpy: {rpy}}}\n')
    (v,) = moved['panda_link0']
    assert v.find('geometry/mesh').get('filename') == mesh
    _assert_at_mount_pose(v, original['panda_link0'][0], xyz, rpy)


def _assert_at_mount_pose(got, given, xyz, rpy):
    """The exported visual got is the file's visual given moved by the mount pose (xyz, rpy): its origin is the
    pose times the file's, composed with scipy's rotations (not the package's)."""
    from scipy.spatial.transform import Rotation
    o = given.find('origin')
    t_file = _vec(o.get('xyz') if o is not None else '')
    r_file = Rotation.from_euler('xyz', _vec(o.get('rpy') if o is not None else ''))
    r0 = Rotation.from_euler('xyz', rpy)
    np.testing.assert_allclose(_vec(got.find('origin').get('xyz')), r0.apply(t_file) + xyz, atol=1e-15)
    np.testing.assert_allclose(Rotation.from_euler('xyz', _vec(got.find('origin').get('rpy'))).as_matrix(),
                               (r0 * r_file).as_matrix(), atol=1e-14)


_PLATFORM = """  - kind: diff_drive
    name: host
    chassis: {mass: 3.3, yaw_inertia: 0.18965, com: [0.0, 0.0, 0.28]}
    wheels: {radius: 0.28, half_track: 0.35, mass: 0.3, spin_inertia: 0.0037}
    motor: {kind: dc_motor, torque_constant: 0.061, resistance: 1.7, inductance: 0.0, supply_voltage: 12.0}
"""
_FREE_BASE = """  - kind: free_base
    name: host
    environment: orbit
    link: base_link
    joint: base_joint
    mass: 25.0
    com: [0.0, 0.0, 0.12]
    inertia: [0.5208, 0.5208, 0.6667, 0.0, 0.0, 0.0]
"""


@pytest.mark.parametrize('host', ['platform', 'free_base'])
def test_a_urdf_arm_on_a_platform_or_a_free_base_is_drawn_whole_with_its_host(host):
    """A URDF arm mounted on a diff_drive platform or a free base: its links keep the file's visuals, its root
    link's (panda_link0, the Panda's base) are drawn on the host's base_link at the mount pose (composed with
    scipy's rotations), and the host keeps its drawn shapes: the platform's chassis and wheels, the free base's
    solid, the same as the host alone draws them. (The host was drawn with nothing, the root link was left out.)"""
    from robodyn_ros.scene import parse_scene
    from robodyn_ros.urdf import example_robot_data_dir
    path = example_robot_data_dir() / 'panda_description' / 'urdf' / 'panda.urdf'
    source = {lk.get('name'): lk.findall('visual') for lk in ET.parse(path).getroot().iter('link')}
    xyz, rpy = [0.05, -0.1, 0.3], [0.0, 0.0, 0.4]
    head = 'name: p\n' + ('gravity: [0, 0, 0]\n' if host == 'free_base' else '') + 'parts:\n'
    host_text = _PLATFORM if host == 'platform' else _FREE_BASE
    arm = (f'  - kind: urdf\n    name: panda\n    file: {path}\n    mount: host\n'
           f'    origin: {{xyz: {xyz}, rpy: {rpy}}}\n'
           '    locked: {panda_finger_joint1: 0.02, panda_finger_joint2: 0.02}\n')

    def links(text):
        return _links_and_joints(parse_scene(text, file='p.yaml').system.urdf())[0]

    alone, both = links(head + host_text), links(head + host_text + arm)
    for name in alone:   # the host's links: drawn as alone (base_link: besides the arm's base, below)
        if name != 'base_link':
            assert [ET.tostring(v).strip() for v in both[name].findall('visual')] == \
                   [ET.tostring(v).strip() for v in alone[name].findall('visual')], name
        assert alone[name].findall('visual') or name.endswith('_contact'), name
    for name, visuals in source.items():
        if name != 'panda_link0':
            assert [v.find('geometry/mesh').get('filename') for v in both[name].findall('visual')] == \
                   [v.find('geometry/mesh').get('filename') for v in visuals], name
    assert 'panda_link0' not in both
    base = both['base_link'].findall('visual')
    meshes = [v for v in base if v.find('geometry/mesh') is not None]
    assert len(meshes) == 1 and len(base) > 1   # the Panda's base, and the host's own shapes
    (v,), (f,) = meshes, source['panda_link0']
    assert v.find('geometry/mesh').get('filename') == f.find('geometry/mesh').get('filename')
    _assert_at_mount_pose(v, f, xyz, rpy)
    if host == 'free_base':   # a floating base's own solid does not depend on what hangs from it
        assert [ET.tostring(x).strip() for x in base if x is not v] == \
               [ET.tostring(x).strip() for x in alone['base_link'].findall('visual')]
