"""Foxglove layouts (``robodyn layout``, :mod:`robodyn_ros.layout`) against recordings of every bundled
scene and of URDF robots: no panel is empty.

For each scene a short recording is made (the recorder ``robodyn run`` uses). The layout made from
the scene equals the one made from its recording; it is a layout in Foxglove's exported shape
(``configById`` + a split tree naming every panel once), each panel's config uses only keys
Foxglove Studio's panels know (from its sources: the 3D panel's ``RendererConfig``/``CameraState``,
the Plot panel's ``PlotConfig``/``PlotPath``, the Publish panel's config); the 3D panel shows topics
the recording has, follows a frame it has; and every message path of every plot resolves to numbers
in the recorded messages (a small evaluator of the path syntax the layouts use: fields, ``[i]``,
``[:]`` and ``{key=="..."}`` filters). The bundled ``config/foxglove/robodyn_layout.json`` is the
stanford_arm layout.
"""
from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import pytest

from robodyn_ros.layout import MAX_LINES, layout, layout_text, recording_info, scene_info
from robodyn_ros.recording import cdr
from robodyn_ros.recording.reader import read_messages
from robodyn_ros.recording.run_sink import McapRunSink
from robodyn_ros.runs import plan_run, resolve_settings
from robodyn_ros.scene import list_scenes, load_scene
from robodyn_ros.simulation import Simulator, run_headless

REPO = Path(__file__).resolve().parents[1]
LAYOUT = REPO / 'config' / 'foxglove' / 'robodyn_layout.json'
SCENES = [name for name, _ in list_scenes()]

TOP_KEYS = {'configById', 'globalVariables', 'userNodes', 'playbackConfig', 'layout'}
SPLIT_KEYS = {'first', 'second', 'direction', 'splitPercentage'}
PANEL_TITLE = 'foxglovePanelTitle'
THREE_D_KEYS = {'cameraState', 'followMode', 'followTf', 'scene', 'transforms', 'topics', 'layers', 'publish',
                'imageMode', PANEL_TITLE}
CAMERA_KEYS = {'distance', 'perspective', 'phi', 'thetaOffset', 'target', 'targetOffset', 'targetOrientation',
               'fovy', 'near', 'far'}
FOLLOW_MODES = {'follow-pose', 'follow-position', 'follow-none'}
SCENE_KEYS = {'enableStats', 'backgroundColor', 'labelScaleFactor', 'ignoreColladaUpAxis', 'meshUpAxis', 'transforms',
              'syncCamera', 'topicsVisible'}
SCENE_TRANSFORM_KEYS = {'editable', 'showLabel', 'labelSize', 'axisScale', 'lineWidth', 'lineColor',
                        'enablePreloading'}
FRAME_KEYS = {'visible', 'frameLocked', 'xyzOffset', 'rpyCoefficient'}
GRID_KEYS = {'visible', 'frameLocked', 'label', 'instanceId', 'layerId', 'frameId', 'size', 'divisions', 'lineWidth',
             'color', 'position', 'rotation', 'order'}
PUBLISH_KEYS = {'type', 'poseTopic', 'pointTopic', 'poseEstimateTopic', 'poseEstimateXDeviation',
                'poseEstimateYDeviation', 'poseEstimateThetaDeviation'}
PLOT_KEYS = {'title', 'paths', 'minYValue', 'maxYValue', 'showXAxisLabels', 'showYAxisLabels', 'showLegend',
             'legendDisplay', 'showPlotValuesInLegend', 'isSynced', 'xAxisVal', 'xAxisPath', 'sidebarDimension',
             'followingViewWidth', PANEL_TITLE}
PLOT_PATH_KEYS = {'value', 'enabled', 'timestampMethod', 'label', 'color', 'showLine'}
PUBLISH_PANEL_KEYS = {'topicName', 'datatype', 'buttonText', 'buttonTooltip', 'buttonColor', 'advancedView', 'value',
                      PANEL_TITLE}


def _record(path, scene, duration=0.06):
    """A short recording of ``scene`` as robodyn run makes it (diagnostics every period)."""
    plan, st = plan_run(resolve_settings(scene, duration=duration), scene.system, scene.y0)
    sim = Simulator(scene.system, scene.y0, plan=plan)
    sink = McapRunSink(path, scene, {**st, 'mode': 'headless'}, diagnostics_period=0.01, batch=8)
    try:
        run_headless(sim, duration, st['rate'], scene.script, [sink])
    finally:
        sink.close()
    return path


