"""The CDR fast path (JointState, Clock, Float64MultiArray, TFMessage) writes exactly the generic encoder's bytes."""
from __future__ import annotations

import math

import numpy as np
import pytest

from robodyn_ros import messages as M
from robodyn_ros.recording import cdr


def generic(type_name, msg) -> bytes:
    enc = cdr._Encoder()
    enc.message(type_name, msg)
    return bytes(enc.buf)


def _joint_states(rng):
    out = []
    for k in range(40):
        n = int(rng.integers(0, 9))
        names = [''.join(rng.choice(list('abcxyz_0123é→'), size=int(rng.integers(0, 12)))) for _ in range(n)]
        arrays = []
        for _ in range(3):
            m = n if rng.random() < 0.7 else int(rng.integers(0, 5))
            a = rng.normal(size=m) * 10.0 ** rng.integers(-300, 300)
            kind = k % 3
            arrays.append(a if kind == 0 else a.astype(np.float32) if kind == 1 else [float(x) for x in a])
        t_ns = int(rng.integers(0, 2 ** 60))
        msg = M.joint_state(t_ns, names, *[np.zeros(0)] * 3)
        msg['position'], msg['velocity'], msg['effort'] = arrays
        msg['header']['frame_id'] = '' if k % 4 else 'base_link'
        msg['header']['stamp'] = {'sec': int(rng.integers(-2 ** 31, 2 ** 31)), 'nanosec': int(rng.integers(0, 2 ** 32))}
        out.append(msg)
    return out


def test_joint_state_fast_path_is_byte_identical():
    rng = np.random.default_rng(3)
    msgs = _joint_states(rng)
    taken = 0
    for msg in msgs:
        fast = cdr._fast_joint_state(msg)
        taken += fast is not None
        assert cdr.encode('sensor_msgs/msg/JointState', msg) == generic('sensor_msgs/msg/JointState', msg)
        if fast is not None:
            assert fast == generic('sensor_msgs/msg/JointState', msg)
    assert taken == len(msgs)  # every one of these went the fast way
    assert len(cdr._NAMES_CACHE) <= cdr._NAMES_CACHE_MAX


def test_clock_and_float64_multi_array_fast_paths_are_byte_identical():
    rng = np.random.default_rng(4)
    for k in range(30):
        t_ns = int(rng.integers(0, 2 ** 60))
        clk = M.clock(t_ns)
        assert cdr._fast_clock(clk) == generic('rosgraph_msgs/msg/Clock', clk)
        data = rng.normal(size=int(rng.integers(0, 8)))
        fa = M.float64_array(data, label='é' * (k % 3) + 'x' * (k % 5))
        fa['layout']['data_offset'] = k
        if k % 4 == 0:
            fa['layout']['dim'] = fa['layout']['dim'] * 2
        assert cdr._fast_float64_multi_array(fa) is not None
        assert cdr.encode('std_msgs/msg/Float64MultiArray', fa) == generic('std_msgs/msg/Float64MultiArray', fa)


@pytest.mark.parametrize('msg', [
    {'header': {'stamp': {'sec': 1, 'nanosec': 2}}, 'name': ['a'], 'position': np.ones(1),
     'velocity': np.ones(1), 'effort': np.ones(1)},                       # missing frame_id
    {'header': {'stamp': {'sec': 1, 'nanosec': 2}, 'frame_id': ''}, 'name': ['a'],
     'position': np.ones((1, 1)), 'velocity': np.ones(1), 'effort': np.ones(1)},  # 2-D array
    {'header': {'stamp': {'sec': 1, 'nanosec': 2}, 'frame_id': ''}, 'name': ['a'],
     'position': [1], 'velocity': np.ones(1), 'effort': np.ones(1)},     # int list
])
def test_unusual_messages_decline_the_fast_path_and_still_encode_generically(msg):
    assert cdr._fast_joint_state(msg) is None
    assert cdr.encode('sensor_msgs/msg/JointState', msg) == generic('sensor_msgs/msg/JointState', msg)


def _tf_message(rng, n):
    names = ['', 'a', 'odom', 'base_link', 'arm_link4', 'é→x', 'tool']
    transforms = []
    for _ in range(n):
        t_ns = int(rng.integers(0, 2 ** 60))
        v = [float(x) for x in rng.normal(size=7) * 10.0 ** rng.integers(-300, 300)]
        transforms.append({'header': M.header(t_ns, str(rng.choice(names))), 'child_frame_id': str(rng.choice(names)),
                           'transform': {'translation': dict(zip('xyz', v[:3])), 'rotation': dict(zip('xyzw', v[3:]))}})
    return {'transforms': transforms}


