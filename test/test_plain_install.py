"""A plain install runs every bundled scene: example-robot-data (a test extra) hidden, ``a1_stand`` and
``solo12_drop`` run on the copy of their two robots bundled with the package
(``robodyn_ros/data/example-robot-data``, found by ``robodyn_ros.meshes.resolve_uri``); and ``robodyn
warm`` and ``robodyn run`` end a broken scene in one line, never a traceback."""
from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from robodyn_ros.meshes import bundled_robot_data_dir, example_robot_data_dir, resolve_uri
from robodyn_ros.scene import list_scenes, load_scene, parse_scene

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ['a1_description/urdf/a1.urdf', 'solo_description/robots/solo12.urdf']


@pytest.fixture(scope='module')
def plain_env(tmp_path_factory):
    """Environment of a ``python -S`` whose packages are this interpreter's site-packages without
    example-robot-data (nor the cmeel prefix it installs into, nor any .pth file), and this tree first."""
    site = Path(sysconfig.get_paths()['purelib'])
    plain = tmp_path_factory.mktemp('plain_site')
    hidden = 0
    for e in site.iterdir():
        if e.name.lower().startswith(('example_robot_data', 'cmeel')) or e.suffix == '.pth':
            hidden += 1
            continue
        (plain / e.name).symlink_to(e)
    assert hidden >= 2
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(plain)]), PYTHONNOUSERSITE='1')


def _py(env, *args, timeout=900):
    return subprocess.run([sys.executable, '-S', *args], env=env, capture_output=True, text=True, timeout=timeout)


def test_the_bundled_files_are_example_robot_datas_own():
    """Byte for byte the installed example-robot-data's files (the test extra is here), with its licence."""
    erd = example_robot_data_dir()
    own = bundled_robot_data_dir()
    files = [p for p in own.rglob('*') if p.is_file()]
    assert len(files) == 16   # a1: URDF, README; solo12: URDF, README, 10 STL; xarm7: URDF, README
    for p in files:
        assert p.read_bytes() == (erd / p.relative_to(own)).read_bytes(), p
    assert (own.parent / 'LICENSE').read_text().startswith('BSD 2-Clause License')
    size = sum(p.stat().st_size for p in own.parent.rglob('*') if p.is_file())
    assert size < 2_000_000, size   # 1.6 MB: three URDFs, solo12's STL meshes, the licence and READMEs


def test_package_uris_prefer_the_installed_example_robot_data_and_fall_back_to_the_bundled_copy(plain_env):
    uri = 'package://example-robot-data/robots/solo_description/meshes/stl/with_foot/solo_foot.stl'
    assert resolve_uri(uri) == example_robot_data_dir() / 'solo_description/meshes/stl/with_foot/solo_foot.stl'
    code = ('from robodyn_ros.meshes import resolve_uri, example_robot_data_dir, MeshError\n'
            f'print(example_robot_data_dir(), resolve_uri({uri!r}))\n'
            'try:\n    resolve_uri("package://example-robot-data/robots/a1_description/meshes/trunk.dae")\n'
            'except MeshError as e:\n    print("MeshError", e)\n')
    p = _py(plain_env, '-c', code)
    assert p.returncode == 0, p.stderr
    first, second = p.stdout.splitlines()
    assert first == f'None {bundled_robot_data_dir() / "solo_description/meshes/stl/with_foot/solo_foot.stl"}'
    assert second.startswith('MeshError package://example-robot-data/robots/a1_description/meshes/trunk.dae: not found')


def test_every_bundled_scene_loads_and_a1_and_solo12_run_without_example_robot_data(plain_env):
    names = [n for n, _ in list_scenes()]
    assert {'a1_stand', 'solo12_drop'} <= set(names)
    code = ('import importlib.metadata as md, warnings\nwarnings.simplefilter("ignore")\n'
            'try:\n    md.distribution("example-robot-data"); print("visible")\nexcept md.PackageNotFoundError:\n'
            '    print("hidden")\n'
            'from robodyn_ros.scene import list_scenes, load_scene\n'
            'print(len([load_scene(n) for n, _ in list_scenes()]))\n')
    p = _py(plain_env, '-c', code)
    assert p.returncode == 0 and p.stdout.split() == ['hidden', str(len(names))], p.stderr
    for scene, t in (('a1_stand', '0.05'), ('solo12_drop', '0.02')):
        p = _py(plain_env, '-m', 'robodyn_ros.cli', 'run', scene, '--duration', t)
        assert p.returncode == 0 and f'simulated {float(t):.3f} s' in p.stdout, (scene, p.stderr)
        assert 'Traceback' not in p.stderr


def test_a_bundled_scene_reads_the_same_robot_with_or_without_example_robot_data():
    """The bundled URDFs are the installed ones, so the scenes' models are equal either way."""
    for rel in BUNDLED:
        assert (bundled_robot_data_dir() / rel).read_bytes() == (example_robot_data_dir() / rel).read_bytes()
    assert load_scene('a1_stand').system.model.total_mass() > 10.0


def test_warm_ends_a_broken_scene_in_one_line_and_warms_the_others(monkeypatch, capsys):
    from robodyn_ros.cli import main, warm
    runs = [('stanford_arm', lambda: load_scene('stanford_arm')),
            ('broken', lambda: parse_scene('name: x\nparts: []\n', file='broken.yaml'))]
    monkeypatch.setattr(warm, '_scene_runs', lambda scratch: runs)
    assert main(['warm', '--quiet', '--jobs', '1']) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == 'robodyn warm: broken: not warmed: broken.yaml: parts: a scene needs at least one part', err
    assert len(err) == 2 and err[1].startswith('robodyn warm: 1 scene could not be warmed (broken);'), err


def test_run_ends_a_broken_scene_in_one_line(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('name: bad\nparts:\n  - {kind: urdf, name: r, file: package://example-robot-data/robots/none.urdf}\n')
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(bad), '--duration', '0.01'],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and 'Traceback' not in p.stderr and len(p.stderr.splitlines()) == 1, p.stderr
    assert 'package://example-robot-data/robots/none.urdf: not found' in p.stderr