def _urdf_robots():
    from robodyn_ros.urdf import example_robot_data_dir
    d = example_robot_data_dir()
    return [d / 'ur_description' / 'urdf' / 'ur5_robot.urdf', d / 'solo_description' / 'robots' / 'solo12.urdf']


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    """name -> (scene layout info, recording path, topic -> [decoded message]) for every bundled scene
    and two example-robot-data URDFs."""
    tmp = tmp_path_factory.mktemp('layouts')
    out = {}
    sources = [(n, n) for n in SCENES] + [(p.stem, str(p)) for p in _urdf_robots()]
    assert len(sources) == len(SCENES) + 2 >= 19
    for name, src in sources:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            scene = load_scene(src)
            path = _record(tmp / f'{name}.mcap', scene)
        msgs = {}
        for topic, _, _, msg in read_messages(path):
            msgs.setdefault(topic, []).append(msg)
        out[name] = (scene_info(scene), path, msgs)
    return out


def _panels(node):
    """Panel ids named by a layout split tree, in order."""
    if isinstance(node, str):
        return [node]
    assert set(node) <= SPLIT_KEYS and {'first', 'second', 'direction'} <= set(node), node
    assert node['direction'] in ('row', 'column')
    assert 0 < node.get('splitPercentage', 50) < 100
    return _panels(node['first']) + _panels(node['second'])


def _resolve(msg, path):
    """Values of a Foxglove message path (the part after the topic) in a decoded message."""
    assert path == ''.join(re.findall(r'\.[A-Za-z_]\w*|\[(?:\d+|:)\]|\{\w+=="[^"]*"\}', path)), path
    values = [msg]
    for token in re.findall(r'\.([A-Za-z_]\w*)|\[(\d+|:)\]|\{(\w+)=="([^"]*)"\}', path):
        field, index, key, want = token
        nxt = []
        for v in values:
            if field:
                nxt.append(getattr(v, field))
            elif index == ':':
                nxt.extend(v)
            elif index:
                if int(index) < len(v):
                    nxt.append(v[int(index)])
            else:
                if getattr(v, key) == want:
                    nxt.append(v)
        values = nxt
    return values


def _check_shape(lay, live=False):
    assert set(lay) == TOP_KEYS and lay['playbackConfig'] == {'speed': 1}
    ids = _panels(lay['layout'])
    assert sorted(ids) == sorted(lay['configById']) and len(set(ids)) == len(ids)
    kinds = [i.split('!')[0] for i in ids]
    assert kinds.count('3D') == 1 and kinds.count('Plot') == 4 and kinds.count('Publish') == (1 if live else 0)
    assert all(re.fullmatch(r'[A-Za-z0-9]+![a-z0-9]+', i) for i in ids), ids
    return ids


@pytest.mark.parametrize('name', SCENES + ['ur5_robot', 'solo12'])
def test_the_layout_of_a_scene_fits_its_recording(runs, name):
    info, path, msgs = runs[name]
    lay = layout(info)
    assert lay == layout(recording_info(path))      # the scene's layout is its recordings' layout
    _check_shape(lay)
    cfg = lay['configById']['3D!robodyn']
    assert set(cfg) <= THREE_D_KEYS and set(cfg['cameraState']) == CAMERA_KEYS
    assert 1.0 <= cfg['cameraState']['distance'] <= 20.0 and cfg['followMode'] in FOLLOW_MODES
    assert set(cfg['scene']) <= SCENE_KEYS and set(cfg['scene']['transforms']) <= SCENE_TRANSFORM_KEYS
    # URDF meshes are Z-up (REP-103, as RViz reads them); Foxglove reads STL and OBJ meshes Y-up unless the
    # 3D panel says otherwise (Studio 1.48's DEFAULT_MESH_UP_AXIS = "y_up", which turned xarm7's links 90°
    # about x: seen in the headless Studio): every layout says Z-up (for meshes a live run serves as files), and
    # these robots' STL and COLLADA meshes are recorded as glTF
    assert cfg['scene'].get('meshUpAxis') == 'z_up'
    description = msgs['/robot_description'][0].data
    with_meshes = ('xarm7_trajectory', 'solo12_drop', 'solo12', 'a1_stand', 'ur5_robot')
    assert ('data:model/gltf-binary;base64,' in description) == (name in with_meshes), \
        name   # their meshes, as glTF (assets.embed_meshes), which Foxglove turns up whatever the setting
    assert 'data:model/stl;' not in description and 'data:model/vnd.collada+xml;' not in description
    assert set(cfg['publish']) == PUBLISH_KEYS
    for layer in cfg['layers'].values():
        assert layer['layerId'] == 'foxglove.Grid' and set(layer) <= GRID_KEYS
    # the shown topics are recorded: the robot, and on a ground or with sensors its markers (touching points
    # after the drop, IMU axes and force-torque arrows), drawn in a frame of the recording's tf tree
    assert set(cfg['topics']) <= set(msgs) and '/robot_description' in cfg['topics']
    assert all(v == {'visible': True} for v in cfg['topics'].values())
    sensors = any(k.startswith(('/imu/', '/ft/')) for k in msgs)
    assert ('/markers' in cfg['topics']) == ('/markers' in msgs) == (bool(info.contacts) or sensors)
    assert sensors == (name == 'xarm7_trajectory')     # the bundled scene with sensors (its IMU and wrist sensor)
    # the hidden axes and the followed frame are frames of the recording's /tf and /tf_static
    frames = {t.child_frame_id for k in ('/tf', '/tf_static') for m in msgs.get(k, []) for t in m.transforms} | \
        {t.header.frame_id for k in ('/tf', '/tf_static') for m in msgs.get(k, []) for t in m.transforms}
    keys = {k[len('frame:'):] for k in cfg['transforms']}
    assert keys == frames and all(set(v) <= FRAME_KEYS for v in cfg['transforms'].values())
    drawn_in = {x.header.frame_id for m in msgs.get('/markers', []) for x in m.markers}
    assert drawn_in <= frames and len(drawn_in) == ('/markers' in msgs)
    assert cfg.get('followTf') is None or cfg['followTf'] in frames
    assert (cfg.get('followTf') is not None) == ('/odom' in msgs)


