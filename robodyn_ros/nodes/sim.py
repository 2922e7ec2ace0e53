"""``sim``: the simulation node, a thin adapter between ROS topics/parameters and the Simulator.

Run it as ``sim --ros-args -p scene:=stanford_arm -p mode:=lockstep -p record:=run.mcap`` (or
``ros2 run robodyn_ros sim ...``). Interface (GUIDE §2, all names relative to the namespace
except ``/clock``): one command subscription per input port of the scene's system
(``effort_commands``, ``wheel_voltage_commands``, ``base_wrench_command``); publishes
``joint_states``, ``odom`` (systems with a base), ``constraint_wrenches/<joint>``,
``contact_wrenches/<link>`` (on a ground),
``robot_description`` (transient local), ``/tf`` and ``/tf_static`` (transient local; when
``tf2_msgs`` is importable and ``publish_tf`` is true), ``/clock``, ``diagnostics``; services
``~/reset`` (std_srvs/Trigger) and ``~/pause`` (std_srvs/SetBool). Parameters: see
:data:`PARAMETERS`. The recording holds what is published, with one exception: without
``tf2_msgs`` the node cannot publish TF but still records it (the bundled TFMessage definition
encodes it), so that the recording shows the robot moving in Foxglove.

Time is cut into control periods of ``1 / publish_rate`` seconds. A period is: scripted
commands (if any), ``Simulator.advance`` to the period's end, outputs, publish (and record). A
command received from a topic is applied at the current simulation time, i.e. at a period
boundary, in every mode; that is what makes every recording re-simulate exactly
(``robodyn resim``). Modes differ only in *when* periods run:

- ``realtime``: whenever simulation time lags wall time x ``rate_factor`` (catching up after a
  slow period, re-anchoring if more than ``max_lag`` s behind);
- ``max``: back to back, answering callbacks every :data:`MAX_MODE_SLICE` s of wall time;
- ``lockstep``: one period per received command message, then publish (deterministic: the
  trajectory does not depend on the machine's speed).
"""
from __future__ import annotations

import math
import os
import signal
import sys
import time
import warnings

import numpy as np

from .. import messages as M
from ..recording import cdr
from ..recording.run_sink import output_records
from ..recording.target import episode_path
from ..runs import StopSignals
from ..simulation import CommandError, SimulationError, Simulator
from .config import PARAMETERS, ConfigError, check_backend, check_live, check_number, resolve_config, urdf_options
from .ports import command_topics, command_values

NODE_NAME = 'robodyn_sim'
#: wall seconds of simulation work between executor spins in ``max`` mode (service latency)
MAX_MODE_SLICE = 0.01
#: wall seconds between spins when there is nothing to simulate (paused, failed, lockstep idle)
IDLE_SPIN = 0.05
#: wall seconds between re-sends of the initial state to new subscribers in lockstep (see README)
LOCKSTEP_RESEND_PERIOD = 0.1
#: wall seconds between diagnostics while simulation time stands still (paused, failed, idle)
IDLE_DIAGNOSTICS_PERIOD = 1.0
#: wall seconds between throttled repeats of the same warning or error
LOG_THROTTLE = 2.0
#: wall seconds the node keeps spinning after its last period (duration or stop_when reached), so
#: that the last published state reaches subscribers (a lockstep controller) before it exits
FINISH_LINGER = 0.3

def _finite_outputs(out) -> bool:
    """True when everything about to be published is finite (one isfinite over all the numbers)."""
    arrays = [out.position, out.velocity, out.effort] + [w for _, w in out.wrenches.values()] + \
        [w for _, w in out.contacts.values()]
    if out.odom is not None:
        arrays += list(out.odom.values())
    return bool(np.isfinite(np.concatenate([np.asarray(a, dtype=float).reshape(-1) for a in arrays])).all())


def _import_msg(type_name: str):
    """The rclpy message class of ``pkg/msg/Type``."""
    import importlib
    pkg, _, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


