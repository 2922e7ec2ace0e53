"""config/foxglove/robodyn_layout.json: a Foxglove Studio layout that opens a recording as a person
wants to see it (the robot in a 3D panel, plots of joints, wrenches and energy drift).

Checked against a recording of the default scene (``make run``'s stanford_arm, 0.2 s headless):
the file is valid JSON in Foxglove's exported-layout shape (``configById`` + a split tree naming
every panel once), each panel's config uses only keys Foxglove's panels know (taken from Foxglove
Studio's sources: the 3D panel's ``RendererConfig``/``CameraState``, the Plot panel's
``PlotConfig``/``PlotPath``), the 3D panel shows ``/robot_description`` with the camera a few
metres from the robot, and every message path of every plot resolves to numbers in the recorded
messages (a small evaluator of the path syntax the layout uses: fields, ``[i]``, ``[:]`` and
``{key=="..."}`` filters).
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

LAYOUT = Path(__file__).resolve().parents[1] / 'config' / 'foxglove' / 'robodyn_layout.json'

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
GRID_KEYS = {'visible', 'frameLocked', 'label', 'instanceId', 'layerId', 'frameId', 'size', 'divisions', 'lineWidth',
             'color', 'position', 'rotation', 'order'}
PUBLISH_KEYS = {'type', 'poseTopic', 'pointTopic', 'poseEstimateTopic', 'poseEstimateXDeviation',
                'poseEstimateYDeviation', 'poseEstimateThetaDeviation'}
PLOT_KEYS = {'title', 'paths', 'minYValue', 'maxYValue', 'showXAxisLabels', 'showYAxisLabels', 'showLegend',
             'legendDisplay', 'showPlotValuesInLegend', 'isSynced', 'xAxisVal', 'xAxisPath', 'sidebarDimension',
             'followingViewWidth', PANEL_TITLE}
PLOT_PATH_KEYS = {'value', 'enabled', 'timestampMethod', 'label', 'color', 'showLine'}


@pytest.fixture(scope='module')
def layout():
    return json.loads(LAYOUT.read_text())


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """topic -> [decoded message] of a 0.2 s stanford_arm recording."""
    out = tmp_path_factory.mktemp('fox') / 'arm.mcap'
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', 'stanford_arm', '--duration', '0.2',
                        '--record', str(out)], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    msgs = {}
    with open(out, 'rb') as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            msgs.setdefault(channel.topic, []).append(msg)
    return msgs


def _panels(node):
    """Panel ids named by a layout split tree, in order."""
    if isinstance(node, str):
        return [node]
    assert set(node) <= SPLIT_KEYS and {'first', 'second', 'direction'} <= set(node), node
    assert node['direction'] in ('row', 'column')
    assert 0 < node.get('splitPercentage', 50) < 100
    return _panels(node['first']) + _panels(node['second'])


def test_layout_is_a_foxglove_layout_naming_each_panel_once(layout):
    assert set(layout) == TOP_KEYS
    ids = _panels(layout['layout'])
    assert sorted(ids) == sorted(layout['configById']) and len(set(ids)) == len(ids)
    kinds = [i.split('!')[0] for i in ids]
    assert kinds.count('3D') == 1 and kinds.count('Plot') == 4 and set(kinds) == {'3D', 'Plot'}
    assert all(re.fullmatch(r'[A-Za-z0-9]+![a-z0-9]+', i) for i in ids), ids
    assert layout['playbackConfig'] == {'speed': 1}


def test_3d_panel_shows_the_robot_description_with_the_camera_on_the_robot(layout, recording):
    cfg = layout['configById']['3D!robodyn']
    assert set(cfg) <= THREE_D_KEYS
    cam = cfg['cameraState']
    assert set(cam) == CAMERA_KEYS
    assert 1.0 <= cam['distance'] <= 6.0 and cam['near'] < 0.1      # a few metres, not Foxglove's 20 m
    assert cam['target'] == [0, 0, 0] and max(abs(x) for x in cam['targetOffset']) <= 1.0
    assert cfg['followMode'] in FOLLOW_MODES
    assert set(cfg['scene']) <= SCENE_KEYS and set(cfg['scene']['transforms']) <= SCENE_TRANSFORM_KEYS
    assert set(cfg['publish']) == PUBLISH_KEYS
    # the URDF layer of the recorded /robot_description is switched on (Foxglove hides topics by default)
    assert cfg['topics'] == {'/robot_description': {'visible': True}}
    assert '/robot_description' in recording and '<robot' in recording['/robot_description'][0].data
    for layer in cfg['layers'].values():
        assert layer['layerId'] == 'foxglove.Grid' and set(layer) <= GRID_KEYS
    # no display frame is forced: Foxglove picks base_link, else odom, whichever the recording has
    assert 'followTf' not in cfg
    parents = {t.header.frame_id for m in recording['/tf'] for t in m.transforms}
    children = {t.child_frame_id for m in recording['/tf'] for t in m.transforms}
    assert 'base_link' in parents - children and {'link1', 'link6'} <= children   # base_link: the root


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


def test_every_plot_path_resolves_to_numbers_in_a_recording(layout, recording):
    topics = sorted(recording, key=len, reverse=True)
    n = 0
    for pid, cfg in layout['configById'].items():
        if not pid.startswith('Plot!'):
            continue
        assert set(cfg) <= PLOT_KEYS and cfg['xAxisVal'] == 'timestamp' and cfg['paths']
        for p in cfg['paths']:
            assert set(p) <= PLOT_PATH_KEYS and p['enabled'] is True
            assert p['timestampMethod'] == 'receiveTime'     # = the recording's log time = simulation time
            topic = next(t for t in topics if p['value'].startswith(t + '.'))
            values = [x for m in recording[topic] for x in _resolve(m, p['value'][len(topic):])]
            assert values, p['value']
            assert all(isinstance(x, (int, float)) or float(x) == float(x) for x in values), p['value']
            n += 1
    assert n >= 19