@pytest.mark.parametrize('name', SCENES + ['ur5_robot', 'solo12'])
def test_no_plot_of_a_scene_is_empty(runs, name):
    info, path, msgs = runs[name]
    lay = layout(info)
    topics = sorted(msgs, key=len, reverse=True)
    plots = [p for p in lay['configById'] if p.startswith('Plot!')]
    assert len(plots) == 4
    for pid in plots:
        cfg = lay['configById'][pid]
        assert set(cfg) <= PLOT_KEYS and cfg['xAxisVal'] == 'timestamp'
        assert 1 <= len(cfg['paths']) <= 3 * MAX_LINES
        for p in cfg['paths']:
            assert set(p) <= PLOT_PATH_KEYS and p['enabled'] is True
            assert p['timestampMethod'] == 'receiveTime'     # = the recording's log time = simulation time
            topic = next(t for t in topics if p['value'].startswith(t + '.'))
            values = [x for m in msgs[topic] for x in _resolve(m, p['value'][len(topic):])]
            assert len(values) == len(msgs[topic]) >= 1, p['value']   # one number per message
            # numbers (diagnostics values are numeric strings, which Foxglove plots as numbers)
            assert all(isinstance(x, (int, float)) or math.isfinite(float(x)) for x in values), p['value']
    # the joints plotted are named (the legend), as many as there are (up to MAX_LINES)
    positions = lay['configById']['Plot!positions']['paths']
    assert [p['label'] for p in positions] == info.joints[:MAX_LINES]


@pytest.mark.parametrize('name', ['stanford_arm', 'mobile_manipulator', 'unfried_free_flyer', 'a1_stand'])
def test_a_live_layout_publishes_a_zero_command_of_the_first_command_topic(runs, name):
    info, _, _ = runs[name]
    lay = layout(info, live=True)
    _check_shape(lay, live=True)
    pub = lay['configById']['Publish!command']
    assert set(pub) <= PUBLISH_PANEL_KEYS
    topic, type_name, n = info.commands[0]
    assert pub['topicName'] == topic and pub['datatype'] == type_name
    msg = json.loads(pub['value'])
    data = cdr.decode(type_name, cdr.encode(type_name, msg))   # a message of that type, all zero
    if 'data' in data:
        assert list(data['data']) == [0.0] * n and n > 0
    else:
        assert data['header']['frame_id'] == 'base_link' and data['wrench']['force'] == {'x': 0.0, 'y': 0.0, 'z': 0.0}


def test_the_bundled_layout_is_the_stanford_arm_layout(runs):
    info, _, _ = runs['stanford_arm']
    assert LAYOUT.read_text() == layout_text(info)
    cfg = json.loads(LAYOUT.read_text())['configById']
    # the arm's shoulder and boom: the reactions plot names joint2 and joint3
    assert {p['value'] for p in cfg['Plot!reactions']['paths']} == \
        {f'/constraint_wrenches/joint{j}.wrench.force.{a}' for j in (2, 3) for a in 'xyz'}


def test_robodyn_layout_writes_the_layout_of_a_recording_and_refuses_a_missing_one(runs, tmp_path):
    from robodyn_ros.cli import main
    _, path, _ = runs['betancur_platform']
    out = tmp_path / 'platform.json'
    assert main(['layout', str(path), '--out', str(out)]) == 0
    assert json.loads(out.read_text()) == layout(recording_info(path))
    assert main(['layout', str(tmp_path / 'missing.mcap')]) == 2
