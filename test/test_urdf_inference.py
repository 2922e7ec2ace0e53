"""URDFs other tools accept and the importer used to refuse: moving links without ``<inertial>`` (mass
and inertia inferred from their geometry, against MuJoCo's ``inertiafromgeom``), the ``spherical``
joint type (against the scene format's spherical joint and Pinocchio's), numbers with a trailing dot
(as C's strtod reads them), ``velocity="0"``, and point-mass links."""
from __future__ import annotations

import struct
import subprocess
import sys
import warnings

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import yaml

from robodyn_ros import kernels
from robodyn_ros.bench.pinbridge import pin_model
from robodyn_ros.mass_properties import DENSITY, hull_properties, shape_properties
from robodyn_ros.model import build_model
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.simulation import Simulator, run_headless
from robodyn_ros.spatial import rpy_to_R
from robodyn_ros.systems.base import backend_scope
from robodyn_ros.urdf import UrdfError, UrdfWarning, read_urdf

ROBODYN = [sys.executable, '-m', 'robodyn_ros.cli']


def _read(source, **kw):
    """(robot, [warning messages])."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        r = read_urdf(source, **kw)
    return r, [str(w.message) for w in caught if issubclass(w.category, UrdfWarning)]


def _l_shape_stl(path):
    """A closed, non-convex L-shaped prism (0.2 x 0.1 with a 0.1 x 0.05 notch, 0.04 thick) as binary STL."""
    xy = [(0, 0), (0.2, 0), (0.2, 0.05), (0.1, 0.05), (0.1, 0.1), (0, 0.1)]
    tris = []
    bottom = [(x, y, 0.0) for x, y in xy]
    top = [(x, y, 0.04) for x, y in xy]
    for k in range(1, 5):          # the caps as fans from vertex 0 (only the vertices enter the hull)
        tris.append((bottom[0], bottom[k + 1], bottom[k]))
        tris.append((top[0], top[k], top[k + 1]))
    for k in range(6):             # the sides
        a, b = k, (k + 1) % 6
        tris.append((bottom[a], bottom[b], top[b]))
        tris.append((bottom[a], top[b], top[a]))
    data = b'\0' * 80 + struct.pack('<I', len(tris))
    for t in tris:
        data += struct.pack('<3f', 0, 0, 0) + b''.join(struct.pack('<3f', *v) for v in t) + b'\0\0'
    path.write_bytes(data)
    return np.array([v for t in tris for v in t])


#: link -> (URDF <geometry>, <origin> xyz, rpy, MJCF geom attributes) of the inferred-inertia arm
SHAPES = {
    'box': ('<box size="0.3 0.1 0.05"/>', (0.1, 0.0, 0.2), (0.3, -0.2, 0.5), 'type="box" size="0.15 0.05 0.025"'),
    'cyl': ('<cylinder radius="0.04" length="0.3"/>', (0.0, 0.05, 0.15), (1.2, 0.0, 0.4),
            'type="cylinder" size="0.04 0.15"'),
    'ball': ('<sphere radius="0.06"/>', (0.02, 0.0, 0.1), (0.0, 0.0, 0.0), 'type="sphere" size="0.06"'),
    'cap': ('<capsule radius="0.03" length="0.2"/>', (0.0, 0.0, 0.1), (0.0, 0.7, 0.0), 'type="capsule" size="0.03 0.1"'),
    'mesh': (None, (0.05, -0.02, 0.0), (0.2, 0.1, -0.3), 'type="mesh" mesh="L"'),
}


def _quat(rpy):
    """MuJoCo's quaternion (w, x, y, z) of URDF roll-pitch-yaw angles."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, rpy_to_R(np.asarray(rpy, dtype=float)).reshape(-1))
    return q


