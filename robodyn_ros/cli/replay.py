"""``robodyn replay``: publish a recording back onto its topics, paced by its simulation time.

Messages go out in file order on the topics and with the types they were recorded with; each
is published when wall time since the start reaches its log time (simulation time) divided by
``--rate``. ``/clock`` follows the log times: the recorded ``/clock`` messages when the file
has them, otherwise one generated per distinct log time, so subscribers with
``use_sim_time`` see the recording's time. Topics recorded transient-local
(``robot_description``, ``/tf_static``) are published transient-local again. A topic whose
message package is not installed here (``/tf`` without ``tf2_msgs``) is left out with a note,
or refused (exit 2) when asked for with ``--topics``.

The recorded bytes are canonical CDR, which is what DDS carries, so they are published as they
are (``Publisher.publish(bytes)``, as ``ros2 bag play`` does) after the recording reader has
checked that every message decodes; nothing is re-encoded on the way. rclpy is imported only
inside :func:`main`.
"""
from __future__ import annotations

import sys
import time

#: one line for ``robodyn --help``
HELP = 'publish a recording back onto its topics with /clock'
#: seconds --wait-subscribers waits on after the replay's publishers have each matched a subscriber: discovery
#: matches the two ends separately, and a subscriber that has not yet matched the replay drops a volatile
#: message (the first /joint_states and /clock were lost so once in a test run under load)
SETTLE = 0.25


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('replay', help=HELP)
    p.add_argument('input', help='MCAP recording')
    p.add_argument('--rate', type=float, default=1.0,
                   help='playback speed: simulated seconds per wall second (0 = as fast as possible)')
    p.add_argument('--topics', nargs='+', default=None, metavar='TOPIC',
                   help='replay only these topics (recorded names, e.g. /joint_states); /clock always follows')
    p.add_argument('--delay', type=float, default=0.5,
                   help='wall seconds to wait for subscribers to connect before the first message')
    p.add_argument('--wait-subscribers', action='store_true',
                   help='start once every replayed topic has a subscriber, and the subscribers have had '
                        f'{SETTLE:g} s to match the replay in turn (waiting at most --delay s)')
    return p


def _durability(offered_qos: str) -> str:
    return 'transient_local' if 'durability: transient_local' in (offered_qos or '') else 'volatile'


def plan(path, topics=None):
    """What a replay publishes: ``(topic -> (type, durability), clock_recorded)``.

    Raises ValueError if a requested topic is not in the recording.
    """
    from ..recording import summarize
    s = summarize(path)
    recorded = s['topics']
    if topics:
        missing = [t for t in topics if t not in recorded]
        if missing:
            raise ValueError(f'{path}: no topic {", ".join(missing)} in the recording; '
                             f'recorded: {", ".join(sorted(recorded))}')
        chosen = list(topics)
    else:
        chosen = sorted(recorded)
    out = {t: (recorded[t]['type'], _durability(recorded[t]['offered_qos_profiles'])) for t in chosen}
    return out, '/clock' in recorded, s


def main(args) -> int:
    """Publish the recording; return 0, or 2 if the file or options are unusable."""
    import importlib

    from .. import messages as M
    from ..recording import decode, read_raw_messages
    if args.rate < 0:
        print(f'robodyn replay: --rate must be >= 0, got {args.rate}', file=sys.stderr)
        return 2
    try:
        chosen, clock_recorded, summary = plan(args.input, args.topics)
    except (OSError, ValueError) as e:
        print(f'robodyn replay: {e}', file=sys.stderr)
        return 2
    if clock_recorded and '/clock' not in chosen:
        chosen['/clock'] = (M.TOPIC_TYPES['/clock'], 'volatile')

    def msg_class(type_name):
        pkg, _, name = type_name.split('/')
        return getattr(importlib.import_module(f'{pkg}.msg'), name)

    # a recording can hold types this machine cannot publish: /tf and /tf_static are recorded
    # even where tf2_msgs is not installed (the recorder bundles the TFMessage definition)
    missing = {}
    for topic, (type_name, _) in chosen.items():
        try:
            msg_class(type_name)
        except (ImportError, AttributeError):
            missing[topic] = type_name
    if missing:
        text = ', '.join(f'{t} ({ty}: package {ty.split("/")[0]} not installed)' for t, ty in missing.items())
        if args.topics:
            print(f'robodyn replay: cannot publish {text}', file=sys.stderr)
            return 2
        print(f'note: not replaying {text}; install it (e.g. ros-jazzy-tf2-msgs) to replay them')
        chosen = {t: v for t, v in chosen.items() if t not in missing}

    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node('robodyn_replay')
    published, status = 0, 0
    try:
        pubs = {}
        for topic, (type_name, durability) in chosen.items():
            qos = (QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                              reliability=ReliabilityPolicy.RELIABLE)
                   if durability == 'transient_local' else 10)
            pubs[topic] = node.create_publisher(msg_class(type_name), topic, qos)
        clock_pub = pubs.get('/clock') or node.create_publisher(msg_class(M.TOPIC_TYPES['/clock']), '/clock', 10)
        end = time.monotonic() + args.delay
        matched = None   # when every publisher had matched a subscriber
        while time.monotonic() < end:
            if args.wait_subscribers and matched is None and all(p.get_subscription_count() for p in pubs.values()):
                matched = time.monotonic()
            if matched is not None and time.monotonic() >= matched + SETTLE:
                break
            rclpy.spin_once(node, timeout_sec=min(0.05, max(end - time.monotonic(), 0.0)))
        wall0, t0, last_clock = time.monotonic(), None, None
        for topic, type_name, t_ns, raw in read_raw_messages(args.input, topics=set(chosen)):
            if t0 is None:
                t0 = t_ns
            if args.rate > 0:
                due = wall0 + (t_ns - t0) / 1e9 / args.rate
                while (wait := due - time.monotonic()) > 0:
                    rclpy.spin_once(node, timeout_sec=min(wait, 0.05))
            decode(type_name, raw)  # refuse to publish bytes that are not a valid message of the type
            if not clock_recorded and t_ns != last_clock:
                clock_pub.publish(M.fill(clock_pub.msg_type(), M.clock(t_ns)))
                last_clock = t_ns
            pubs[topic].publish(bytes(raw))
            published += 1
        # let reliable subscribers fetch the last messages before the publishers go away
        end = time.monotonic() + min(args.delay, 1.0)
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        status = 130
    except ValueError as e:
        print(f'robodyn replay: {args.input}: undecodable message: {e}', file=sys.stderr)
        status = 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    span = ((summary['end_time_ns'] or 0) - (summary['start_time_ns'] or 0)) / 1e9
    print(f'replayed {published} messages on {len(chosen)} topics ({span:.3f} s of simulation time'
          + (f' at x{args.rate:g}' if args.rate > 0 else ', unpaced') + ')')
    if not summary['finished']:
        print(f'note: {args.input} was not finished cleanly ({summary["error"]}); '
              f'replayed the {summary["message_count"]} messages of its complete chunks')
    return status