def make_node_class():
    """Build the node class (rclpy is imported here, so importing this module needs no ROS)."""
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_srvs.srv import SetBool, Trigger

    class SimNode(Node):
        """The simulation node; construction validates parameters and loads the scene.

        Drive it with :meth:`work` between executor spins (see :func:`main`); :attr:`finished`
        turns True when ``duration`` is reached; :meth:`close` finishes the recording.
        """

        def __init__(self, **kwargs):
            super().__init__(NODE_NAME, **kwargs)
            from ..scene import load_scene
            raw = {}
            for name, (default, text) in PARAMETERS.items():
                desc = ParameterDescriptor(description=text, dynamic_typing=True)
                raw[name] = self.declare_parameter(name, default, desc).value
            urdf_file = raw['robot_description_file']
            if not isinstance(urdf_file, str) or (urdf_file and not urdf_file.lower().endswith('.urdf')):
                raise ConfigError(f"parameter 'robot_description_file' must be the path of a .urdf file, "
                                  f"got {urdf_file!r}")
            if not isinstance(raw['scene'], str):
                raise ConfigError(f"parameter 'scene' must be a scene name or path, got {raw['scene']!r}")
            self.live = None   # the live server's pieces (_start_live), when foxglove_port is set
            self._live_sock = self._bind_live(raw)   # a port in use is refused before the scene loads
            # scene:='' without a URDF file: the robot is the URDF another node publishes
            self.external_description = not raw['scene'] and not urdf_file
            urdf_opts = urdf_options(raw)   # command_interface, sensors: for a URDF robot
            if not (urdf_file or self.external_description) and any(v is not None for v in urdf_opts.values()):
                raise ConfigError("parameters 'command_interface' and 'sensors' apply to a URDF robot "
                                  "(robot_description_file, or scene:=''); a scene file gives command_interfaces "
                                  'on its part and a sensors list')
            from ..systems.base import backend_scope
            with backend_scope(check_backend(raw['backend'])):
                if self.external_description:
                    from ..scene import SceneError, parse_scene, urdf_scene_text
                    text = self._read_robot_description(check_number('robot_description_timeout',
                                                                raw['robot_description_timeout'], positive=True))
                    try:
                        self.scene = parse_scene(urdf_scene_text(text=text, **urdf_opts), file='robot_description')
                    except SceneError as e:
                        raise ConfigError(f'the URDF on robot_description cannot be simulated: {e}') from None
                elif urdf_file:
                    self.scene = load_scene(urdf_file, **urdf_opts)
                else:
                    self.scene = load_scene(raw['scene'])
            self.cfg = cfg = resolve_config(raw, self.scene)
            self.namespace = self.get_namespace()
            try:
                self.sim = Simulator(self.scene.system, cfg.y0, plan=cfg.plan, command_timeout=cfg.command_timeout)
            except (ValueError, SimulationError) as e:
                raise ConfigError(f'cannot build the simulator: {e}') from None
            self.period = 1.0 / cfg.publish_rate   # s of simulation time per control period
            self.paused = cfg.start_paused
            self._paused_wall = 0.0   # wall seconds spent paused (left out of the summary's wall time)
            self.finished = False
            self.episode = 0
            self.recorders = []       # every McapRunSink opened (one per episode)
            self.recorder = None
            self._timed_out_warned = set()
            self._last_logged = {}
            self._start_period_clock()

            # -- publishers: state topics known from one output at the initial state
            out0 = self.sim.outputs(wrenches=True)
            self.pub = {'joint_states': self._publisher('joint_states'),
                        '/clock': self._publisher('/clock'),
                        'diagnostics': self._publisher('diagnostics')}
            if out0.odom is not None:
                self.pub['odom'] = self._publisher('odom')
            self.wrench_pubs = {}
            for name in out0.wrenches:
                topic = M.wrench_topic(name)
                self.wrench_pubs[topic] = self.create_publisher(_import_msg(M.WRENCH_TYPE), topic, 10)
            self.pub.update(self.wrench_pubs)
            for link in out0.contacts:   # the ground's wrench on each link that has contact points
                topic = M.contact_topic(link)
                self.pub[topic] = self.create_publisher(_import_msg(M.WRENCH_TYPE), topic, 10)
            self._control_publishers(out0)
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                                 reliability=ReliabilityPolicy.RELIABLE)
            self.description = M.string(self.scene.system.urdf())
            if not self.external_description:  # else the node that published it owns the topic
                self.pub['robot_description'] = self.create_publisher(
                    _import_msg(M.TOPIC_TYPES['robot_description']), 'robot_description', latched)
            self.tf = None   # the TfTree of /tf (published and recorded) when publish_tf
            if cfg.publish_tf:
                from ..tf import TfTree
                self.tf = TfTree(self.scene.system)
                try:
                    tf_msg = _import_msg(M.TOPIC_TYPES['/tf'])
                except ImportError:
                    self.get_logger().info('tf2_msgs is not installed: /tf and /tf_static are not published '
                                           '(recordings still carry them)')
                else:   # tf2's broadcaster QoS: depth 100 for /tf, latched depth 1 for /tf_static
                    self.pub['/tf'] = self.create_publisher(tf_msg, '/tf', 100)
                    self.pub['/tf_static'] = self.create_publisher(tf_msg, '/tf_static', latched)

            # -- command subscriptions, one per input port (none with scripted commands)
            self.subs = []
            if not cfg.scripted_commands:
                for port, (topic, type_name) in command_topics(self.scene.system).items():
                    if self.scene.system.inputs[port].kind == 'vector' and not self.scene.system.inputs[port].size:
                        continue   # a port with nothing to command (an arm whose joints all take positions)
                    self.subs.append(self.create_subscription(
                        _import_msg(type_name), topic, lambda msg, port=port: self._on_command(port, msg), 10))

            self.create_service(Trigger, '~/reset', self._on_reset)
            self.create_service(SetBool, '~/pause', self._on_pause)

            # -- start: description, recording, initial state at t0
            if 'robot_description' in self.pub:
                self.pub['robot_description'].publish(M.fill(self.pub['robot_description'].msg_type(),
                                                             self.description))
            if '/tf_static' in self.pub:
                static = self.tf.static_message(M.to_ns(self.sim.t))
                if static['transforms']:
                    self.pub['/tf_static'].publish(M.fill(self.pub['/tf_static'].msg_type(), static))
            self._tf_layouts = {}
            self._publish_command_joint_names(latched)
            self._markers_setup()
            self._start_live()
            self._refresh_subscribers()
            self._open_recording()
            self._commanded = False     # lockstep: a command has arrived since the last (re)start
            # lockstep: joint_states subscriber count at the last (re)send of the initial state; 0 so
            # that a subscriber matched just after the first publication still gets the state
            self._resend_subs = 0
            self._next_resend = 0.0
            self._next_idle_diag = time.monotonic() + IDLE_DIAGNOSTICS_PERIOD
            self._publish_initial_state()
            self.get_logger().info(
                f'scene {self.scene.name}: {cfg.integrator} '
                + (f'dt={cfg.dt:g} s' if cfg.dt else '') + (' ' if cfg.dt and cfg.rtol else '')
                + (f'rtol={cfg.rtol:g} atol={cfg.atol:g}' if cfg.rtol else '')
                + f', {cfg.publish_rate:g} Hz, mode {cfg.mode}'
                + (f' x{cfg.rate_factor:g}' if cfg.mode == 'realtime' else '')
                + (', scripted commands' if cfg.scripted_commands else
                   f', commands on {", ".join(t for t, _ in command_topics(self.scene.system).values())}')
                + (f', recording to {self.recorder.path}' if self.recorder and self.recorder.path else '')
                + (f', live on {self.live.server.url}' if self.live else '')
                + (f' ({cfg.auto})' if cfg.auto else ''))
            # the run (real-time schedule, summary wall time) starts now, after the set-up
            self._wall_start = self._anchor_wall = self._rtf_wall = self._pause_began = time.monotonic()
            self._cpu_start = time.process_time()   # CPU of the run (paused spinning costs next to none)

        # -- command interfaces, servo and sensors (robodyn_ros.systems.servo, .sensors) ---------
        def _control_publishers(self, out0):
            """Publishers of the further messages of each output (a servo's desired and error states, the
            sensors' readings: ``SystemOutputs.messages``), known from the initial output."""
            for topic, type_name, _ in out0.messages:
                self.pub[topic] = self.create_publisher(_import_msg(type_name), topic, 10)

        def _publish_command_joint_names(self, latched):
            """Latch ``command_joint_names`` (std_msgs/String: one line ``<topic>: [joints]`` per joint command
            topic, in that topic's order) and log it, when the scene has position or velocity commands."""
            sys_ = self.scene.system
            self.command_joint_names = None
            if not any(p in sys_.inputs for p in ('position', 'velocity')):
                return
            self.command_joint_names = M.string(M.command_joint_names(sys_))
            pub = self.create_publisher(_import_msg(M.TOPIC_TYPES['command_joint_names']), 'command_joint_names',
                                        latched)
            self.pub['command_joint_names'] = pub
            pub.publish(M.fill(pub.msg_type(), self.command_joint_names))
            self.get_logger().info('command joints (command_joint_names):\n' + self.command_joint_names['data'])

        # -- set-up helpers -------------------------------------------------------------------
        def _read_robot_description(self, timeout: float) -> str:
            """The URDF text on ``robot_description`` (transient local: a robot_state_publisher's),
            waiting up to ``timeout`` wall seconds; ConfigError if none arrives."""
            import rclpy
            got = []
            qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
            sub = self.create_subscription(_import_msg(M.TOPIC_TYPES['robot_description']), 'robot_description',
                                           lambda msg: got.append(msg.data), qos)
            end = time.monotonic() + timeout
            while not got and time.monotonic() < end:
                rclpy.spin_once(self, timeout_sec=0.05)
            self.destroy_subscription(sub)
            if not got:
                raise ConfigError(f"scene:='' and no robot_description_file: no URDF arrived on robot_description "
                                  f'within {timeout:g} s (robot_description_timeout)')
            return got[-1]

        def _publisher(self, topic):
            return self.create_publisher(_import_msg(M.TOPIC_TYPES[topic]), topic, 10)

        def _start_period_clock(self):
            """(Re)start the period counter at the current simulation time and the realtime anchor."""
            self.t_start = self.sim.t
            self.k = 0
            self._anchor_wall = time.monotonic()
            self._anchor_sim = self.sim.t
            self._rtf_wall, self._rtf_sim = self._anchor_wall, self.sim.t
            self.rtf = float('nan')
            self._next_diag = self.sim.t

        def _open_recording(self):
            """The run's encoder: an MCAP file (``record``), and the live viewers' stream (``foxglove_port``):
            the same records to both. Neither: no recorder."""
            if not self.cfg.record and self.live is None:
                return
            from ..recording.run_sink import NODE_CHUNK_SPAN, McapRunSink
            path = None
            if self.cfg.record:
                path = episode_path(self.cfg.record, self.episode)
                os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            self.recorder = McapRunSink(path, self.scene, self.cfg.settings(self.namespace),
                                        record_wrenches=True, diagnostics_period=self.cfg.diagnostics_period,
                                        namespace=self.namespace.strip('/'), record_tf=self.cfg.publish_tf,
                                        chunk_span=NODE_CHUNK_SPAN, embed_meshes=self.cfg.embed_meshes,
                                        taps=() if self.live is None else (self.live.tap,))
            self.recorders.append(self.recorder)
            self.recorder.on_start(self.sim)

        def _record(self, topic, type_name, msg, t_ns):
            """Write one published message dict to the recording (same dict as published)."""
            from ..recording.run_sink import resolve
            r = self.recorder
            r.writer.write(resolve(topic, r.namespace), type_name, msg, t_ns)
            r.count += 1

        def _refresh_subscribers(self):
            """Note which publishers have subscribers (asked once per work() call, not per message:
            a new subscriber is served from the next executor spin on)."""
            self._subscribed = {topic: pub.get_subscription_count() > 0 for topic, pub in self.pub.items()}
            self._wrench_subscribed = any(self._subscribed[t] for t in self.wrench_pubs)

        def _wrenches_wanted(self) -> bool:
            return self.recorder is not None or self._wrench_subscribed

        # -- commands -------------------------------------------------------------------------
        def _on_command(self, port, msg):
            """A command message: validate, hold (zero-order) and record; in lockstep run one period."""
            try:
                try:
                    values = command_values(port, msg)
                except CommandError:
                    self.sim.ports[port].rejected += 1   # refused before reaching the simulator
                    raise
                self.sim.set_command(port, values)
            except CommandError as e:
                self._log_throttled('error', str(e), f'command rejected ({self.sim.rejected_commands} so far), '
                                                     f'last valid command stays: {e}')
            else:
                self._timed_out_warned.discard(port)
                if self.recorder is not None:
                    self.recorder.on_command(self.sim.t, port, self.sim.ports[port].value)
            if self.cfg.mode == 'lockstep':
                self._commanded = True
                if self._can_advance():
                    self._refresh_subscribers()
                    self._run_period()

        def _publish_initial_state(self):
            """Publish the state at the start of a run (or after ~/reset). With scripted commands the
            first period's command is set first, so that joint_states at t0 carries the effort
            applied from t0 on (as run_headless does); from topics, it is the command in force."""
            if self.cfg.scripted_commands:
                self._apply_script()
            self._publish_outputs(self.sim.outputs(wrenches=self._wrenches_wanted()))

        def _apply_script(self):
            for port, values in self.scene.script(self.sim.t, self.sim.y).items():
                self.sim.set_command(port, values)
                if self.recorder is not None:
                    self.recorder.on_command(self.sim.t, port, self.sim.ports[port].value)

        # -- one control period ---------------------------------------------------------------
        def _can_advance(self) -> bool:
            return not (self.paused or self.finished or self.sim.failed)

        def _run_period(self) -> bool:
            """Scripted commands, advance one period, publish; False (and failed) on a simulation error."""
            sim = self.sim
            try:
                if self.cfg.scripted_commands and self.k > 0:   # period 0's: set with the initial state
                    self._apply_script()
                # same arithmetic as run_headless, so period ends are bit-identical to a headless run
                sim.advance(self.t_start + (self.k + 1) / self.cfg.publish_rate)
                out = sim.outputs(wrenches=self._wrenches_wanted())
                if not _finite_outputs(out):
                    sim.failed = f'non-finite outputs at t={sim.t:.6f} s; nothing published'
                    raise SimulationError(sim.failed)
            except (SimulationError, CommandError) as e:
                self._fail(e)
                return False
            self.k += 1
            self._warn_timeouts()
            self._publish_outputs(out)
            if self.cfg.duration and sim.t - self.t_start >= self.cfg.duration - 0.5 * self.period:
                self.finished = True
            if self.scene.stop is not None and self.scene.stop(sim.t, sim.y):   # the scene's stop_when
                self.finished = True
            return True

        def _log_throttled(self, level: str, key: str, text: str):
            """Log ``text`` unless the same ``key`` was logged less than LOG_THROTTLE s ago.

            Throttled per message rather than per call site, so a NaN command is still reported
            right after a wrong-length one.
            """
            now = time.monotonic()
            if now - self._last_logged.get(key, -math.inf) < LOG_THROTTLE:
                return
            if len(self._last_logged) > 100:
                self._last_logged.clear()
            self._last_logged[key] = now
            getattr(self.get_logger(), level)(text)

        def _warn_timeouts(self):
            for port, p in self.sim.ports.items():
                if p.timed_out and port not in self._timed_out_warned:
                    self._timed_out_warned.add(port)
                    self.get_logger().warning(
                        f'no {M.PORT_TOPICS.get(port, port)} for {self.cfg.command_timeout:g} s of simulation '
                        f'time: {port} set to zero until the next command', throttle_duration_sec=LOG_THROTTLE)

        def _fail(self, err):
            """Stop advancing: log the cause and the last good state, publish an ERROR diagnostic."""
            sim = self.sim
            if not sim.failed:
                sim.failed = str(err)
            self.get_logger().error(
                f'simulation stopped at t={sim.t:.6f} s: {err}; last good state y={sim.y.tolist()}; '
                f'still serving ~/reset and ~/pause')
            self._publish_diagnostics(record=True)

        # -- publication ----------------------------------------------------------------------
        def _publish_outputs(self, out):
            """State messages, /clock and (every diagnostics_period) diagnostics of one period.

            The state messages are encoded once, to canonical CDR (the bytes the recorder writes,
            :func:`robodyn_ros.recording.run_sink.output_records`), and published as serialized
            messages; only the topics with a subscriber (or all, when recording) are built.
            """
            t_ns = M.to_ns(self.sim.t)
            rec = self.recorder
            subscribed = self._subscribed
            want = None if rec is not None else subscribed.get
            for topic, type_name, data in output_records(t_ns, out, bool(out.wrenches), self.tf, want,
                                                         self._tf_layouts):
                if subscribed.get(topic):
                    self.pub[topic].publish(data)
                if rec is not None:
                    rec._write_data(topic, type_name, data, t_ns)
            if rec is not None or subscribed.get('/clock'):
                data = cdr.clock_bytes(*divmod(t_ns, 1_000_000_000))
                if subscribed.get('/clock'):
                    self.pub['/clock'].publish(data)
                if rec is not None:
                    rec._write_data('/clock', M.TOPIC_TYPES['/clock'], data, t_ns)
            self._publish_markers(out, t_ns)
            self._last_extra = out.extra
            if self.sim.t >= self._next_diag - 1e-9:
                self._publish_diagnostics(record=True)
                self._next_diag += self.cfg.diagnostics_period

        def _status(self):
            if self.sim.failed:
                return 2, f'stopped: {self.sim.failed}'
            if self.paused:
                return 0, 'paused'
            if self.finished:
                return 0, 'finished'
            lag = (self.cfg.mode == 'realtime' and math.isfinite(self.rtf)
                   and self.rtf < 0.95 * self.cfg.rate_factor)
            timed_out = [p for p, s in self.sim.ports.items() if s.timed_out]
            if lag:
                return 1, f'cannot keep real time: real-time factor {self.rtf:.3f} < {self.cfg.rate_factor:g}'
            if timed_out:
                return 1, f'command timeout: {", ".join(timed_out)} held at zero'
            return 0, 'running'

        def _publish_diagnostics(self, record: bool):
            """Diagnostics of the simulator, the system's extra values and the node (rate, mode).

            record: also record it (the regular ones every diagnostics_period of simulation time,
            and state changes); the real-time factor window spans two regular ones.
            """
            now = time.monotonic()
            if record and now > self._rtf_wall and self.sim.t > self._rtf_sim:
                self.rtf = (self.sim.t - self._rtf_sim) / (now - self._rtf_wall)
                self._rtf_wall, self._rtf_sim = now, self.sim.t
            values = self.sim.diagnostics_values(wall_clock=True)
            values.update(getattr(self, '_last_extra', {}) or {})
            values.update({'mode': self.cfg.mode, 'rate_factor_target': self.cfg.rate_factor,
                           'real_time_factor': self.rtf,
                           'real_time_factor_overall': ((self.sim.t - self._anchor_sim) /
                                                        max(now - self._anchor_wall, 1e-9)),
                           'publish_rate': self.cfg.publish_rate, 'paused': self.paused,
                           'episode': self.episode})
            level, message = self._status()
            t_ns = M.to_ns(self.sim.t)
            msg = M.diagnostic_array(t_ns, 'robodyn_ros: simulation', level, message, values)
            pub = self.pub['diagnostics']
            pub.publish(M.fill(pub.msg_type(), msg))
            if record and self.recorder is not None:
                self._record('diagnostics', M.TOPIC_TYPES['diagnostics'], msg, t_ns)
            self._next_idle_diag = now + IDLE_DIAGNOSTICS_PERIOD

        # -- services -------------------------------------------------------------------------
        def _on_reset(self, request, response):
            """Back to the initial state at time 0; the recording continues in a new file."""
            self.sim.reset()
            self._timed_out_warned.clear()
            self.finished = False
            if self.recorder is not None:
                self.recorder.close()
                self.episode += 1
                self._open_recording()
            else:
                self.episode += 1
            self._start_period_clock()
            self._commanded = False
            self._resend_subs = 0
            self._refresh_subscribers()
            self._publish_initial_state()
            response.success = True
            response.message = (f'reset to the initial state at t={self.sim.t:g} s'
                                + (f'; recording continues in {self.recorder.path}'
                                   if self.recorder and self.recorder.path else ''))
            self.get_logger().info(response.message)
            return response

        def _on_pause(self, request, response):
            """Pause (data=true) or resume (false) simulation time; commands are still held."""
            was = self.paused
            self.paused = bool(request.data)
            now = time.monotonic()
            if self.paused and not was:
                self._pause_began = now
            if was and not self.paused:
                self._paused_wall += now - self._pause_began
                self._anchor_wall, self._anchor_sim = now, self.sim.t
                self._rtf_wall, self._rtf_sim = self._anchor_wall, self.sim.t
                if self.cfg.mode == 'lockstep':
                    self._resend_state()
            response.success = True
            response.message = f'{"paused" if self.paused else "running"} at t={self.sim.t:g} s'
            self.get_logger().info(response.message)
            self._publish_diagnostics(record=False)
            return response

        def _resend_state(self):
            """Publish the current state again (not recorded: same time, same bytes) for new listeners."""
            if self.sim.failed:
                return
            out = self.sim.outputs(wrenches=bool(self.wrench_pubs) and self._wrenches_wanted())
            t_ns = M.to_ns(self.sim.t)
            for topic, _type, msg in M.output_messages(t_ns, out, wrenches=bool(out.wrenches), tf=self.tf):
                pub = self.pub.get(topic)
                if pub is not None:
                    pub.publish(M.fill(pub.msg_type(), msg))
            self.pub['/clock'].publish(M.fill(self.pub['/clock'].msg_type(), M.clock(t_ns)))

        # -- the loop body ----------------------------------------------------------------------
        def work(self) -> float:
            """Run the periods that are due now; return how long (s) the executor may wait for callbacks."""
            now = time.monotonic()
            mode = self.cfg.mode
            self._refresh_subscribers()
            if now >= self._next_idle_diag and (mode == 'lockstep' or not self._can_advance()):
                self._publish_diagnostics(record=False)   # simulation time stands still: say why
            if not self._can_advance():
                return IDLE_SPIN
            if mode == 'lockstep':
                if not self._commanded and now >= self._next_resend:
                    # until the first command, (re)send the initial state to each new subscriber
                    n = self.pub['joint_states'].get_subscription_count()
                    if n > self._resend_subs:
                        self._resend_state()
                    self._resend_subs = n
                    self._next_resend = now + LOCKSTEP_RESEND_PERIOD
                return IDLE_SPIN
            if mode == 'max':
                while time.monotonic() - now < MAX_MODE_SLICE:
                    if not self._run_period() or self.finished:
                        break
                return 0.0
            # realtime: simulation time follows wall time x rate_factor from the anchor
            rf = self.cfg.rate_factor
            while True:
                now = time.monotonic()
                target = self._anchor_sim + (now - self._anchor_wall) * rf
                next_end = self.t_start + (self.k + 1) / self.cfg.publish_rate
                if next_end > target:
                    return min(max((next_end - target) / rf, 0.0), IDLE_SPIN)
                if (target - next_end) / rf > self.cfg.max_lag:
                    self.get_logger().warning(
                        f'{(target - next_end) / rf:.3f} s behind real time x{rf:g}; skipping ahead '
                        '(lower rate_factor or publish_rate, or use mode max)',
                        throttle_duration_sec=LOG_THROTTLE)
                    self._anchor_wall = now - (self.t_start + self.k / self.cfg.publish_rate - self._anchor_sim) / rf
                if not self._run_period() or self.finished:
                    return 0.0

        # -- markers (recording.markers): contact points and forces, sensors ---------------------
        def _markers_setup(self):
            """The ``markers`` publisher when the system draws markers (a ground, sensors), else nothing."""
            from ..recording.markers import TOPIC, TYPE, Markers
            self.markers = Markers.of(self.scene.system)
            if self.markers is not None:
                try:
                    self.pub[TOPIC] = self.create_publisher(_import_msg(TYPE), TOPIC, 10)
                except ImportError:   # as /tf without tf2_msgs: recorded (and live), not published
                    self.get_logger().info('visualization_msgs is not installed: markers are not published '
                                           '(recordings still carry them)')

        def _publish_markers(self, out, t_ns):
            """The period's MarkerArray (the recorder's bytes) to its subscribers and the recording."""
            if self.markers is None:
                return
            from ..recording.markers import TOPIC, TYPE, MarkerInputs
            rec = self.recorder
            if rec is None and not self._subscribed.get(TOPIC):
                return
            data = self.markers.message(t_ns, MarkerInputs.of_outputs(out))
            if self._subscribed.get(TOPIC):
                self.pub[TOPIC].publish(data)
            if rec is not None:
                rec._write_data(TOPIC, TYPE, data, t_ns)

        # -- live: a Foxglove WebSocket server (robodyn_ros.live) ---------------------------------
        def _bind_live(self, raw):
            """The listening socket of ``foxglove_port`` (None when 0), or ConfigError (port in use)."""
            host, port = check_live(raw)
            if not port:
                return None
            from ..live.server import LivePortError, bind
            try:
                return bind(host, port)
            except LivePortError as e:
                raise ConfigError(f"parameter 'foxglove_port': {e}") from None

        def _start_live(self):
            """Serve the run: the server on its thread; client requests wake the executor (a guard
            condition) and are taken in :meth:`_take_live`, between two periods."""
            if self._live_sock is None:
                return
            from types import SimpleNamespace

            from ..live.server import LiveServer, LiveTap
            from ..live.steering import RATE_FACTOR, Steering, service_set
            from ..recording.run_sink import resolve
            ns = self.namespace.strip('/')
            commands = {} if self.cfg.scripted_commands else {
                resolve(topic, ns): (port, t) for port, (topic, t) in command_topics(self.scene.system).items()}
            gc = self.create_guard_condition(self._take_live)
            steering = Steering(commands, command_values, wake=gc.trigger)
            server = LiveServer(self._live_sock, f'robodyn_ros {NODE_NAME}: {self.scene.name}', steering,
                                services=service_set(self.get_fully_qualified_name() + '/'),
                                parameters={RATE_FACTOR: self.cfg.rate_factor}).start()
            steering.advertise(server)
            self.live = SimpleNamespace(server=server, steering=steering, tap=LiveTap(server), guard=gc)

        def _take_live(self):
            """Apply the clients' requests as their ROS counterparts: commands through the command ports'
            checks (:meth:`_on_command`), reset and pause through the services, rate_factor."""
            from types import SimpleNamespace

            from ..live.server import Publish, ServiceCall, SetParameter
            from ..live.steering import RATE_FACTOR, RefusedCommand, set_bool_data, trigger_response
            live = self.live
            for req in live.steering.take():
                if isinstance(req, Publish):
                    try:
                        got = live.steering.command(req)
                    except RefusedCommand as e:
                        self.sim.ports[e.port].rejected += 1
                        self._log_throttled('error', str(e), f'command rejected ({self.sim.rejected_commands} so far), '
                                                             f'last valid command stays: {e}')
                        live.server.status(req.client, 2, f'robodyn_ros: command rejected: {e}')
                        continue
                    if got is None:
                        takes = ', '.join(live.steering.commands) or 'none'
                        live.server.status(req.client, 1, f'robodyn_ros: {req.topic} is not a command topic of this '
                                                          f'node (it takes {takes})')
                        continue
                    before = self.sim.rejected_commands
                    self._on_command(*got)
                    if self.sim.rejected_commands > before:
                        live.server.status(req.client, 2, f'robodyn_ros: command on {req.topic} rejected '
                                                          f'({self.sim.rejected_commands} so far); see the node log')
                elif isinstance(req, ServiceCall):
                    response = SimpleNamespace(success=False, message='')
                    try:
                        if req.service.endswith('/reset'):
                            self._on_reset(None, response)
                        else:
                            self._on_pause(SimpleNamespace(data=set_bool_data(req.payload)), response)
                    except ValueError as e:
                        response.message = f'{req.service}: {e}'
                    req.reply(trigger_response(response.success, response.message))
                elif isinstance(req, SetParameter):
                    value = req.value
                    if req.name != RATE_FACTOR or isinstance(value, bool) or not isinstance(value, (int, float)) \
                            or not math.isfinite(value) or value <= 0:
                        req.reply(self.cfg.rate_factor, f"robodyn_ros: only {RATE_FACTOR} can be set, to a number > 0; "
                                                        f"got {req.name} = {value!r}")
                        continue
                    from rclpy.parameter import Parameter
                    self.cfg.rate_factor = float(value)
                    self._anchor_wall, self._anchor_sim = time.monotonic(), self.sim.t
                    self.set_parameters([Parameter(RATE_FACTOR, value=float(value))])
                    live.server.set_parameter(RATE_FACTOR, float(value))
                    req.reply(float(value), None)

        # -- shutdown ---------------------------------------------------------------------------
        def close(self) -> str:
            """Finish the recording; return the run summary (``robodyn run`` format)."""
            from ..runs import summary
            for r in self.recorders:
                r.close()
            if self.live is not None:
                self.live.server.close()
            now = time.monotonic()
            wall = now - self._wall_start - self._paused_wall - (now - self._pause_began if self.paused else 0.0)
            st = {'integrator': self.cfg.integrator, 'dt': self.cfg.dt, 'rtol': self.cfg.rtol,
                  'atol': self.cfg.atol, 'auto': self.cfg.auto}
            record = self.recorder.path if self.recorder else None   # None: live only
            return summary(self.scene, self.sim, st, wall, record, self.recorders,
                           cpu=time.process_time() - self._cpu_start)

    return SimNode


def main(args=None) -> int:
    """Entry point of the ``sim`` console script; returns the exit status (2 = bad parameters)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from ..kernels import jit, start_compiler_if_cold
    from ..scene import SceneError
    jit.set_mode('interpret')   # a cold cache: run the kernels as Python while a child compiles them
    start_compiler_if_cold()   # (an empty cache: the child gets ready while ROS and the scene start)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    # warnings (a URDF read leniently, a marginal step) as one log line each; the default filter
    # prints each once
    from rclpy.logging import get_logger
    warnings.showwarning = lambda message, *a, **k: get_logger(NODE_NAME).warning(str(message))
    stop = StopSignals()   # the loop finishes the current period, then shuts down cleanly
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    node, status = None, 0
    try:
        node = make_node_class()()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        wait = 0.0
        while not stop.asked() and not node.finished:
            executor.spin_once(timeout_sec=wait)
            wait = node.work()
        if node.finished:   # the last state was just published: let DDS deliver it before leaving
            end = time.monotonic() + FINISH_LINGER
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.02)
    except (ConfigError, SceneError) as e:
        print(f'sim: {e}', file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            print(node.close(), flush=True)
            node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    sys.exit(main())
