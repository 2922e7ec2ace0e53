"""IMU and force-torque sensors (kernels/sensors.py, systems/sensors.py) against Pinocchio on example-robot-
data's Panda (the URDF we read, fingers locked): the IMU on the welded hand equals Pinocchio's frame
classical acceleration minus gravity, angular velocity and orientation to 1e-9; it reads +g at rest and 0 in
free fall; a force-torque sensor on the fixed joint panda_joint8, read in panda_hand_tcp (rotated and
offset from the welded child), equals Pinocchio's RNEA wrench transmitted through that joint (made a
revolute joint held at 0 for Pinocchio to report it), moved to that frame, to 1e-9 relative; seeded noise
gives the same bytes twice; bad sensors are refused naming the key."""
from __future__ import annotations

import re

import numpy as np
import pinocchio as pin
import pytest

from robodyn_ros.meshes import resolve_uri
from robodyn_ros.scene import parse_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.validation import SceneError

PANDA = 'package://example-robot-data/robots/panda_description/urdf/panda.urdf'
FINGERS = ('panda_finger_joint1', 'panda_finger_joint2')


def _panda_scene(sensors, extra=''):
    text = (f'name: panda\nparts:\n  - kind: urdf\n    name: panda\n    file: {PANDA}\n'
            f'    locked: {{panda_finger_joint1: 0.0, panda_finger_joint2: 0.0}}\n{extra}sensors: {sensors}\n')
    return parse_scene(text, file='panda.yaml')


def _pin_model(revolute_joint8=False):
    """Pinocchio's model of the same URDF text, fingers fixed (as our ``locked``), joint8 optionally a
    revolute joint (so that RNEA reports the wrench it transmits)."""
    text = open(resolve_uri(PANDA)).read()
    for j in FINGERS:
        text = re.sub(rf'<joint name="{j}" type="prismatic">', f'<joint name="{j}" type="fixed">', text)
    text = re.sub(r'<mimic[^>]*/>', '', text)
    if revolute_joint8:
        text = text.replace('<joint name="panda_joint8" type="fixed">',
                            '<joint name="panda_joint8" type="revolute"><axis xyz="0 0 1"/>'
                            '<limit effort="1" lower="-1" upper="1" velocity="1"/>')
    return pin.buildModelFromXML(text)


def _state(rng):
    """A state and joint efforts (N·m, within the Panda's limits): the arm driven, not falling freely (a limp
    chain falls with its hand, whose wrist then transmits little)."""
    q = rng.uniform(-1.0, 1.0, 7)
    v = rng.uniform(-2.0, 2.0, 7)
    u = rng.uniform(-10.0, 10.0, 7)
    return q, v, u


def _readings(scene, q, v, u=None):
    y = np.concatenate([q, v])
    sim = Simulator(scene.system, y, integrator='rk4', dt=1e-3)
    if u is not None:
        sim.set_command('effort', u)
    return {topic: msg for topic, _, msg in sim.outputs().messages}


def test_imu_on_the_welded_hand_equals_pinocchios_classical_acceleration_minus_gravity():
    sc = _panda_scene('[{kind: imu, link: panda_hand, name: hand}]')
    model = _pin_model()
    data = model.createData()
    fid = model.getFrameId('panda_hand')
    rng = np.random.default_rng(7)
    for _ in range(5):
        q, v, u = _state(rng)
        tau = u - model.damping * v                        # the efforts and the URDF's damping
        a = pin.aba(model, data, q, v, tau)
        pin.forwardKinematics(model, data, q, v, a)
        pin.updateFramePlacements(model, data)
        R = data.oMf[fid].rotation
        acc = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL).linear
        want_f = acc - R.T @ model.gravity.linear
        want_w = pin.getFrameVelocity(model, data, fid, pin.LOCAL).angular
        m = _readings(sc, q, v, u)['imu/hand']
        f = np.array([m['linear_acceleration'][k] for k in 'xyz'])
        w = np.array([m['angular_velocity'][k] for k in 'xyz'])
        qm = m['orientation']
        Rm = pin.Quaternion(qm['w'], qm['x'], qm['y'], qm['z']).toRotationMatrix()
        assert np.abs(f - want_f).max() < 1e-9 * max(1.0, np.abs(want_f).max()), (f, want_f)
        assert np.abs(w - want_w).max() < 1e-9, (w, want_w)
        assert np.abs(Rm - R).max() < 1e-9
        assert np.abs(want_f).max() > 1.0 and m['header']['frame_id'] == 'panda_hand'