def _inferred_arm(tmp_path):
    """(URDF text, MJCF text): a chain of five moving links without <inertial>, each with one collision
    shape (box, cylinder, sphere, capsule, a non-convex mesh scaled 1.5 x 1 x 2), the same shapes as MuJoCo
    geoms of density 1000 in bodies at the same frames."""
    stl = tmp_path / 'L.stl'
    _l_shape_stl(stl)
    links, joints, bodies = ['<link name="base"/>'], [], []
    parent = 'base'
    for k, (name, (geom, xyz, rpy, mj)) in enumerate(SHAPES.items()):
        geom = geom or f'<mesh filename="{stl}" scale="1.5 1 2"/>'
        links.append(f'<link name="{name}"><collision><origin xyz="{" ".join(map(str, xyz))}" '
                     f'rpy="{" ".join(map(str, rpy))}"/><geometry>{geom}</geometry></collision></link>')
        joints.append(f'<joint name="j_{name}" type="revolute"><parent link="{parent}"/><child link="{name}"/>'
                      f'<origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit effort="1" velocity="1" lower="-1" '
                      f'upper="1"/></joint>')
        q = _quat(rpy)
        bodies.append(f'<body name="{name}"><joint type="hinge"/><geom {mj} pos="{" ".join(map(str, xyz))}" '
                      f'quat="{" ".join(repr(float(x)) for x in q)}" density="{DENSITY}"/></body>')
        parent = name
    urdf = '<robot name="inferred">' + ''.join(links) + ''.join(joints) + '</robot>'
    mjcf = (f'<mujoco><asset><mesh name="L" file="{stl}" scale="1.5 1 2" inertia="convex"/></asset>'
            '<worldbody>' + ''.join(bodies) + '</worldbody></mujoco>')
    return urdf, mjcf


def test_moving_links_without_inertial_get_the_mass_properties_mujoco_infers_from_their_geometry(tmp_path):
    """Box, cylinder, sphere, capsule and a non-convex mesh (MuJoCo's convex-hull mesh inertia), each
    placed by its collision origin: mass, centre of mass and inertia of every link equal MuJoCo's body
    mass, ipos and inertia (principal moments rotated by iquat) for the same geoms at density 1000, to
    1e-9 relative; one warning names the five links and the density."""
    urdf, mjcf = _inferred_arm(tmp_path)
    r, notes = _read(urdf)
    inferred = [n for n in notes if 'without <inertial>' in n]
    assert len(inferred) == 1 and 'density 1000 kg/m³' in inferred[0] and all(k in inferred[0] for k in SHAPES), notes
    mj = mujoco.MjModel.from_xml_string(mjcf)
    by = {s.name: s for s in r.specs}
    checked, worst = 0, 0.0
    for name in SHAPES:
        b = mj.body(name).id
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, mj.body_iquat[b])
        R = R.reshape(3, 3)
        I_mj = R @ np.diag(mj.body_inertia[b]) @ R.T
        s = by[name]
        scale = max(np.abs(I_mj).max(), 1e-12)
        err = max(abs(s.mass - mj.body_mass[b]) / mj.body_mass[b], np.abs(np.asarray(s.com) - mj.body_ipos[b]).max(),
                  np.abs(np.asarray(s.inertia) - I_mj).max() / scale)
        worst = max(worst, err)
        checked += 1
    print(f'inferred mass properties vs MuJoCo: worst relative difference {worst:.1e}')
    assert checked == 5 and worst < 1e-12, worst   # measured 8.7e-15 (docs/urdf.md)
    # and the arm simulates: energy conserved by the inferred bodies (no damping)
    with backend_scope('numba'), warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        f = tmp_path / 'inferred.urdf'
        f.write_text(urdf)
        sc = load_scene(f)
        sim = Simulator(sc.system, sc.y0 + np.r_[0.3 * np.ones(5), np.zeros(5)], integrator='rk4', dt=1e-4)
        run_headless(sim, 0.2, 100.0)
        assert abs(sim.energy_report()['relative_drift']) < 1e-9


def test_closed_forms_of_the_primitives_and_the_hull():
    """The formulas themselves against exact values a second way: a box's corners as a mesh give the box;
    a capsule of zero length is the sphere; a long capsule tends to the cylinder of its length + 4r/3."""
    m, c, I = hull_properties(np.array([[x, y, z] for x in (-0.15, 0.15) for y in (-0.05, 0.05)
                                        for z in (-0.025, 0.025)]) + (1.0, 2.0, 3.0))
    mb, _, Ib = shape_properties('box', (0.3, 0.1, 0.05))
    assert abs(m - mb) < 1e-12 * mb and np.allclose(c, (1, 2, 3), atol=1e-14) and np.abs(I - Ib).max() < 1e-12 * Ib.max()
    ms, _, Is = shape_properties('sphere', (0.1,))
    mc, _, Ic = shape_properties('capsule', (0.1, 0.0))
    assert abs(ms - mc) < 1e-15 and np.abs(Is - Ic).max() < 1e-15
    with pytest.raises(ValueError, match='no volume'):
        hull_properties(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=float))


