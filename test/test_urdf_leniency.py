"""URDF import read leniently: every branch of the leniency with a small inline URDF (what is
accepted, with which note, and what stays refused), effort="0", inertias breaking the triangle
inequality (as given, balanced, refused), and what ``robodyn run`` prints."""
from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pinocchio as pin
import pytest

from robodyn_ros.model import build_model, to_urdf
from robodyn_ros.scene import load_scene, parse_scene
from robodyn_ros.simulation import Simulator, run_headless
from robodyn_ros.urdf import UrdfError, UrdfWarning, read_urdf
from test_urdf import _joint, _link, _robot

ROBODYN = [sys.executable, '-m', 'robodyn_ros.cli']


def _inertial(ixx, iyy, izz, ixy=0.0, ixz=0.0, iyz=0.0, mass=1.0, origin=''):
    return (f'<inertial>{origin}<mass value="{mass}"/><inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="{ixy}" '
            f'ixz="{ixz}" iyz="{iyz}"/></inertial>')


#: a clean two-link arm every variant below is compared with
ARM = _robot(_link('a'), _link('b'), _link('c'), _joint('j1', 'a', 'b'),
             _joint('j2', 'b', 'c', extra='<origin xyz="0 0 1"/><axis xyz="0 1 0"/>'), name='arm')


