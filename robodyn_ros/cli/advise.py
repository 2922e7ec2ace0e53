"""``robodyn advise SCENE --tolerance TOL``: the cheapest integrator setting that meets TOL (measured)."""
from __future__ import annotations

import sys

#: one line for ``robodyn --help``
HELP = 'which integrator and step/tolerance meet a tolerance at least cost'


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('advise', help=HELP,
                       description='Answers from work-precision measurements of the scene cached per scene and '
                                   'machine (robodyn bench precision); measures the quick ladder first when '
                                   'there are none (about a minute).')
    p.add_argument('scene', help='bundled scene name or path to a scene YAML file')
    p.add_argument('--tolerance', type=float, required=True,
                   help='largest acceptable final-state error (max_i |y_i - y_ref,i| / (1 + |y_ref,i|))')
    p.add_argument('--refresh', action='store_true', help='measure again even when cached')
    p.add_argument('--quiet', action='store_true', help='no progress bar while measuring')
    return p


def main(args) -> int:
    """Print the advice; 0 when a measured setting meets the tolerance, 1 when none does, 2 on bad input."""
    from ..advise import advise, format_advice
    from ..bench.precision import Progress, count_runs
    from ..scene import SceneError
    try:
        total = count_runs(args.scene, 'quick')
        adv = advise(args.scene, args.tolerance, refresh=args.refresh,
                     progress=Progress(total, quiet=args.quiet))
    except (SceneError, ValueError) as e:
        print(f'robodyn advise: {e}', file=sys.stderr)
        return 2
    print(format_advice(adv, args.scene))
    return 0 if adv.best is not None else 1
