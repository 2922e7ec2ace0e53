"""A free root's initial velocity, wherever a user writes it: the scene's ``initial_state.v``, the sim
node's parameters, a sweep's parameters. Its six numbers are the root's twist ``[ω; v_O]`` in its
body axes, angular first (Featherstone's order); ROS Twist puts linear first, so a bare list is
read with a warning, and the mapping ``{root: {linear, angular, frame}, joints}`` says which
(robodyn_ros.scene.state). Checked by throwing a ball and watching where it goes."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import yaml

from robodyn_ros.scene import SceneError, parse_scene
from robodyn_ros.scene.state import VelocityOrderWarning
from robodyn_ros.simulation import Simulator

from test_contact import sphere_urdf

#: the ball's initial orientation: turned 90° about world z, so that its body x is world y
TURNED = [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]


def ball(v, quat=TURNED, ground=True):
    """A 1 kg ball (r = 5 cm) on a free root 1 m up, in zero gravity (on a ground it never reaches, or
    without one: the free-flyer system); its initial velocity ``v`` as written in the scene:
    ``(scene, warnings)``."""
    parts = [{'kind': 'urdf', 'name': 'ball', 'urdf': sphere_urdf(), 'floating': True}]
    if ground:
        parts.append({'kind': 'ground'})
    data = {'name': 'throw', 'gravity': [0.0, 0.0, 0.0], 'parts': parts,
            'initial_state': {'q': [0.0, 0.0, 1.0, *quat], 'v': v}}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        sc = parse_scene(yaml.safe_dump(data, sort_keys=False), file='throw.yaml')
    return sc, [w for w in caught if issubclass(w.category, VelocityOrderWarning)]


def travel(sc, T=0.2):
    """Displacement (3,) of the ball's centre in the world over T s (rk4 at 1 ms)."""
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    sim.advance(T)
    return sim.y[:3] - sc.y0[:3]


@pytest.mark.parametrize('ground', [True, False], ids=['arm_on_ground', 'free_flyer'])
def test_a_ball_thrown_along_minus_x_in_the_world_travels_along_minus_x(ground):
    """``{root: {linear: [-1, 0, 0], frame: world}}``: 0.2 m along −x in 0.2 s, whatever the ball's
    orientation (turned 90° about z here), no spin, no warning; ``frame: body`` throws it along its
    own −x, which is world −y."""
    sc, caught = ball({'root': {'linear': [-1.0, 0.0, 0.0], 'angular': [0.0, 0.0, 0.0], 'frame': 'world'}},
                      ground=ground)
    assert not caught
    np.testing.assert_allclose(travel(sc), [-0.2, 0.0, 0.0], atol=1e-12)
    assert not np.any(sc.y0[sc.system.nq:sc.system.nq + 3])     # no spin
    sc, caught = ball({'root': {'linear': [-1.0, 0.0, 0.0], 'frame': 'body'}}, ground=ground)
    assert not caught
    np.testing.assert_allclose(travel(sc), [0.0, -0.2, 0.0], atol=1e-12)