def _read(source, **kw):
    """(robot, [warning messages]) of read_urdf with every warning recorded."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        r = read_urdf(source, **kw)
    got = [str(w.message) for w in caught if issubclass(w.category, UrdfWarning)]
    assert got == r.notes
    return r, got


def _same_robot(a, b):
    assert [s.name for s in a.specs] == [s.name for s in b.specs]
    for s, t in zip(a.specs, b.specs):
        assert (s.joint, s.joint_type, s.mass) == (t.joint, t.joint_type, t.mass)
        np.testing.assert_array_equal(s.inertia, t.inertia)
        np.testing.assert_array_equal(s.origin_xyz, t.origin_xyz)


# ------------------------------------------------------------------------------------------------
# the document
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize('head', [b'\xef\xbb\xbf', b'\n\n  \n', b'\xef\xbb\xbf\r\n\r\n'], ids=['bom', 'blank', 'bom+crlf'])
def test_bom_and_blank_lines_before_the_declaration_are_skipped(tmp_path, head):
    import xml.etree.ElementTree as ET
    clean, notes = _read(ARM)
    assert notes == []
    f = tmp_path / 'arm.urdf'
    f.write_bytes(head + b'<?xml version="1.0" encoding="utf-8"?>\n' + ARM.encode())
    if head.strip(b'\xef\xbb\xbf'):  # blank lines: the standard library's parser alone refuses the file
        with pytest.raises(ET.ParseError, match='XML or text declaration not at start of entity'):
            ET.parse(f)
    r, notes = _read(f)
    assert notes == []
    _same_robot(r, clean)
    r, notes = _read(head.decode('utf-8') + '<?xml version="1.0"?>\n' + ARM)  # the same as text
    assert notes == []
    _same_robot(r, clean)


@pytest.mark.parametrize('tail', [b'\x00', b'\x00\x00junk', b'\n<robot name="second"/>'], ids=['nul', 'junk', 'element'])
def test_bytes_after_the_root_element_are_ignored_with_a_note(tmp_path, tail):
    f = tmp_path / 'arm.urdf'
    f.write_bytes(ARM.encode() + tail)
    r, notes = _read(f)
    _same_robot(r, read_urdf(ARM))
    assert len(notes) == 1 and notes[0].startswith(f'{f}: (document): ignored what follows </robot> from line ')


def test_other_encodings_are_read_as_declared(tmp_path):
    name = 'bras_à_coude'
    text = ARM.replace('name="arm"', f'name="{name}"')
    f = tmp_path / 'latin.urdf'
    f.write_bytes(b'<?xml version="1.0" encoding="ISO-8859-1"?>\n' + text.encode('latin-1'))
    assert _read(f)[0].name == name
    f.write_bytes(('<?xml version="1.0" encoding="UTF-16"?>\n' + text).encode('utf-16'))  # with its BOM
    assert _read(f)[0].name == name


def test_unknown_elements_are_ignored_with_one_note():
    text = ARM.replace('<link name="b">', '<link name="b"><contact><lateral_friction value="1"/></contact>') \
              .replace('</robot>', '<ros2_control name="x"/><ros2_control name="y"/><transmission name="t"/>'
                                   '<gazebo/></robot>')
    r, notes = _read(text)
    _same_robot(r, read_urdf(ARM))
    assert notes == ['(document): ignored elements that are not URDF: <ros2_control> x2, <link>/<contact>']


def test_robot_without_a_name_takes_the_file_name(tmp_path):
    f = tmp_path / 'nameless.urdf'
    f.write_text(ARM.replace(' name="arm"', ''))
    assert _read(f)[0].name == 'nameless'
    assert _read(ARM.replace(' name="arm"', ''))[0].name == 'robot'


def test_materials_without_names_and_shared_materials_make_a_description_urdfdom_reads():
    """A top-level material without a name is ignored; a visual's material without a name gets
    one; a visual naming a top-level material gets its colour (the exported description has no
    top-level materials). urdfdom (robot_state_publisher's parser, through Pinocchio's geometry
    reader) is the judge: it refuses a visual material without a name, and reads the export."""
    vis = ('<visual><geometry><box size="0.1 0.1 0.1"/></geometry><material name="blue"/></visual>'
           '<visual><geometry><sphere radius="0.1"/></geometry><material><color rgba="1 0 0 1"/></material></visual>')
    text = _robot('<material><color rgba="0 1 0 1"/></material>',
                  '<material name="blue"><color rgba="0 0 1 1"/></material>',
                  _link('a'), f'<link name="b">{vis}{_inertial(0.1, 0.1, 0.1)}</link>',
                  _joint('j1', 'a', 'b'), name='painted')
    r, notes = _read(text)
    assert notes == []
    b = next(s for s in r.specs if s.name == 'b')
    assert '<color rgba="0 0 1 1"' in b.visuals[0] and 'name="b_visual1"' in b.visuals[1]
    exported = to_urdf(build_model(r.specs, root=r.root, name=r.name, root_visuals=r.root_visuals))
    pm = pin.buildModelFromXML(exported)

    def visuals(text):  # urdfdom drops the link's visuals (robot_state_publisher: the whole model) on an error
        return pin.buildGeomFromUrdfString(pm, text, pin.GeometryType.VISUAL).ngeoms
    assert visuals(exported) == 2
    nameless = exported.replace(' name="b_visual1"', '')
    assert nameless != exported and visuals(nameless) == 0


# ------------------------------------------------------------------------------------------------
# refusals: one line naming the place
# ------------------------------------------------------------------------------------------------
REFUSED = [
    ('xml error', ARM.replace('<link name="c">', '<link name="c" <oops>'), r"^line 1, column \d+: not well-formed XML"),
    ('nul inside', ARM.replace('<link name="c">', '<link name="c">\x00'), r'^line 1, column \d+: not well-formed XML'),
    ('empty', '<?xml version="1.0"?>\n<!-- nothing -->', r'^\(document\): not well-formed XML: no element found'),
    ('unclosed', '<robot name="x"><link name="a">', r'^\(document\): not well-formed XML: <robot> is never closed'),
    ('xacro', ARM.replace('<robot name="arm">', '<robot name="arm" xmlns:xacro="http://www.ros.org/wiki/xacro">'
                                                '<xacro:macro name="m"/>'),
     r'^<xacro:macro>: an unexpanded xacro macro'),
    ('no link', '<robot name="void"></robot>', r"^robot 'void': no <link> element"),
    ('two inertials', ARM.replace('<link name="b">', f'<link name="b">{_inertial(1, 1, 1)}'),
     r"^link 'b': 2 <inertial> elements"),
    ('mass without value', ARM.replace('<mass value="1"/>', '<mass/>', 1), r"^link 'a': <inertial> needs <mass value"),
    ('no ixx', ARM.replace('ixx="0.1" ', '', 1), r"^link 'a': <inertia> needs ixx, iyy and izz"),
    ('two origins', ARM.replace('<origin xyz="0 0 1"/>', '<origin xyz="0 0 1"/><origin/>'),
     r"^joint 'j2': 2 <origin> elements"),
    ('bad vector', ARM.replace('<origin xyz="0 0 1"/>', '<origin xyz="0 0"/>'),
     r"^joint 'j2': <origin xyz=\"0 0\">: expected 3 numbers, got 2"),
    ('inf', ARM.replace('<origin xyz="0 0 1"/>', '<origin xyz="0 0 inf"/>'),
     r"^joint 'j2': <origin xyz=\"0 0 inf\">: expected finite numbers"),
    ('word', ARM.replace('ixx="0.1"', 'ixx="${m}"', 1), r"^link 'a': <inertia ixx=\"\$\{m\}\">: expected 1 number"),
    ('mimic without joint', ARM.replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><mimic/>'),
     r"^joint 'j2': <mimic> needs joint="),
    ('joint without name', ARM.replace('name="j2" ', ''), r'^<joint> number 2: needs a name attribute'),
    ('link without name', ARM.replace('<link name="c">', '<link>'), r'^<link> number 3: needs a name attribute'),
    ('joint without type', ARM.replace('type="revolute"', '', 1), r"^joint 'j1': needs a type attribute"),
]


@pytest.mark.parametrize('what, text, pattern', REFUSED, ids=[r[0] for r in REFUSED])
def test_refusals_are_one_line_naming_the_place(what, text, pattern):
    with pytest.raises(UrdfError, match=pattern) as e:
        read_urdf(text)
    assert '\n' not in str(e.value) and e.value.file is None


def test_a_file_refusal_starts_with_the_file(tmp_path):
    f = tmp_path / 'broken.urdf'
    f.write_text(REFUSED[-1][1])
    with pytest.raises(UrdfError) as e:
        read_urdf(f)
    assert str(e.value) == f"{f}: joint 'j1': needs a type attribute" and e.value.file == str(f)
    with pytest.raises(UrdfError, match=r'^/nowhere/x\.urdf: \(file\): cannot read the URDF file: No such file'):
        read_urdf('/nowhere/x.urdf')


# ------------------------------------------------------------------------------------------------
# effort="0"
# ------------------------------------------------------------------------------------------------
def test_effort_zero_means_no_limit_given_with_one_warning_naming_the_joints():
    lim = '<axis xyz="0 1 0"/><limit effort="{}" lower="-1" upper="1" velocity="2"/>'
    text = _robot(_link('a'), _link('b'), _link('c'), _link('d'),
                  _joint('j1', 'a', 'b', extra=lim.format(0)), _joint('j2', 'b', 'c', extra=lim.format(5)),
                  _joint('j3', 'c', 'd', extra=lim.format('0.0')))
    r, notes = _read(text)
    assert notes == ['<limit effort="0"> read as "no effort limit given" (the ROS convention) on 2 joints: j1, j3']
    s = {x.joint: x for x in r.specs}
    assert (s['j1'].effort_limit, s['j2'].effort_limit, s['j3'].effort_limit) == (None, 5.0, None)
    assert s['j1'].limits == (-1.0, 1.0) and s['j1'].velocity_limit == 2.0  # the rest of <limit> is kept
    sc = parse_scene('name: x\nparts:\n  - kind: urdf\n    name: r\n    urdf: |\n      ' + text + '\n')
    np.testing.assert_array_equal(sc.system.inputs['effort'].limit, [np.inf, 5.0, np.inf])


# ------------------------------------------------------------------------------------------------
# inertias breaking the triangle inequality
# ------------------------------------------------------------------------------------------------
def _pendulum(inertial):
    """One link on a revolute joint about y whose com hangs 0.3 m below it."""
    return _robot(_link('a'), f'<link name="b">{inertial}</link>',
                  _joint('j1', 'a', 'b', extra='<axis xyz="0 1 0"/>'), name='p')


def test_positive_definite_inertia_breaking_the_triangle_inequality_is_kept_as_given():
    """I = diag(0.01, 0.02, 0.05): I1 + I2 < I3 by 40 % of I3, positive definite. Kept as given with
    a warning; our kernels and Pinocchio give the same M, RNEA and ABA on it (a rotated inertial
    frame, so every entry counts), the mass matrix is positive definite, and a run conserves energy."""
    origin = '<origin xyz="0.05 0 -0.3" rpy="0.3 0.2 0.1"/>'
    lim = '<limit effort="10" lower="-3" upper="3" velocity="9"/>'  # urdfdom needs one on a revolute joint
    text = _robot(_link('a'), f'<link name="b">{_inertial(0.01, 0.02, 0.05, origin=origin)}</link>', _link('c'),
                  _joint('j1', 'a', 'b', extra='<axis xyz="0 1 0"/>' + lim),
                  _joint('j2', 'b', 'c', extra='<origin xyz="0 0 -0.5"/><axis xyz="1 0 0"/>' + lim), name='p')
    r, notes = _read(text)
    assert len(notes) == 1
    assert notes[0].startswith("link 'b' (joint 'j1'): principal moments 0.01, 0.02, 0.05 kg·m² break the triangle "
                               "inequality (I1 + I2 = 0.03 < I3; 40 % of I3): accepted as given")
    b = r.specs[0]
    assert b.inertia_as_given
    R = pin.rpy.rpyToMatrix(0.3, 0.2, 0.1)
    np.testing.assert_allclose(b.inertia, R @ np.diag([0.01, 0.02, 0.05]) @ R.T, atol=1e-17)
    sc = parse_scene('name: x\nparts:\n  - kind: urdf\n    name: r\n    urdf: |\n      ' + text + '\n')
    m = sc.system.model
    pm = pin.buildModelFromXML(text)
    pd = pm.createData()
    from robodyn_ros import kernels
    km = kernels.CompiledModel(m)
    rng = np.random.default_rng(3)
    for _ in range(4):
        q, v, tau = rng.normal(size=2), rng.normal(size=2), rng.normal(size=2)
        M, Mp = km.crba(q), pin.crba(pm, pd, q)
        np.testing.assert_allclose(M, np.triu(Mp) + np.triu(Mp, 1).T, rtol=1e-12, atol=1e-15)
        assert np.linalg.eigvalsh(M).min() > 0.0
        np.testing.assert_allclose(km.aba(q, v, tau), pin.aba(pm, pd, q, v, tau), rtol=1e-10)
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    sim.set_command('effort', [0.0, 0.0])
    run_headless(sim, 0.5, 100.0)
    assert abs(sim.energy_report()['relative_drift']) < 1e-8


def test_singular_inertia_breaking_the_triangle_inequality_is_balanced_as_mujoco_does():
    """I = diag(0, 0.1, 0.2) (a zero moment, and 0 + 0.1 < 0.2): every moment becomes the mean 0.1,
    as MuJoCo's compiler does with balanceinertia="true" (its body_inertia read back from an MJCF
    body with the same diagonal inertia; its URDF reader refuses a zero moment outright)."""
    import mujoco
    text = _pendulum(_inertial(0.0, 0.1, 0.2, origin='<origin xyz="0 0 -0.3"/>'))
    r, notes = _read(text)
    assert len(notes) == 1 and 'and the smallest is zero: balanced as MuJoCo\'s balanceinertia does (all three ' \
                                'moments set to their mean 0.1 kg·m²)' in notes[0]
    np.testing.assert_allclose(r.specs[0].inertia, np.eye(3) * 0.1, rtol=1e-15)
    assert not r.specs[0].inertia_as_given
    mjcf = ('<mujoco><compiler balanceinertia="{}"/><worldbody><body name="b"><joint type="hinge" axis="0 1 0"/>'
            '<inertial pos="0 0 -0.3" mass="1" diaginertia="0 0.1 0.2"/></body></worldbody></mujoco>')
    mj = mujoco.MjModel.from_xml_string(mjcf.format('true'))
    np.testing.assert_allclose(mj.body_inertia[mj.body('b').id], np.diag(r.specs[0].inertia), rtol=1e-15)
    with pytest.raises(ValueError, match='A \\+ B >= C'):  # without the option MuJoCo refuses it
        mujoco.MjModel.from_xml_string(mjcf.format('false'))


def test_physical_inertias_and_slender_bars_pass_without_a_note_and_negative_moments_are_refused():
    assert _read(_pendulum(_inertial(0.1, 0.1, 0.2)))[1] == []  # I1 + I2 = I3: a flat plate
    assert _read(_pendulum(_inertial(0.0, 0.1, 0.1, origin='<origin xyz="0 0 -0.3"/>')))[1] == []  # a bar
    with pytest.raises(UrdfError, match=r"link 'b' \(joint 'j1'\): inertia is not positive semi-definite"):
        read_urdf(_pendulum(_inertial(-0.01, 0.1, 0.1)))


def test_a_welded_sensor_breaking_the_triangle_inequality_is_lumped_first():
    """A massive link with a fixed child whose inertia alone breaks the triangle inequality: the
    welded composite is judged (here it is physical: no note)."""
    text = _robot(_link('a'), f'<link name="b">{_inertial(0.2, 0.2, 0.2)}</link>',
                  f'<link name="imu">{_inertial(0.0, 0.0, 0.001, mass=0.01)}</link>',
                  _joint('j1', 'a', 'b'), _joint('weld', 'b', 'imu', 'fixed', '<origin xyz="0 0 0.1"/>'))
    r, notes = _read(text)
    assert notes == []
    assert [s.mass for s in r.specs] == [1.01, 0.0]


# ------------------------------------------------------------------------------------------------
# what robodyn run prints
# ------------------------------------------------------------------------------------------------
def test_robodyn_run_prints_each_warning_once_and_refuses_in_one_line(tmp_path):
    lenient = tmp_path / 'lenient.urdf'
    lenient.write_bytes(b'\n\n' + _pendulum(_inertial(0.01, 0.02, 0.05, origin='<origin xyz="0 0 -0.3"/>'))
                        .replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><limit effort="0" velocity="1"/>')
                        .encode() + b'\x00')
    p = subprocess.run(ROBODYN + ['run', str(lenient), '--duration', '0.05', '--backend', 'numba'],
                       capture_output=True, text=True, timeout=240)
    assert p.returncode == 0, p.stderr
    lines = p.stderr.splitlines()
    assert len(lines) == 3 and all(ln.startswith(f'robodyn: warning: {lenient}: ') for ln in lines), p.stderr
    assert sum('effort="0"' in ln for ln in lines) == 1 and sum('triangle' in ln for ln in lines) == 1
    assert 'simulated 0.050 s' in p.stdout
    broken = tmp_path / 'broken.urdf'
    broken.write_text(_pendulum(_inertial(-0.01, 0.1, 0.1)))
    p = subprocess.run(ROBODYN + ['run', str(broken), '--duration', '0.05'], capture_output=True, text=True,
                       timeout=240)
    assert p.returncode == 2 and p.stdout == ''
    assert p.stderr.splitlines() == [f"robodyn run: {broken}: link 'b' (joint 'j1'): inertia is not positive "
                                     "semi-definite (eigenvalues [-0.01, 0.1, 0.1])"]


def test_romeo_inertias_as_docs_urdf_describes_them_and_as_mujoco_reads_them():
    """romeo_small: two links break the triangle inequality by 80 % and 74 % of I3 and are kept as
    given; MuJoCo refuses the file unless it balances them. romeo_laas_small: LHipPitch_link has a
    negative principal moment and is refused, by MuJoCo too (with or without balanceinertia)."""
    import re

    import mujoco

    from robodyn_ros.urdf import example_robot_data_dir
    d = example_robot_data_dir() / 'romeo_description' / 'urdf'
    r, notes = _read(d / 'romeo_small.urdf')
    tri = [n for n in notes if 'triangle' in n]
    assert len(tri) == 2 and all('accepted as given' in n for n in tri)
    assert "link 'RShoulderYawLink'" in tri[0] and '(I1 + I2 = 0.001341 < I3; 80 % of I3)' in tri[0]
    assert "link 'RElbowYawLink'" in tri[1] and '; 74 % of I3)' in tri[1]
    with pytest.raises(UrdfError, match=r"romeo_laas_small\.urdf: link 'LHipPitch_link' \(joint 'LHipPitch_joint'\): "
                                        r"inertia is not positive semi-definite \(eigenvalues \[-0\.0027"):
        read_urdf(d / 'romeo_laas_small.urdf')

    def mj(name, balance):
        text = re.sub(r'<(visual|collision)>.*?</\1>', '', (d / name).read_text(), flags=re.S)
        if balance:
            text = re.sub(r'(<robot[^>]*>)', r'\1<mujoco><compiler balanceinertia="true"/></mujoco>', text, count=1)
        return mujoco.MjModel.from_xml_string(text)
    with pytest.raises(ValueError, match=r"inertia must satisfy A \+ B >= C"):
        mj('romeo_small.urdf', False)
    assert mj('romeo_small.urdf', True).nbody > 30
    for balance in (False, True):
        with pytest.raises(ValueError, match='inertia must have positive eigenvalues'):
            mj('romeo_laas_small.urdf', balance)


def test_the_node_logs_each_warning_once_and_runs(tmp_path):
    """The sim node on a URDF read leniently: each warning is one log line, once; the run ends
    normally."""
    from ros_helpers import run_sim_to_end
    f = tmp_path / 'lenient.urdf'
    f.write_bytes(b'\n' + _pendulum(_inertial(0.01, 0.02, 0.05, origin='<origin xyz="0 0 -0.3"/>'))
                  .replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><limit effort="0" velocity="1"/>').encode()
                  + b'\x00')
    rc, log = run_sim_to_end({'robot_description_file': str(f), 'mode': 'max', 'duration': 0.05, 'backend': 'numba'},
                             tmp_path / 'node.log')
    assert rc == 0, log
    warned = [ln for ln in log.splitlines() if '[WARN]' in ln and str(f) in ln]
    assert len(warned) == 3, log
    assert sum('effort="0"' in ln for ln in warned) == 1 and sum('triangle' in ln for ln in warned) == 1
    assert 'Traceback' not in log


def test_a_massless_hand_is_locked_with_one_note_and_the_rest_moves_as_pinocchio_with_it_fixed():
    """A 'hand' joint whose finger links carry no mass, with a finger that mimics it (romeo's hands in
    example-robot-data): the joint has nothing to accelerate, so it is locked at 0 as a fixed joint
    with its follower (at multiplier · 0 + offset), one note naming it; the arm that carries them
    moves. Oracle: Pinocchio on the same text with those two joints written as fixed at those
    positions (the follower's offset folded into its origin), M and ABA at random states."""
    lim = '<limit effort="0" lower="-1" upper="1" velocity="0"/>'
    fingers = ('<link name="f1"/><link name="f2"/>'
               + _joint('hand', 'b', 'f1', extra='<origin xyz="0 0 0.5"/><axis xyz="1 0 0"/>' + lim)
               + _joint('finger', 'f1', 'f2', extra='<origin xyz="0 0.1 0"/><axis xyz="1 0 0"/>' + lim
                        + '<mimic joint="hand" multiplier="2" offset="0.25"/>'))
    text = _robot(_link('a'), _link('b'), fingers, name='arm',
                  *[_joint('j1', 'a', 'b', extra='<axis xyz="0 1 0"/><limit effort="10" lower="-3" upper="3" velocity="9"/>')])
    r, notes = _read(text)
    assert [s.joint for s in r.specs if s.joint_type != 'fixed'] == ['j1']
    f2 = next(s for s in r.specs if s.name == 'f2')   # the follower's frame where its mimic law puts it
    np.testing.assert_allclose(f2.origin_R, pin.rpy.rpyToMatrix(0.25, 0.0, 0.0), atol=1e-15)
    lock = [n for n in notes if 'locked as fixed' in n]
    assert len(lock) == 1 and 'hand at 0' in lock[0] and 'no mass below it' in lock[0], notes
    assert 'with the joint that mimics it (2 joints in all)' in lock[0], lock
    fixed = text.replace('<joint name="hand" type="revolute">', '<joint name="hand" type="fixed">').replace(
        '<joint name="finger" type="revolute"><parent link="f1"/><child link="f2"/><origin xyz="0 0.1 0"/>',
        '<joint name="finger" type="fixed"><parent link="f1"/><child link="f2"/><origin xyz="0 0.1 0" rpy="0.25 0 0"/>')
    assert fixed.count('type="fixed"') == 2
    pm = pin.buildModelFromXML(fixed)
    pd = pm.createData()
    assert pm.nv == 1
    sc = parse_scene('name: x\nparts:\n  - kind: urdf\n    name: r\n    urdf: |\n      ' + text + '\n')
    from robodyn_ros import kernels
    km = kernels.CompiledModel(sc.system.model)
    rng = np.random.default_rng(5)
    for _ in range(3):
        q, v, tau = rng.normal(size=1), rng.normal(size=1), rng.normal(size=1)
        np.testing.assert_allclose(km.crba(q), pin.crba(pm, pd, q), rtol=1e-13)
        np.testing.assert_allclose(km.aba(q, v, tau), pin.aba(pm, pd, q, v, tau), rtol=1e-12)


def test_a_robot_whose_only_moving_joints_are_massless_is_still_refused():
    """Locking every joint would leave nothing to simulate: the refusal names the first joint."""
    text = _robot(_link('a'), '<link name="b"/>', _joint('j1', 'a', 'b'))
    with pytest.raises(UrdfError, match=r"link 'b' \(joint 'j1'\): missing <inertial> on a moving link, and no "
                                        r"<collision> or <visual> geometry to infer one from at a leaf"):
        read_urdf(text)


def test_aligned_axes_with_no_inertia_between_them_get_armature_or_are_refused_naming_the_joints(tmp_path):
    """icub's neck at q = 0: two joints about the same line with a link of zero inertia between them
    (a point mass on the axis), so one motion of the pair meets no inertia: the mass matrix is singular
    (Pinocchio's CRBA of the same file has the zero eigenvalue too) and its accelerations would be
    round-off. By default the importer gives the two joints the smallest armature that makes M regular,
    with one warning, and ``robodyn run`` runs it; a scene asking for no armature is refused in one line
    naming both joints, exit 2; turned by 0.5 rad, the same robot runs without armature."""
    point = '<inertial><mass value="0.1"/><inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" iyz="0"/></inertial>'
    lim = '<limit effort="10" lower="-3" upper="3" velocity="9"/>'
    text = _robot(_link('a'), f'<link name="b">{point}</link>', _link('c'),
                  _joint('roll', 'a', 'b', extra='<axis xyz="1 0 0"/>' + lim),
                  _joint('yaw', 'b', 'c', extra='<axis xyz="1 0 0"/>' + lim), name='neck')
    pm = pin.buildModelFromXML(text)
    w = np.linalg.eigvalsh(pin.crba(pm, pm.createData(), np.zeros(2)))
    assert w[0] < 1e-15 * w[-1]
    f = tmp_path / 'neck.urdf'
    f.write_text(text)
    p = subprocess.run(ROBODYN + ['run', str(f), '--duration', '0.01'], capture_output=True, text=True, timeout=600)
    warned = [ln for ln in p.stderr.splitlines() if 'armature' in ln]
    assert p.returncode == 0 and len(warned) == 1 and 'joints roll, yaw meets no inertia' in warned[0], p.stderr
    scene = tmp_path / 'neck.yaml'
    scene.write_text(f'name: neck\nparts:\n  - {{kind: urdf, name: neck, file: {f}, armature: 0}}\n')
    p = subprocess.run(ROBODYN + ['run', str(scene), '--duration', '0.01'], capture_output=True, text=True,
                       timeout=600)
    lines = [ln for ln in p.stderr.splitlines() if not ln.startswith('robodyn: warning')]
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert 'the mass matrix is singular' in lines[0] and 'roll' in lines[0] and 'yaw' in lines[0], lines
    sc = parse_scene('name: x\nparts:\n  - kind: urdf\n    name: r\n    armature: 0\n    urdf: |\n      '
                     + text.replace('<joint name="yaw" type="revolute"><parent link="b"/><child link="c"/>',
                                    '<joint name="yaw" type="revolute"><parent link="b"/><child link="c"/>'
                                    '<origin rpy="0 0.5 0"/>') + '\n')
    Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)   # no refusal: the axes no longer line up


def test_a_robot_of_fixed_joints_only_runs_with_nothing_to_integrate():
    """iris_simple and quadrotor_base of example-robot-data on a fixed base: no moving joint, so no
    state; the preflight's mass-matrix check has nothing to look at, and the run goes through."""
    text = _robot(_link('a'), _link('b'), _joint('j', 'a', 'b', kind='fixed', extra=''), name='rigid')
    sc = parse_scene('name: x\nparts:\n  - kind: urdf\n    name: r\n    urdf: |\n      ' + text + '\n')
    assert sc.system.ny == 0
    sim = Simulator(sc.system, sc.y0, dt=1e-3)
    run_headless(sim, 0.05, 100.0)
    assert sim.t == pytest.approx(0.05)
