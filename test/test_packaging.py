"""Packaging: package.xml agrees with the installed metadata, and colcon installs what ROS needs.

The colcon build runs on a copy of the tracked files (``git ls-files``) in a temporary
workspace, so the repository never gets build/ install/ log/ directories.  It takes a few
seconds (about one for colcon itself).
"""
import configparser
import importlib.metadata
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

PACKAGE = 'robodyn_ros'
REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent  # not resolved: the venv's bin, not the base python's
EXEC_DEPENDS = ('rclpy', 'std_msgs', 'sensor_msgs', 'nav_msgs', 'geometry_msgs', 'rosgraph_msgs',
                'diagnostic_msgs', 'std_srvs', 'python3-numpy', 'python3-scipy')
CONSOLE_SCRIPTS = {'sim': 'robodyn_ros.nodes.sim:main', 'robodyn': 'robodyn_ros.cli:main',
                   'diver_controller': 'robodyn_ros.nodes.diver_controller:main',
                   'pd_hold_controller': 'robodyn_ros.nodes.pd_hold_controller:main'}
COLCON_TIMEOUT_S = 120


@pytest.fixture(scope='module')
def tracked():
    """The tracked files present in the work tree, listed once so that the build and the
    checks see the same set even while others commit."""
    out = subprocess.run(['git', 'ls-files', '-z'], cwd=REPO, check=True,
                         capture_output=True).stdout
    return [rel for rel in out.decode().split('\0') if rel and (REPO / rel).is_file()]


@pytest.fixture(scope='module')
def manifest():
    """The parsed package.xml root element."""
    return ET.parse(REPO / 'package.xml').getroot()


def test_manifest_is_format_3_with_the_runtime_dependencies(manifest):
    assert manifest.tag == 'package' and manifest.get('format') == '3'
    assert manifest.findtext('name') == PACKAGE
    assert manifest.findtext('export/build_type') == 'ament_python'
    exec_depends = {e.text.strip() for e in manifest.findall('exec_depend')}
    missing = sorted(set(EXEC_DEPENDS) - exec_depends)
    assert not missing, f'package.xml lacks <exec_depend> for {missing}'


def test_installed_metadata_agrees_with_manifest(manifest):
    """The version (and license, maintainer) pip installed are those of package.xml."""
    meta = importlib.metadata.metadata(PACKAGE)
    version = manifest.findtext('version').strip()
    assert importlib.metadata.version(PACKAGE) == version, (
        'the installed robodyn_ros metadata is stale or disagrees with package.xml; '
        'reinstall with `make venv` (pip install -e .)')
    assert meta['License'] == manifest.findtext('license').strip()
    maintainer = manifest.find('maintainer')
    assert meta['Maintainer-email'] == maintainer.get('email')
    assert meta['Maintainer'] == maintainer.text.strip()
    entry_points = {ep.name: ep.value for ep in
                    importlib.metadata.distribution(PACKAGE).entry_points
                    if ep.group == 'console_scripts'}
    assert entry_points == CONSOLE_SCRIPTS


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory, tracked):
    """Build a copy of the tracked sources with the venv's colcon; return the install prefix."""
    colcon = VENV_BIN / 'colcon'
    if not colcon.exists():
        pytest.fail(f'colcon is not installed in {VENV_BIN} (pip package '
                    'colcon-common-extensions, part of the [test] extra)')
    workspace = tmp_path_factory.mktemp('colcon_ws')
    source = workspace / 'src' / PACKAGE
    for rel in tracked:
        dst = source / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, dst)
    env = dict(os.environ)
    env['PATH'] = f'{VENV_BIN}{os.pathsep}{env.get("PATH", "")}'
    env['COLCON_HOME'] = str(workspace / '.colcon')  # ignore the user's colcon defaults
    for var in ('AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH', 'COLCON_PREFIX_PATH'):
        env.pop(var, None)  # nor underlay workspaces of the user's shell
    result = subprocess.run(
        [str(colcon), 'build', '--base-paths', 'src',
         '--event-handlers', 'console_cohesion+', 'desktop_notification-'],
        cwd=workspace, env=env, capture_output=True, text=True, timeout=COLCON_TIMEOUT_S)
    if result.returncode != 0:
        pytest.fail(f'colcon build failed ({result.returncode}):\n{result.stdout[-4000:]}\n'
                    f'{result.stderr[-4000:]}')
    listing = subprocess.run([str(colcon), 'list', '--base-paths', 'src'], cwd=workspace,
                             env=env, capture_output=True, text=True, timeout=60).stdout
    # Without the catkin_pkg module colcon-ros skips package.xml and builds the package as a
    # plain Python package: check it was recognised as an ament_python one.
    assert f'{PACKAGE}\tsrc/{PACKAGE}\t(ros.ament_python)' in listing, listing
    return workspace / 'install' / PACKAGE