def test_tf_message_fast_path_is_byte_identical():
    rng = np.random.default_rng(5)
    for k in range(40):
        msg = _tf_message(rng, k % 6)
        fast = cdr._fast_tf_message(msg)
        assert fast is not None
        assert fast == generic('tf2_msgs/msg/TFMessage', msg)
        # the cached layout of the same frames with other numbers
        again = _tf_message(rng, k % 6)
        for a, b in zip(again['transforms'], msg['transforms']):
            a['header']['frame_id'], a['child_frame_id'] = b['header']['frame_id'], b['child_frame_id']
        assert cdr.encode('tf2_msgs/msg/TFMessage', again) == generic('tf2_msgs/msg/TFMessage', again)
    assert len(cdr._TF_CACHE) <= cdr._NAMES_CACHE_MAX


def test_unusual_tf_messages_decline_the_fast_path_and_still_encode_generically():
    rng = np.random.default_rng(6)
    msg = _tf_message(rng, 2)
    msg['transforms'][1]['transform']['rotation']['w'] = np.float64(1.0)   # numpy scalar
    no_child = _tf_message(rng, 1)
    del no_child['transforms'][0]['child_frame_id']
    for m in (msg, no_child, {'transforms': tuple(_tf_message(rng, 1)['transforms'])}):
        assert cdr._fast_tf_message(m) is None
        assert cdr.encode('tf2_msgs/msg/TFMessage', m) == generic('tf2_msgs/msg/TFMessage', m)


def _diagnostics(rng, k):
    values = {f'k{i}' + 'é' * (i % 2): [1.5, -2, True, 'rk4', float('nan'), np.float64(3e-300)][i % 6]
              for i in range(int(rng.integers(0, 12)))}
    msg = M.diagnostic_array(int(rng.integers(0, 2 ** 60)), 'robodyn_ros: simulation' * (k % 2),
                             int(rng.integers(0, 3)), 'running' + 'x' * (k % 5), values, hardware_id='h' * (k % 3))
    if k % 4 == 3:
        msg['status'] = msg['status'] * 2 if k % 8 == 3 else []
    return msg


def test_diagnostic_array_fast_path_is_byte_identical():
    rng = np.random.default_rng(11)
    for k in range(40):
        msg = _diagnostics(rng, k)
        fast = cdr._fast_diagnostic_array(msg)
        assert fast is not None and fast == generic('diagnostic_msgs/msg/DiagnosticArray', msg)
    odd = _diagnostics(rng, 0)
    odd['status'][0]['level'] = 1        # an int, not one byte: declined, still encoded
    assert cdr._fast_diagnostic_array(odd) is None
    odd['status'][0]['level'] = b'\x01'
    del odd['status'][0]['hardware_id']  # missing field: the generic encoder fills it in
    assert cdr._fast_diagnostic_array(odd) is None
    assert cdr.encode('diagnostic_msgs/msg/DiagnosticArray', odd) == generic('diagnostic_msgs/msg/DiagnosticArray', odd)


def test_diagnostic_array_bytes_align_every_string_length():
    """Keys and values of every length mod 4 (and past the packed short lengths), after frame ids and
    strings of every length: the fast encoder (keys and header encoded once per alignment) writes
    the generic encoder's bytes, message after message."""
    rng = np.random.default_rng(5)
    n = 0
    for frame in ('', 'a', 'ab', 'abc'):
        for k in range(12):
            values = {'k' * int(rng.integers(1, 9)) + str(i): 'v' * int(rng.integers(0, 80)) for i in range(k)}
            msg = M.diagnostic_array(int(rng.integers(0, 2 ** 60)), 'n' * (k % 4), 0, 'm' * (k % 3), values,
                                     hardware_id='h' * (k % 5))
            msg['header']['frame_id'] = frame
            assert cdr._fast_diagnostic_array(msg) == generic('diagnostic_msgs/msg/DiagnosticArray', msg)
            n += 1
    assert n == 48


def test_diagnostic_values_bytes_equal_the_generic_encoding_of_the_status_dict():
    """The recorder's diagnostics (cdr.diagnostic_values_bytes: a status's fields and keys laid out once
    per set of keys) against the generic encoder of messages.diagnostic_array's dict: values of every
    kind messages formats (floats, non-finite ones, ints, booleans, numpy scalars, strings) and of
    every length mod 4, keys of every length, the same keys again with other values."""
    rng = np.random.default_rng(9)
    kinds = [lambda: float(rng.normal() * 10.0 ** rng.integers(-8, 8)), lambda: float('nan'), lambda: -math.inf,
             lambda: int(rng.integers(-10 ** 9, 10 ** 9)), lambda: bool(rng.integers(0, 2)),
             lambda: np.float64(rng.normal()), lambda: np.int64(rng.integers(0, 99)), lambda: np.bool_(True),
             lambda: 'w' * int(rng.integers(0, 70)), lambda: 'rosenbrock2']
    n = 0
    for frame in ('', 'a', 'ab', 'abc'):
        for k in range(10):
            keys = ['é' * int(rng.integers(0, 3)) + 'k' * int(rng.integers(1, 9)) + str(i) for i in range(k)]
            for again in range(3):   # the same keys (a cached layout), other values
                values = {key: kinds[int(rng.integers(0, len(kinds)))]() for key in keys}
                t_ns = int(rng.integers(0, 2 ** 60))
                msg = M.diagnostic_array(t_ns, 'n' * (k % 4), k % 3, 'm' * (k % 3), values, hardware_id='h' * (k % 5))
                msg['header']['frame_id'] = frame
                sec, nsec = divmod(t_ns, 1_000_000_000)
                assert cdr.diagnostic_values_bytes(sec, nsec, frame, k % 3, 'n' * (k % 4), 'm' * (k % 3), 'h' * (k % 5),
                                                   values, M.format_value) == \
                    generic('diagnostic_msgs/msg/DiagnosticArray', msg)
                n += 1
    assert n == 120