def test_visual_geometry_serves_when_there_is_no_collision_and_density_is_a_scene_key(tmp_path):
    urdf = ('<robot name="v"><link name="a"/><link name="b"><visual><origin xyz="0 0 -0.2"/><geometry><sphere '
            'radius="0.05"/></geometry></visual></link><joint name="j" type="continuous"><parent link="a"/>'
            '<child link="b"/><axis xyz="0 1 0"/></joint></robot>')
    r, notes = _read(urdf)
    m = DENSITY * 4 / 3 * np.pi * 0.05 ** 3
    assert abs(r.specs[0].mass - m) < 1e-12 and np.allclose(r.specs[0].com, (0, 0, -0.2))
    assert len(notes) == 1 and 'b 0.5236 kg (1 visual shape)' in notes[0], notes
    def scene(density):
        return yaml.safe_dump({'name': 'v', 'parts': [{'kind': 'urdf', 'name': 'v', 'density': density, 'urdf': urdf}]})
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        assert abs(parse_scene(scene(500)).system.model.specs[0].mass - m / 2) < 1e-12
        with pytest.raises(SceneError, match=r'density: expected a number >= 0'):
            parse_scene(scene(-1))
        with pytest.raises(SceneError, match=r"missing <inertial> on a moving link, and no <collision> or <visual> "
                                             r"geometry to infer one from"):
            parse_scene(scene(0))   # no inference: the link is massless, nothing moves


def test_a_link_without_geometry_or_with_an_unreadable_mesh_is_refused_in_one_line(tmp_path):
    bare = ('<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="continuous"><parent link="a"/>'
            '<child link="b"/><axis xyz="0 1 0"/></joint></robot>')
    with pytest.raises(UrdfError, match=r"link 'b' \(joint 'j'\): missing <inertial> on a moving link, and no "
                                        r"<collision> or <visual> geometry to infer one from at a leaf"):
        read_urdf(bare)
    lost = bare.replace('<link name="b"/>', '<link name="b"><collision><geometry><mesh filename='
                                            '"package://nowhere_pkg/meshes/b.stl"/></geometry></collision></link>')
    with pytest.raises(UrdfError, match=r"link 'b': has no <inertial>, and its <collision> mesh cannot be read to "
                                        r"infer one \(package://nowhere_pkg/meshes/b.stl: not found") as e:
        read_urdf(lost)
    assert '\n' not in str(e.value)


# ------------------------------------------------------------------------------------------------
# spherical joints
# ------------------------------------------------------------------------------------------------
SPHERICAL_URDF = ('<robot name="ball"><link name="base"/>'
                  '<link name="upper"><inertial><origin xyz="0 0.05 -0.3"/><mass value="2"/><inertia ixx="0.05" '
                  'iyy="0.04" izz="0.02" ixy="0.003" ixz="0" iyz="0.001"/></inertial></link>'
                  '<link name="lower"><inertial><origin xyz="0 0 -0.25"/><mass value="1"/><inertia ixx="0.02" '
                  'iyy="0.02" izz="0.005" ixy="0" ixz="0" iyz="0"/></inertial></link>'
                  '<joint name="shoulder" type="spherical"><parent link="base"/><child link="upper"/>'
                  '<origin xyz="0 0 1" rpy="0.1 0 0"/><limit lower="-1" upper="1" effort="5" velocity="2"/>'
                  '<dynamics damping="0.0"/></joint>'
                  '<joint name="elbow" type="revolute"><parent link="upper"/><child link="lower"/>'
                  '<origin xyz="0 0 -0.6"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="5" velocity="2"/>'
                  '</joint></robot>')

