"""``robodyn check``: is a recording readable, what is in it, and do its invariants hold?"""
from __future__ import annotations

import json
import math
import sys

#: one line for ``robodyn --help``
HELP = 'read a recording: topics, counts, time range, invariants'


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('check', help=HELP)
    p.add_argument('file', help='MCAP recording')
    p.add_argument('--json', action='store_true', help='print the report as JSON')
    return p


def _nonfinite(msg, path=''):
    """Paths of non-finite floats inside a decoded message (mcap_ros2 objects or dicts)."""
    bad = []
    if isinstance(msg, float):
        return [path] if not math.isfinite(msg) else []
    if isinstance(msg, (list, tuple)):
        for k, x in enumerate(msg):
            bad += _nonfinite(x, f'{path}[{k}]')
        return bad
    if hasattr(msg, 'tolist') and not isinstance(msg, (str, bytes)):
        return _nonfinite(msg.tolist(), path)
    slots = getattr(msg, '__slots__', None) or (list(vars(msg)) if hasattr(msg, '__dict__') else [])
    for s in slots:
        bad += _nonfinite(getattr(msg, s), f'{path}.{s}' if path else s)
    return bad


def check_file(path) -> dict:
    """Summary of ``path`` plus invariant checks; ``report['ok']`` is the verdict.

    Invariants: the file finished cleanly; every message decodes; no non-finite number in
    any message; ``/clock`` never goes back; header stamps equal log times (sim-time stamping);
    log times within the recorded range.
    """
    import struct

    from mcap.exceptions import McapError

    from ..recording.reader import read_messages, summarize
    s = summarize(path)
    problems = []
    if not s['finished']:
        problems.append(f'not finished cleanly ({s["error"] or "no footer"}); '
                        f'{s["message_count"]} messages in {s["chunk_count"]} complete chunks recovered')
    decoded, nonfinite, clock_back, stamp_mismatch = 0, [], 0, 0
    last_clock = None
    try:
        for topic, _type, t_ns, msg in read_messages(path):
            decoded += 1
            bad = _nonfinite(msg)
            if bad:
                nonfinite.append(f'{topic} @ {t_ns} ns: {bad[:3]}')
            if topic.endswith('/clock') or topic == '/clock':
                c = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
                if last_clock is not None and c < last_clock:
                    clock_back += 1
                last_clock = c
            h = getattr(msg, 'header', None)
            if h is not None and (h.stamp.sec * 1_000_000_000 + h.stamp.nanosec) != t_ns:
                stamp_mismatch += 1
    except (McapError, ValueError, KeyError, IndexError, EOFError, struct.error) as e:
        problems.append(f'decoding stopped after {decoded} messages: {type(e).__name__}: {e}')
    if decoded != s['message_count']:
        problems.append(f'decoded {decoded} of {s["message_count"]} messages')
    if nonfinite:
        problems.append(f'{len(nonfinite)} messages contain non-finite numbers, e.g. {nonfinite[0]}')
    if clock_back:
        problems.append(f'/clock went backwards {clock_back} times')
    if stamp_mismatch:
        problems.append(f'{stamp_mismatch} header stamps differ from their log time (not sim-time stamped)')
    s.update(decoded=decoded, problems=problems, ok=not problems)
    return s


def main(args) -> int:
    """Print the report; exit 0 if readable and every invariant holds, 1 otherwise, 2 if unreadable."""
    try:
        rep = check_file(args.file)
    except (OSError, ValueError) as e:
        print(f'robodyn check: {args.file}: cannot read: {e}', file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(rep, indent=2, default=str))
        return 0 if rep['ok'] else 1
    t0, t1 = rep['start_time_ns'], rep['end_time_ns']
    md = rep['metadata'].get('robodyn', {})
    print(f'file         {rep["path"]}')
    print(f'status       {"finished" if rep["finished"] else "NOT finished"}, profile {rep["profile"]}, '
          f'{rep["message_count"]} messages, {rep["chunk_count"]} chunks')
    if t0 is not None:
        print(f'sim time     {t0 / 1e9:.6f} .. {t1 / 1e9:.6f} s')
    if md:
        print(f'scene        {md.get("scene_name", "?")} (robodyn_ros {md.get("package_version", "?")}), '
              f'settings {md.get("settings", "")}')
    print('topics')
    for name, tp in sorted(rep['topics'].items()):
        print(f'  {name:40s} {tp["type"]:36s} {tp["count"]:8d}')
    if rep['ok']:
        print('invariants   OK (decodes, finite, /clock monotonic, stamps = log times)')
        return 0
    for p in rep['problems']:
        print(f'PROBLEM      {p}')
    return 1