def test_layouts_put_the_numbers_where_the_generic_encoder_does():
    rng = np.random.default_rng(12)
    for k in range(20):
        n = [int(x) for x in rng.integers(0, 7, size=3)]
        names = tuple(f'j{i}' + 'é' * (k % 3) for i in range(n[0]))
        arrays = [rng.normal(size=m) for m in n]
        t_ns = int(rng.integers(0, 2 ** 60))
        sec, nsec = divmod(t_ns, 10 ** 9)
        tpl, offsets = cdr.joint_state_layout(cdr.joint_state_names('', names), n)
        buf = bytearray(tpl)
        buf[cdr.STAMP_AT:cdr.STAMP_AT + 8] = cdr._TIME.pack(sec, nsec)
        for at, a in zip(offsets, arrays):
            buf[at:at + 8 * len(a)] = a.astype('<f8').tobytes()
        assert bytes(buf) == generic('sensor_msgs/msg/JointState', M.joint_state(t_ns, names, *arrays))
        tpl, at = cdr.float64_array_layout(n[1])
        assert tpl[:at] + arrays[1].tobytes() == generic('std_msgs/msg/Float64MultiArray', M.float64_array(arrays[1]))
        w = rng.normal(size=6)
        tpl, at = cdr.wrench_stamped_layout('link' * (k % 3))
        buf = bytearray(tpl)
        buf[cdr.STAMP_AT:cdr.STAMP_AT + 8] = cdr._TIME.pack(sec, nsec)
        buf[at:at + 48] = np.r_[w[3:], w[:3]].tobytes()
        assert bytes(buf) == generic('geometry_msgs/msg/WrenchStamped', M.wrench_stamped(t_ns, 'link' * (k % 3), w))
        odom = {'position': rng.normal(size=3), 'orientation': rng.normal(size=4), 'linear': rng.normal(size=3),
                'angular': rng.normal(size=3)}
        tpl, at = cdr.odometry_layout()
        buf = bytearray(tpl)
        buf[cdr.STAMP_AT:cdr.STAMP_AT + 8] = cdr._TIME.pack(sec, nsec)
        buf[at:at + 56] = np.r_[odom['position'], odom['orientation']].tobytes()
        buf[at + 8 * 43:at + 8 * 49] = np.r_[odom['linear'], odom['angular']].tobytes()
        assert bytes(buf) == generic('nav_msgs/msg/Odometry', M.odometry(t_ns, odom))


@pytest.mark.parametrize('name', ['stanford_arm', 'mobile_manipulator', 'unfried_free_flyer', 'huston_prescribed_planar3'])
def test_tf_transform_values_equal_the_per_publication_transforms(name):
    import warnings

    from robodyn_ros.scene import load_scene
    from robodyn_ros.simulation import Simulator
    from robodyn_ros.tf import TfTree
    sc = load_scene(name)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    tree = TfTree(sc.system)
    outs = []
    for k in range(12):
        sim.advance(0.01 * (k + 1))
        outs.append(sim.outputs(wrenches=False))
    rng = np.random.default_rng(13)
    pos = np.array([o.position for o in outs]) + rng.normal(size=(12, len(outs[0].position))) * 3.0  # any angle
    odom = None if outs[0].odom is None else np.array([np.r_[o.odom['position'], o.odom['orientation']] for o in outs])
    got = tree.transform_values(outs[0].joint_names, pos, odom)
    for k, o in enumerate(outs):
        trs = tree.transforms(o.joint_names, pos[k], o.odom)
        assert len(trs) == got.shape[1] > 0
        want = np.array([(*p, *q) for _, _, p, q in trs])
        assert want.tobytes() == got[k].tobytes()   # bit for bit
    assert [f for f in tree.frames(odom is not None)] == [(p, c) for p, c, _, _ in trs]
