"""``robodyn layout``: a Foxglove layout that fits a scene's robot or a recording (:mod:`robodyn_ros.layout`)."""
from __future__ import annotations

import os
import sys

#: one line for ``robodyn --help``
HELP = 'write a Foxglove layout for a scene or a recording (its joints, contacts, reactions)'


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('layout', help=HELP)
    p.add_argument('source', help='bundled scene name, scene YAML or URDF file, or a recording (IN.mcap)')
    p.add_argument('--out', default=None, help='layout file to write (default: print it)')
    p.add_argument('--live', action='store_true',
                   help='for a live run (robodyn run --live, the node\'s foxglove_port): add a Publish panel for '
                        'the first command topic')
    return p


def main(args) -> int:
    """Write (or print) the layout; exit 2 for a source that cannot be read."""
    import warnings

    from ..layout import layout_text, recording_info, scene_info
    try:
        if args.source.lower().endswith('.mcap'):
            if not os.path.isfile(args.source):
                raise ValueError(f'{args.source}: no such recording')
            info = recording_info(args.source)
        else:
            from ..scene import SceneError, load_scene
            try:
                with warnings.catch_warnings():   # what the scene's run would say; a layout needs none of it
                    warnings.simplefilter('ignore')
                    scene = load_scene(args.source)
            except SceneError as e:
                raise ValueError(str(e)) from None
            info = scene_info(scene)
    except (ValueError, OSError) as e:
        print(f'robodyn layout: {e}', file=sys.stderr)
        return 2
    text = layout_text(info, live=args.live)
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        with open(args.out, 'w') as f:
            f.write(text)
    except OSError as e:
        print(f'robodyn layout: {args.out}: {e.strerror or e}', file=sys.stderr)
        return 2
    print(f'{args.out}: Foxglove layout for {info.name} (Layouts > Import from file...)')
    return 0