def test_imu_reads_plus_g_at_rest():
    """The Panda held by its position servo (feed-forward = gravity at the held posture: no acceleration):
    the hand's IMU reads 9.81 m/s² straight up (world z), expressed in the hand."""
    sc = _panda_scene('[{kind: imu, link: panda_hand}]', extra='    command_interfaces: position\n')
    q = np.array([0.3, -0.5, 0.2, -2.0, 0.4, 1.5, 0.6])
    m = _readings(sc, q, np.zeros(7))['imu/panda_hand']
    f = np.array([m['linear_acceleration'][k] for k in 'xyz'])
    qm = m['orientation']
    R = pin.Quaternion(qm['w'], qm['x'], qm['y'], qm['z']).toRotationMatrix()
    assert np.abs(R @ f - [0.0, 0.0, 9.81]).max() < 1e-9, R @ f


def test_imu_reads_zero_in_free_fall():
    """A spinning body on a free joint (its origin at its centre of mass), falling: specific force 0 while its
    angular velocity reads the spin, in the body."""
    text = ('name: fall\nparts:\n  - kind: arm\n    name: body\n    mount: free\n    links:\n'
            '      - {name: box, joint: free_joint, parent: odom, type: free, mass: 2.0, com: [0, 0, 0],\n'
            '         inertia: [[0.02, 0, 0], [0, 0.03, 0], [0, 0, 0.04]]}\n'
            'sensors: [{kind: imu, link: box}]\n')
    sc = parse_scene(text, file='fall.yaml')
    y = sc.y0.copy()
    y[7:10] = [1.0, -2.0, 0.5]      # angular velocity (body)
    y[10:13] = [0.3, 0.0, 1.0]      # linear velocity
    sim = Simulator(sc.system, y, integrator='rk4', dt=1e-3)
    sim.advance(0.2)
    m = {t: msg for t, _, msg in sim.outputs().messages}['imu/box']
    f = np.array([m['linear_acceleration'][k] for k in 'xyz'])
    w = np.array([m['angular_velocity'][k] for k in 'xyz'])
    assert np.abs(f).max() < 1e-12, f
    assert np.allclose(w, sim.y[7:10], rtol=0, atol=1e-15) and np.abs(w).max() > 0.5


def test_force_torque_on_a_fixed_joint_equals_pinocchios_transmitted_wrench_in_a_rotated_frame():
    sc = _panda_scene('[{kind: force_torque, joint: panda_joint8, frame: panda_hand_tcp, name: wrist}]')
    fixed = _pin_model()
    dfix = fixed.createData()
    model = _pin_model(revolute_joint8=True)
    data = model.createData()
    jid = model.getJointId('panda_joint8')
    tcp = model.getFrameId('panda_hand_tcp')
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, v, u = _state(rng)
        a = pin.aba(fixed, dfix, q, v, u - fixed.damping * v)
        pin.rnea(model, data, np.append(q, 0.0), np.append(v, 0.0), np.append(a, 0.0))
        pin.updateFramePlacements(model, data)
        X = data.oMi[jid].inverse() * data.oMf[tcp]        # the tcp frame in joint8's frame
        f = X.actInv(data.f[jid])                           # the same wrench about the tcp, in its axes
        want = np.concatenate([f.angular, f.linear])
        m = _readings(sc, q, v, u)['ft/wrist']
        got = np.array([m['wrench']['torque'][k] for k in 'xyz'] + [m['wrench']['force'][k] for k in 'xyz'])
        assert np.abs(got - want).max() < 1e-9 * np.abs(want).max(), (got, want)
        assert np.abs(want[3:]).max() > 1.0 and m['header']['frame_id'] == 'panda_hand_tcp'
        # the frame is turned and offset from the child: its reading differs from constraint_wrenches/panda_joint8
        wr = sc.system.outputs(0.0, np.concatenate([q, v]), {'effort': u}).wrenches['panda_joint8'][1]
        assert np.abs(wr - got).max() > 0.1