SPHERICAL_SCENE = """
name: ball
parts:
  - kind: arm
    name: ball
    root: base
    links:
      - {name: upper, joint: shoulder, parent: base, type: spherical, origin: {xyz: [0, 0, 1], rpy: [0.1, 0, 0]},
         mass: 2.0, com: [0, 0.05, -0.3], inertia: [0.05, 0.04, 0.02, 0.003, 0.0, 0.001]}
      - {name: lower, joint: elbow, parent: upper, type: revolute, origin: {xyz: [0, 0, -0.6]}, axis: [1, 0, 0],
         mass: 1.0, com: [0, 0, -0.25], inertia: [0.02, 0.02, 0.005, 0.0, 0.0, 0.0]}
"""


def test_a_urdf_spherical_joint_is_the_scene_formats_spherical_joint_and_pinocchios():
    """``type="spherical"`` (a URDF extension some simulators read): the same model as the scene's
    spherical joint (M, ABA at seeded states equal to round-off), and Pinocchio's JointModelSpherical on
    the same tree agrees; its <limit> is ignored with one warning."""
    r, notes = _read(SPHERICAL_URDF)
    assert [s.joint_type for s in r.specs] == ['spherical', 'revolute']
    assert len(notes) == 1 and "joint 'shoulder': a spherical joint" in notes[0] and '<limit effort>' in notes[0]
    mu = build_model(r.specs, root=r.root, name='ball')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        ms = parse_scene(SPHERICAL_SCENE).system.model
    ku, ks = kernels.CompiledModel(mu), kernels.CompiledModel(ms)
    pm, qmap, vmap, _ = pin_model(mu)
    pd = pm.createData()
    rng = np.random.default_rng(12)
    n = 0
    for _ in range(4):
        q = np.r_[rng.normal(size=4), rng.normal()]
        q[:4] /= np.linalg.norm(q[:4])
        v, tau = rng.normal(size=4), rng.normal(size=4)
        assert np.abs(ku.crba(q) - ks.crba(q)).max() < 1e-13 and np.abs(ku.aba(q, v, tau) - ks.aba(q, v, tau)).max() < 1e-12
        qp, vp, tp = np.empty(5), np.empty(4), np.empty(4)
        qp[qmap], vp[vmap], tp[vmap] = q, v, tau
        assert np.abs(ku.aba(q, v, tau) - pin.aba(pm, pd, qp, vp, tp)[vmap]).max() < 1e-10
        n += 1
    assert n == 4


