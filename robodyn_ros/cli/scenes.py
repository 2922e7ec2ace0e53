"""``robodyn scenes``: list the bundled scenes."""
from __future__ import annotations

#: one line for ``robodyn --help``
HELP = 'list the bundled scenes'


def add_parser(sub):
    """Register the subcommand."""
    return sub.add_parser('scenes', help=HELP)


def main(args) -> int:
    """Print one line per bundled scene: name and description."""
    from ..scene import list_scenes
    for name, description in list_scenes():
        print(f'{name:28s} {description.strip().splitlines()[0] if description.strip() else ""}')
    print('\nyour own robot (URDF): robodyn run robot.urdf --record run.mcap   or a scene part '
          '{kind: urdf, name: robot, file: robot.urdf}; ROS: sim --ros-args -p robot_description_file:=robot.urdf')
    return 0