def test_noise_is_seeded_and_recorded_bytes_repeat(tmp_path):
    """An IMU with noise and bias: two runs give identical files; the readings differ from the noiseless by
    about the stated σ (a sample of 300 within 20%)."""
    from robodyn_ros.cli import main as robodyn
    noisy = ('[{kind: imu, link: panda_hand, name: hand, noise: {angular_velocity: 0.01, linear_acceleration: 0.1}, '
             'bias: {angular_velocity: [0.001, 0, 0]}, seed: 4}]')
    for k in (1, 2):
        path = tmp_path / f'p{k}.yaml'
        path.write_text(f'name: panda\nparts:\n  - kind: urdf\n    name: panda\n    file: {PANDA}\n'
                        f'    locked: {{panda_finger_joint1: 0.0, panda_finger_joint2: 0.0}}\nsensors: {noisy}\n'
                        'simulation: {duration: 1.0}\n')
        assert robodyn(['run', str(path), '--record', str(tmp_path / f'r{k}.mcap')]) == 0
    a, b = (tmp_path / 'r1.mcap').read_bytes(), (tmp_path / 'r2.mcap').read_bytes()
    assert a == b
    sc = _panda_scene(noisy)
    clean = _panda_scene('[{kind: imu, link: panda_hand, name: hand}]')
    q, v, _ = _state(np.random.default_rng(0))
    y = np.concatenate([q, v])
    d = []
    for t in np.arange(300) * 0.01:
        m1 = {tp: m for tp, _, m in sc.system.outputs(t, y, sc.system.zero_inputs()).messages}['imu/hand']
        m0 = {tp: m for tp, _, m in clean.system.outputs(t, y, clean.system.zero_inputs()).messages}['imu/hand']
        d.append([m1['linear_acceleration'][k] - m0['linear_acceleration'][k] for k in 'xyz'])
    sd = np.std(np.array(d))
    assert 0.08 < sd < 0.12, sd
    assert m1['linear_acceleration_covariance'][0] == pytest.approx(0.01)


@pytest.mark.parametrize('sensors, where', [
    ('[{kind: imu, link: nope}]', "sensors[0].link: no link 'nope'"),
    ('[{kind: force_torque, joint: nope}]', "sensors[0].joint: no joint 'nope'"),
    ('[{kind: sonar, link: panda_hand}]', 'sensors[0].kind: expected kind: imu or kind: force_torque'),
    ('[{kind: imu, link: panda_hand, noise: {force: 1.0}}]', 'sensors[0].noise'),
])
def test_bad_sensors_are_refused_naming_the_key(sensors, where):
    with pytest.raises(SceneError) as e:
        _panda_scene(sensors)
    assert where in str(e.value), str(e.value)


def test_the_recorders_fast_encoders_write_what_the_generic_encoder_writes():
    """The servo's JointState messages and the force-torque WrenchStamped are recorded by the fast encoders of
    joint_states and constraint wrenches: the same bytes as cdr.encode of their dicts (the IMU: cdr.encode)."""
    from robodyn_ros.recording import cdr
    from robodyn_ros.recording.run_sink import output_records
    sc = _panda_scene('[{kind: force_torque, joint: panda_joint8, frame: panda_hand_tcp, name: wrist}, '
                      '{kind: imu, link: panda_hand}]', extra='    command_interfaces: position\n')
    q, v, _ = _state(np.random.default_rng(1))
    sim = Simulator(sc.system, np.concatenate([q, v]), integrator='rk4', dt=1e-3)
    out = sim.outputs()
    msgs = {t: (ty, m) for t, ty, m in out.messages}
    assert set(msgs) == {'joint_trajectory_desired', 'joint_trajectory_error', 'imu/panda_hand', 'ft/wrist'}
    sim.advance(0.25)   # a stamp with seconds and nanoseconds
    out = sim.outputs()
    msgs = {t: (ty, m) for t, ty, m in out.messages}
    assert msgs['ft/wrist'][1]['header']['stamp'] == {'sec': 0, 'nanosec': 250_000_000}
    recs = {t: data for t, _, data in output_records(250_000_000, out, False)}
    for topic, (ty, m) in msgs.items():
        assert recs[topic] == cdr.encode(ty, m), topic