def test_colcon_installs_executables_for_ros2_run(colcon_install):
    lib = colcon_install / 'lib' / PACKAGE
    egg_info = list(colcon_install.glob(f'lib/python*/site-packages/{PACKAGE}-*.egg-info'))
    assert len(egg_info) == 1, egg_info
    entry_points = configparser.ConfigParser(delimiters=('=',))
    entry_points.read(egg_info[0] / 'entry_points.txt')
    assert dict(entry_points['console_scripts']) == CONSOLE_SCRIPTS
    for name, target in CONSOLE_SCRIPTS.items():
        script = lib / name
        assert script.is_file(), f'{script} missing: ros2 run {PACKAGE} {name} would fail'
        assert os.access(script, os.X_OK)
        text = script.read_text()
        assert text.startswith('#!') and 'python' in text.splitlines()[0]
        # setuptools writes a loader of the named entry point; other installers import it.
        module = target.split(':')[0]
        assert (f"'console_scripts', '{name}'" in text) or (module in text), text


def source_copy(colcon_install):
    """The workspace copy of the sources that colcon built from."""
    return colcon_install.parents[1] / 'src' / PACKAGE


def test_colcon_installs_manifest_and_ament_index_marker(colcon_install):
    installed = colcon_install / 'share' / PACKAGE / 'package.xml'
    assert installed.read_bytes() == (source_copy(colcon_install) / 'package.xml').read_bytes()
    marker = colcon_install / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE
    assert marker.is_file(), 'ament resource marker missing: ros2 pkg list would not see us'


def test_colcon_installs_every_tracked_module(colcon_install, tracked):
    """A subpackage without __init__.py is silently dropped by find_packages."""
    site = next(colcon_install.glob('lib/python*/site-packages'))
    modules = [rel for rel in tracked if rel.startswith(f'{PACKAGE}/') and rel.endswith('.py')]
    assert f'{PACKAGE}/__init__.py' in modules
    missing = [rel for rel in modules if not (site / rel).is_file()]
    assert not missing, f'not installed (missing __init__.py?): {missing}'


def test_colcon_installs_every_config_file(colcon_install, tracked):
    config = [rel for rel in tracked if rel.startswith('config/')]
    assert config, ('config/ has no tracked files: no scene would be installed to '
                    f'share/{PACKAGE}/config (scenes are expected under config/scenes/)')
    share = colcon_install / 'share' / PACKAGE
    missing = [rel for rel in config if not (share / rel).is_file()]
    assert not missing, (f'tracked config files not installed to share/{PACKAGE}/ '
                         f'(setup.py data_files): {missing}')
    source = source_copy(colcon_install)
    for rel in config:
        assert (share / rel).read_bytes() == (source / rel).read_bytes(), rel


def test_colcon_installs_the_bundled_message_definitions(colcon_install, tracked):
    """setup.py package_data: the tf2_msgs/TFMessage .msg and .json the recorder falls back to."""
    site = next(colcon_install.glob('lib/python*/site-packages'))
    bundled = [rel for rel in tracked if rel.startswith(f'{PACKAGE}/recording/msg/')]
    assert {f'{PACKAGE}/recording/msg/tf2_msgs/msg/TFMessage.msg',
            f'{PACKAGE}/recording/msg/tf2_msgs/msg/TFMessage.json'} <= set(bundled), bundled
    missing = [rel for rel in bundled if not (site / rel).is_file()]
    assert not missing, f'not installed (setup.py package_data): {missing}'
