"""ament_python package for robodyn_ros (see package.xml for ROS metadata)."""
import os
from glob import glob

from setuptools import find_packages, setup

package_name = 'robodyn_ros'


def _package_xml(tag):
    """One field of package.xml, the single source of the version and description."""
    import re
    with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), 'package.xml')) as f:
        return re.search(rf'<{tag}>([^<]+)</{tag}>', f.read()).group(1).strip()


def _config_files():
    out = {}
    for path in glob('config/**/*', recursive=True):
        if os.path.isfile(path):
            dest = os.path.join('share', package_name, os.path.dirname(path))
            out.setdefault(dest, []).append(path)
    return sorted(out.items())


setup(
    name=package_name,
    version=_package_xml('version'),
    packages=find_packages(exclude=['test']),
    # recording/msg: bundled .msg/.json definitions (tf2_msgs/TFMessage) for recordings without tf2_msgs;
    # data/example-robot-data: the three robots the bundled scenes a1_stand, solo12_drop, xarm7_trajectory need
    # (URDFs, the STL meshes solo12's URDF names, example-robot-data's licence; 1.6 MB; meshes.resolve_uri finds them)
    package_data={package_name: ['data/*', 'recording/msg/*/msg/*', 'data/example-robot-data/**/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ] + _config_files(),
    # numba: compiled kernels (robodyn_ros.kernels); pip-only (no rosdep key), optional at run time:
    # without it ArmSystem falls back to the numpy reference kernels
    # mcap-ros2-support decodes recordings for check/plot/resim; numba compiles the kernels;
    # dask + distributed run `robodyn sweep` (and the precision ladder) on a local or remote cluster,
    # pyarrow writes its Parquet table; URDF files are read with the standard library (robodyn_ros.urdf);
    # yourdfpy is a test oracle only; websockets serves runs live to Foxglove (robodyn_ros.live: imported
    # only with robodyn run --live or the node's foxglove_port)
    install_requires=['setuptools', 'numpy', 'scipy', 'PyYAML', 'mcap', 'mcap-ros2-support', 'numba',
                      'dask', 'distributed', 'pyarrow', 'websockets'],
    extras_require={
        'plot': ['matplotlib'],
        'test': ['pytest', 'pytest-xdist', 'pin', 'mujoco', 'rosbags', 'colcon-common-extensions', 'matplotlib', 'example-robot-data',
                 'yourdfpy'],
    },
    zip_safe=True,
    maintainer='robodyn_ros developers',
    maintainer_email='robodyn@example.com',
    description=_package_xml('description'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sim = robodyn_ros.nodes.sim:main',
            'robodyn = robodyn_ros.cli:main',
            'diver_controller = robodyn_ros.nodes.diver_controller:main',
            'pd_hold_controller = robodyn_ros.nodes.pd_hold_controller:main',
        ],
    },
)
