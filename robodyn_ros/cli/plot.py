"""``robodyn plot``: one PNG of stacked panels chosen from what a recording contains."""
from __future__ import annotations

import sys

#: one line for ``robodyn --help``
HELP = 'plot a recording to PNG (panels chosen from its topics)'


def add_parser(sub):
    """Register the subcommand and its options."""
    from ..plotting import PANELS
    p = sub.add_parser('plot', help=HELP,
                       description='Plot a recording to one PNG of stacked panels. With --panels auto '
                                   '(the default) every panel the recording has data for is drawn.')
    p.add_argument('file', help='MCAP recording')
    p.add_argument('--out', default=None, help='PNG to write (default: the recording with .png)')
    p.add_argument('--panels', default='auto',
                   help=f'auto, or a comma-separated list drawn in that order, from: {", ".join(PANELS)}')
    p.add_argument('--title', default=None, help='figure title (default: scene, file, integrator, time range)')
    return p


def main(args) -> int:
    """Write the PNG and print its path.

    Exit 0 when written; 1 when nothing can be plotted (no known topic, none of the requested
    panels has data) or matplotlib is missing; 2 on bad input (unknown panel name, missing or
    non-MCAP file) or when the PNG cannot be written.
    """
    from ..plotting import PlotError, UnreadableRecording, parse_panels, plot_recording
    try:
        panels = parse_panels(args.panels)
    except PlotError as e:
        print(f'robodyn plot: {e}', file=sys.stderr)
        return 2
    try:
        out, _chosen, skipped = plot_recording(args.file, out=args.out, panels=panels, title=args.title)
    except UnreadableRecording as e:
        print(f'robodyn plot: {e}', file=sys.stderr)
        return 2
    except PlotError as e:
        print(f'robodyn plot: {e}', file=sys.stderr)
        return 1
    except OSError as e:
        print(f'robodyn plot: {e}', file=sys.stderr)
        return 2
    for p in skipped:
        print(f'robodyn plot: note: no data for panel {p!r} in {args.file}; left out', file=sys.stderr)
    print(out)
    return 0
