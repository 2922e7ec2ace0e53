"""Sensor markers (``markers``, visualization_msgs/MarkerArray; recording/markers.py) read back from
recordings by rosbags (its own CDR decoder and the recorded schema).

* Panda (example-robot-data's URDF, fingers locked, swinging under constant efforts) with an IMU on
  ``panda_link5`` and a force-torque sensor on ``panda_joint8`` read in ``panda_hand_tcp`` (rotated 45°
  and offset from the welded hand) with a bias: the IMU's three arrows start at Pinocchio's placement of
  the link and run 0.1 m along its x, y, z axes; the force-torque arrows start at Pinocchio's placement of
  the frame and run along the recorded ``ft/wrist`` force and moment turned into the world by that
  placement, at 0.5 m per the robot's weight (Pinocchio's total mass times g), all at the joint positions
  of the recorded ``joint_states`` of the same stamp, in the frame the recorded ``/tf`` tree is rooted at.
* A1 on the ground with an IMU on its trunk: the contact markers first (as without sensors), then the
  trunk's axes at the recorded ``odom`` pose, in the odom frame.
* No sensors and no ground: no ``markers`` topic (test_markers_assets.py); xarm7_trajectory's layout
  shows the topic (test_foxglove_layout.py).
"""
from __future__ import annotations

import re
import warnings

import numpy as np
import pinocchio as pin
import pytest

from robodyn_ros.meshes import resolve_uri
from robodyn_ros.recording.run_sink import McapRunSink
from robodyn_ros.runs import plan_run, resolve_settings
from robodyn_ros.scene import load_scene, parse_scene
from robodyn_ros.simulation import Simulator, run_headless

PANDA = 'package://example-robot-data/robots/panda_description/urdf/panda.urdf'
FINGERS = ('panda_finger_joint1', 'panda_finger_joint2')
ARROW, DELETEALL = 0, 3
AXIS = 0.1          # m: an IMU's axes (docs)
AT_WEIGHT = 0.5     # m of arrow at the robot's weight (docs)

PANDA_SCENE = f"""name: panda_sensors
parts:
  - kind: urdf
    name: panda
    file: {PANDA}
    locked: {{panda_finger_joint1: 0.0, panda_finger_joint2: 0.0}}
initial_state:
  q: [0.3, -0.5, 0.2, -2.0, 0.4, 1.5, 0.6]
  v: [0.8, -0.6, 1.2, 0.5, -1.5, 1.0, 2.0]
commands:
  effort: {{profile: constant, value: [5.0, 20.0, -3.0, 10.0, 1.0, 2.0, -1.0]}}
sensors:
  - {{kind: imu, link: panda_link5, name: elbow}}
  - {{kind: force_torque, joint: panda_joint8, frame: panda_hand_tcp, name: wrist,
      bias: {{force: [2.0, 0.0, -1.0], torque: [0.0, 0.3, 0.0]}}}}
simulation: {{integrator: rk4, dt: 1.0e-3, publish_rate: 100.0}}
"""


def _record(path, scene, duration):
    plan, st = plan_run(resolve_settings(scene, duration=duration), scene.system, scene.y0)
    sim = Simulator(scene.system, scene.y0, plan=plan)
    sink = McapRunSink(path, scene, {**st, 'mode': 'headless'}, batch=64)
    try:
        run_headless(sim, duration, st['rate'], scene.script, [sink])
    finally:
        sink.close()


def _read(path) -> dict:
    """topic -> [(log time ns, message)] decoded by rosbags."""
    from rosbags.highlevel import AnyReader
    msgs = {}
    with AnyReader([path]) as reader:
        for c, t, raw in reader.messages():
            msgs.setdefault(c.topic, []).append((t, reader.deserialize(raw, c.msgtype)))
    return msgs


def _pin_panda():
    """Pinocchio's model of the same URDF text, fingers fixed (as our ``locked``)."""
    text = open(resolve_uri(PANDA)).read()
    for j in FINGERS:
        text = re.sub(rf'<joint name="{j}" type="prismatic">', f'<joint name="{j}" type="fixed">', text)
    text = re.sub(r'<mimic[^>]*/>', '', text)
    return pin.buildModelFromXML(text)


def _xyz(v):
    return np.array([v.x, v.y, v.z])


def _arrow(m):
    assert m.type == ARROW and len(m.points) == 2
    return _xyz(m.points[0]), _xyz(m.points[1])


@pytest.fixture(scope='module')
def panda(tmp_path_factory):
    path = tmp_path_factory.mktemp('panda') / 'panda.mcap'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        scene = parse_scene(PANDA_SCENE, file='panda_sensors.yaml')
    _record(path, scene, 0.3)
    return _read(path)