def test_a_urdf_spherical_joint_runs_and_exports_as_three_revolute_joints(tmp_path):
    f = tmp_path / 'ball.urdf'
    f.write_text(SPHERICAL_URDF)
    p = subprocess.run(ROBODYN + ['run', str(f), '--duration', '0.05'], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0 and 'simulated 0.050 s' in p.stdout, p.stderr
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        sc = load_scene(f)
    assert sc.system.model.state_joint_names == ['shoulder_x', 'shoulder_y', 'shoulder_z', 'elbow']


# ------------------------------------------------------------------------------------------------
# numbers, limits, point masses
# ------------------------------------------------------------------------------------------------
PENDULUM = ('<robot name="p"><link name="a"/><link name="b"><inertial><origin xyz="0 0 -0.5"/><mass value="1"/>'
            '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>'
            '<joint name="j" type="revolute"><parent link="a"/><child link="b"/><origin rpy="0 0 -1.57" xyz="0 0 1"/>'
            '<axis xyz="0 1 0"/><limit lower="-1.57" upper="1.57" effort="10" velocity="2"/></joint></robot>')


def test_a_number_with_a_trailing_dot_is_read_as_strtod_reads_it_with_one_warning():
    clean, notes = _read(PENDULUM)
    assert notes == []
    dotted, notes = _read(PENDULUM.replace('rpy="0 0 -1.57"', 'rpy="0 0 -1.57."').replace('upper="1.57"',
                                                                                             'upper="1.57."'))
    assert len(notes) == 1 and notes[0].startswith('2 numbers with a trailing dot read as C\'s strtod reads them'), notes
    assert '<origin rpy="0 0 -1.57.">' in notes[0] and '<limit upper="1.57.">' in notes[0]
    s, t = clean.specs[0], dotted.specs[0]
    assert s.limits == t.limits and np.array_equal(s.origin_R, t.origin_R)
    for bad in ('-1.57..', '1.5.7', '.', '-.e1.'):
        with pytest.raises(UrdfError, match='expected 3 numbers'):
            read_urdf(PENDULUM.replace('rpy="0 0 -1.57"', f'rpy="0 0 {bad}"'))


def test_velocity_zero_is_no_limit_with_one_warning_as_effort_zero():
    r, notes = _read(PENDULUM.replace('velocity="2"', 'velocity="0"'))
    assert r.specs[0].velocity_limit is None and r.velocity_limits == {}
    assert notes == ['<limit velocity="0"> (or below) read as "no velocity limit given", as effort="0" is, on '
                     '1 joint: j']


POINT_ARM = ('<robot name="pm"><link name="base"/>'
             '<link name="l1"><inertial><origin xyz="{c1}"/><mass value="1"/><inertia ixx="0" iyy="0" izz="0" '
             'ixy="0" ixz="0" iyz="0"/></inertial></link>'
             '<link name="l2"><inertial><origin xyz="{c2}"/><mass value="1"/><inertia ixx="0" iyy="0" izz="0" '
             'ixy="0" ixz="0" iyz="0"/></inertial></link>'
             '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/>'
             '<limit lower="-3" upper="3" effort="10" velocity="0"/></joint>'
             '<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 -0.5"/>'
             '<axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="10" velocity="0"/></joint></robot>')


def test_point_masses_run_where_the_mass_matrix_is_regular_against_the_closed_form():
    """Two point masses of 1 kg at the ends of two 0.5 m links (all-zero inertia tensors, velocity="0"):
    M(q) is the double pendulum's closed form ``[[m1 l² + m2 (2 l² + 2 l² cos q2), ...]]``."""
    r, notes = _read(POINT_ARM.format(c1='0 0 -0.5', c2='0 0 -0.5'))
    assert [n for n in notes if 'velocity' in n] and not [n for n in notes if 'armature' in n], notes
    m = build_model(r.specs, root=r.root)
    km = kernels.CompiledModel(m)
    L = 0.5
    for q2 in (0.0, 0.7, 2.0):
        M = km.crba(np.array([0.3, q2]))
        c = np.cos(q2)
        ref = np.array([[L * L + (2 * L * L + 2 * L * L * c), L * L + L * L * c], [L * L + L * L * c, L * L]])
        assert np.abs(M - ref).max() < 1e-14, (q2, M, ref)


def test_a_point_mass_on_its_own_axis_gets_armature_and_without_it_the_refusal_names_the_joint(tmp_path):
    """l2's point mass sits on j2's axis: M is singular in every configuration. By default the importer
    gives j2 the smallest armature that makes M regular (one warning); a scene asking for none is refused,
    and where the linearisation is not finite its message names the joint and the quantity (it used to
    say only that the linearisation of ArmSystem was not finite)."""
    text = POINT_ARM.format(c1='0 0 -0.5', c2='0 0 0')
    r, notes = _read(text)
    arm = [n for n in notes if 'armature' in n]
    assert len(arm) == 1 and 'a motion of joint j2 meets no inertia there' in arm[0], arm
    assert [s.armature > 0 for s in r.specs] == [False, True]
    f = tmp_path / 'pm.urdf'
    f.write_text(text)
    p = subprocess.run(ROBODYN + ['run', str(f), '--duration', '0.05'], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    scene = tmp_path / 'pm.yaml'
    scene.write_text(f'name: pm\nparts:\n  - {{kind: urdf, name: pm, file: {f}, armature: 0}}\n')
    p = subprocess.run(ROBODYN + ['run', str(scene), '--duration', '0.05'], capture_output=True, text=True, timeout=600)
    errors = [ln for ln in p.stderr.splitlines() if not ln.startswith('robodyn: warning:')]
    assert p.returncode == 2 and len(errors) == 1 and 'Traceback' not in p.stderr, p.stderr
    assert 'j2' in errors[0] and 'no mass or inertia about their axis' in errors[0], errors