def test_a_world_frame_spin_is_turned_into_body_axes():
    """angular in world axes, the ball turned 90° about z: a spin about world x is about body −y; the
    ball spins in place (it does not travel) and its published angular velocity (body axes, odom's twist)
    says so."""
    sc, _ = ball({'root': {'angular': [2.0, 0.0, 0.0], 'frame': 'world'}})
    nq = sc.system.nq
    np.testing.assert_allclose(sc.y0[nq:nq + 6], [0.0, -2.0, 0.0, 0.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(travel(sc), 0.0, atol=1e-15)


def test_a_bare_list_is_read_angular_first_in_body_axes_with_a_warning():
    """The trap: ``v: [-1, 0, 0, 0, 0, 0]``, meant as a throw along −x, is a spin about body x: the ball
    spins in place, and a warning says how the numbers were read and how to write them. The linear part
    of a bare list is in body axes: [0, 0, 0, −1, 0, 0] on the turned ball goes along world −y. A zero
    root twist, or a joint velocity alone, warns about nothing."""
    sc, caught = ball([-1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert len(caught) == 1
    msg = str(caught[0].message)
    assert msg.startswith("throw.yaml: initial_state.v: the free root 'root_joint''s velocity is read angular first, "
                          "in its body axes"), msg
    assert 'angular [-1.0, 0.0, 0.0] rad/s, linear [0.0, 0.0, 0.0] m/s' in msg and 'frame: world or body' in msg
    np.testing.assert_allclose(travel(sc), 0.0, atol=1e-15)
    sc, caught = ball([0.0, 0.0, 0.0, -1.0, 0.0, 0.0])
    assert len(caught) == 1
    np.testing.assert_allclose(travel(sc), [0.0, -0.2, 0.0], atol=1e-12)
    assert not ball([0.0] * 6)[1]


def test_bad_velocity_mappings_are_refused_with_file_key_reason():
    def bad(v, **kw):
        with pytest.raises(SceneError) as e:
            ball(v, **kw)
        return str(e.value)
    assert bad({'root': {'linear': [-1, 0, 0]}}) == 'throw.yaml: initial_state.v.root.frame: missing required key'
    assert bad({'root': {'linear': [-1, 0, 0], 'frame': 'odom'}}).startswith(
        "throw.yaml: initial_state.v.root.frame: expected one of world, body")
    assert bad({'root': {'linear': [-1, 0], 'frame': 'world'}}).startswith(
        'throw.yaml: initial_state.v.root.linear: expected 3 values')
    assert bad({'joints': []}).startswith('throw.yaml: initial_state.v.root: missing required key')
    # a tree without a free root takes a list only
    text = ('name: p\nparts:\n  - kind: urdf\n    name: p\n    urdf: \'<robot name="p"><link name="a"/><link name="b">'
            '<inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>'
            '</link><joint name="j" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint>'
            '</robot>\'\ninitial_state: {v: {root: {linear: [1, 0, 0], frame: world}}}\n')
    with pytest.raises(SceneError, match=r'^p\.yaml: initial_state\.v: a mapping \{root, joints\} is for a tree with a '
                                         r'free root; ArmSystem has none: give a list of 1'):
        parse_scene(text, file='p.yaml')


def _config(sc, **params):
    from robodyn_ros.nodes.sim import PARAMETERS, resolve_config
    raw = {k: default for k, (default, _) in PARAMETERS.items()}
    raw.update(params)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        cfg = resolve_config(raw, sc)
    return cfg, [w for w in caught if issubclass(w.category, VelocityOrderWarning)]


def test_the_sim_node_parameters_say_the_frame_or_warn():
    """``initial_root_linear_velocity``/``initial_root_angular_velocity`` with ``initial_root_velocity_frame``
    set the free root's twist as the scene's mapping does (world axes turned into body axes); a bare
    ``initial_velocities`` or ``initial_state`` with a root twist warns; without the frame, or on a scene
    without a free root, the parameters are refused naming them."""
    from robodyn_ros.nodes.sim import ConfigError
    from robodyn_ros.scene import load_scene
    sc, _ = ball({'root': {'linear': [0.0, 0.0, 0.0], 'frame': 'world'}})
    nq = sc.system.nq
    cfg, caught = _config(sc, initial_root_linear_velocity=[-1.0, 0.0, 0.0], initial_root_velocity_frame='world')
    assert not caught
    np.testing.assert_allclose(cfg.y0[nq:nq + 6], [0.0, 0.0, 0.0, 0.0, 1.0, 0.0], atol=1e-15)   # world −x = body +y
    cfg, caught = _config(sc, initial_velocities=[-1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert len(caught) == 1 and "parameter 'initial_velocities'" in str(caught[0].message)
    np.testing.assert_allclose(cfg.y0[nq:nq + 6], [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    cfg, caught = _config(sc, initial_state=[0.0, 0.0, 1.0, *TURNED, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0])
    assert len(caught) == 1 and "parameter 'initial_state'" in str(caught[0].message)
    with pytest.raises(ConfigError, match="initial_root_velocity_frame' must be world or body"):
        _config(sc, initial_root_linear_velocity=[-1.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match="has no free root"):
        _config(load_scene('betancur_pendulum'), initial_root_angular_velocity=[0.0, 0.0, 1.0],
                initial_root_velocity_frame='body')


def test_a_sweep_over_a_free_roots_bare_velocities_warns_once(tmp_path):
    """A sweep drawing ``initial_state.v`` of a scene whose free root's velocity is a bare list warns at
    the spec (not per run); over the mapping's ``initial_state.v.root.linear`` it does not, and each run's
    ball goes where its draw says."""
    from robodyn_ros import sweep_spec as S
    for v, key, warns in (([0.0] * 6, 'initial_state.v', True),
                          ({'root': {'linear': [0.0, 0.0, 0.0], 'frame': 'world'}}, 'initial_state.v.root.linear',
                           False)):
        sc, _ = ball(v)
        (tmp_path / 'throw.yaml').write_text(sc.text)
        spec = tmp_path / 'spec.yaml'
        spec.write_text(f'scene: throw.yaml\nseed: 1\nsamples: 2\nduration: 0.05\n'
                        f'random:\n  {key}: {{uniform: [-1.0, 1.0]}}\nfigures: [energy_drift]\n')
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always')
            loaded = S.load_spec(str(spec))
        ours = [w for w in caught if issubclass(w.category, VelocityOrderWarning)]
        assert len(ours) == (1 if warns else 0), [str(w.message) for w in ours]
        if warns:
            assert f'random.{key}: the free root' in str(ours[0].message)
            continue
        task = S.expand(loaded, [0])[0]
        drawn = np.array(task['params'][key], dtype=float)
        run = S.build_scene(loaded.scene_text, loaded.scene_file, task['params'], loaded.backend)
        np.testing.assert_allclose(travel(run, 0.05), 0.05 * drawn, atol=1e-12)