def test_imu_axes_and_force_torque_arrows_are_pinocchios_frames_and_the_recorded_wrench(panda):
    msgs = panda
    model = _pin_panda()
    data = model.createData()
    link5, tcp = model.getFrameId('panda_link5'), model.getFrameId('panda_hand_tcp')
    scale = AT_WEIGHT / (pin.computeTotalMass(model) * 9.81)
    js = {t: m for t, m in msgs['/joint_states']}
    ft = {t: m for t, m in msgs['/ft/wrist']}
    root = {tr.header.frame_id for _, m in msgs['/tf_static'] + msgs['/tf'] for tr in m.transforms} - \
        {tr.child_frame_id for _, m in msgs['/tf_static'] + msgs['/tf'] for tr in m.transforms}
    assert len(root) == 1
    markers = msgs['/markers']
    assert len(markers) == len(js) == len(ft) == 31        # one per publication (100 Hz over 0.3 s)
    moved = []
    for t, ma in markers:
        assert ma.markers[0].action == DELETEALL
        rest = ma.markers[1:]
        assert all(m.header.frame_id in root and m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == t
                   for m in ma.markers)
        by = {(m.ns, m.id): m for m in rest}
        assert len(by) == len(rest) == 5 and set(by) == {('imu/elbow', 0), ('imu/elbow', 1), ('imu/elbow', 2),
                                                         ('ft/wrist', 0), ('ft/wrist', 1)}
        j = js[t]
        q = np.array([j.position[list(j.name).index(n)] for n in model.names[1:]])
        pin.framesForwardKinematics(model, data, q)
        X = data.oMf[link5]
        for a in range(3):
            tail, tip = _arrow(by[('imu/elbow', a)])
            np.testing.assert_allclose(tail, X.translation, rtol=0, atol=1e-9)
            np.testing.assert_allclose(tip - tail, AXIS * X.rotation[:, a], rtol=0, atol=1e-9)
        S = data.oMf[tcp]
        w = ft[t].wrench
        assert ft[t].header.frame_id == 'panda_hand_tcp'
        for k, v in ((0, w.force), (1, w.torque)):
            tail, tip = _arrow(by[('ft/wrist', k)])
            np.testing.assert_allclose(tail, S.translation, rtol=0, atol=1e-9)
            np.testing.assert_allclose(tip - tail, scale * (S.rotation @ _xyz(v)), rtol=0, atol=1e-9)
        moved.append(X.translation.copy())
    assert np.ptp(np.array(moved), axis=0).max() > 0.05          # the link moved: the poses are the period's


def test_an_imu_on_a_robot_on_the_ground_draws_after_the_contact_markers(tmp_path):
    """a1_stand with an IMU on its trunk (the free joint's child): each message is the contact markers of a
    run without the sensor, then the trunk's axes at the recorded odom pose."""
    from robodyn_ros.scene import find_scene
    text = open(find_scene('a1_stand')).read() + '\nsensors: [{kind: imu, link: trunk}]\n'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        with_imu = parse_scene(text, file='a1_imu.yaml')
        plain = load_scene('a1_stand')
    _record(tmp_path / 'imu.mcap', with_imu, 0.3)
    _record(tmp_path / 'plain.mcap', plain, 0.3)
    a, b = _read(tmp_path / 'imu.mcap'), _read(tmp_path / 'plain.mcap')
    odom = {t: m for t, m in a['/odom']}
    assert len(a['/markers']) == len(b['/markers']) == len(odom) == 61
    touching = 0
    for (t, m), (tb, mb) in zip(a['/markers'], b['/markers']):
        assert t == tb
        n = len(mb.markers)
        touching += n > 1
        assert len(m.markers) == n + 3
        for x, y in zip(m.markers[:n], mb.markers):               # the contact markers as without the IMU
            assert (x.ns, x.id, x.type, x.action) == (y.ns, y.id, y.type, y.action)
            assert [_xyz(p).tolist() for p in x.points] == [_xyz(p).tolist() for p in y.points]
        o = odom[t]
        assert all(x.header.frame_id == o.header.frame_id for x in m.markers)
        p, qo = o.pose.pose.position, o.pose.pose.orientation
        R = pin.Quaternion(qo.w, qo.x, qo.y, qo.z).toRotationMatrix()
        for a_ in range(3):
            x = m.markers[n + a_]
            assert (x.ns, x.id) == ('imu/trunk', a_)
            tail, tip = _arrow(x)
            np.testing.assert_allclose(tail, _xyz(p), rtol=0, atol=1e-9)
            np.testing.assert_allclose(tip - tail, AXIS * R[:, a_], rtol=0, atol=1e-9)
    assert touching >= 20
