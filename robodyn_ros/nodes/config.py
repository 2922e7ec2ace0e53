"""The sim node's parameters: their defaults (:data:`PARAMETERS`) and their validation against the
scene (:func:`resolve_config`), which merges the scene's settings the way ``robodyn run`` does.

No rclpy here: the node (:mod:`robodyn_ros.nodes.sim`) declares these parameters and hands their
values over, so the validation is tested without ROS.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the node's modes (see :mod:`robodyn_ros.nodes.sim`)
MODES = ('realtime', 'max', 'lockstep')


#: name -> (default, description); '' / 0 defaults mean "the scene's simulation setting"
PARAMETERS = {
    'scene': ('stanford_arm', 'bundled scene name or path to a scene YAML file (or a .urdf file)'),
    'robot_description_file': ('', "a URDF file to simulate on a fixed base instead of 'scene' ('' = use 'scene')"),
    'robot_description_timeout': (10.0, "with scene:='' and no robot_description_file: wall seconds to wait for "
                                        "the URDF on robot_description (transient local)"),
    'integrator': ('', "integrator name (auto, rk4, rosenbrock2, dop853, ...); '' = the scene's (default auto)"),
    'dt': (0.0, "fixed step (s) of fixed-step integrators; 0 = the scene's"),
    'rtol': (0.0, "relative tolerance of error-controlled integrators (rosenbrock2: error control, dt its largest "
                  "step); 0 = the scene's or the default"),
    'atol': (0.0, "absolute tolerance of error-controlled integrators; 0 = the scene's or the default"),
    'step_budget': (0.0, "error-controlled integrators: accepted steps per simulated second past which the "
                         "simulation stops, naming the stiff mode; .inf = none; 0 = the scene's or the default"),
    'publish_rate': (0.0, "control and publication rate (Hz); one period = 1/publish_rate; 0 = the scene's"),
    'mode': ('realtime', 'realtime, max (as fast as possible) or lockstep (one period per command)'),
    'rate_factor': (1.0, 'realtime mode: simulated seconds per wall second'),
    'max_lag': (0.25, 'realtime mode: wall seconds behind schedule after which the node stops catching up'),
    'command_timeout': (0.5, 'simulated seconds without a command after which inputs go to zero; 0 = never'),
    'duration': (0.0, 'simulated seconds to run, then exit; 0 = until shut down'),
    'record': ('', "MCAP file to record to; '' = no recording; an existing file is refused unless overwrite"),
    'overwrite': (False, 'replace the record file (and its -1, -2, ... episode files) if they exist'),
    'scripted_commands': (False, "use the scene's scripted commands instead of the command topics"),
    'start_paused': (False, 'start with simulation time paused; resume with ~/pause (data: false)'),
    'initial_positions': (None, "initial joint positions (nq values; unset = the scene's)"),
    'initial_velocities': (None, "initial velocities (nv values; unset = the scene's); a free root's come first, "
                                 "angular then linear, in its body axes (Featherstone's order, not Twist's)"),
    'initial_root_linear_velocity': (None, "a free root's initial linear velocity [x, y, z] (m/s) in the axes of "
                                           "initial_root_velocity_frame; unset = as above"),
    'initial_root_angular_velocity': (None, "a free root's initial angular velocity [x, y, z] (rad/s) in the axes of "
                                            "initial_root_velocity_frame; unset = as above"),
    'initial_root_velocity_frame': ('', "world or body: the axes of the two above (required with them)"),
    'initial_state': (None, "full initial state vector (ny values; overrides the above): [q; v], a free root's "
                            "twist angular first in its body axes"),
    'diagnostics_period': (1.0, 'simulated seconds between diagnostics messages'),
    'publish_tf': (True, 'publish (and record) /tf and /tf_static; without tf2_msgs they are only recorded'),
    'command_interface': ('', "a URDF robot (robot_description_file or the robot_description topic): effort, "
                              "position or velocity commands for every actuated joint; '' = effort"),
    'sensors': ('', "a URDF robot: its sensors as a YAML list (as a scene's sensors key), e.g. "
                    "'[{kind: imu, link: base_link}]'; '' = none"),
    'backend': ('', "dynamics kernels: numpy, numba, generated or auto; '' = $ROBODYN_BACKEND, else auto "
                    "(the generic compiled kernels, then the model's own code once a background process has "
                    'compiled it, the same bytes); numba = generic only; generated = the model\'s own from the start'),
    'foxglove_port': (0, 'serve the run live on a Foxglove WebSocket at this TCP port (0 = off); clients see '
                         'every recorded topic and may publish commands, call reset and pause, set rate_factor'),
    'foxglove_host': ('127.0.0.1', 'address the Foxglove WebSocket serves on (127.0.0.1: this machine only)'),
    'embed_meshes': (True, "the recorded (and live) robot_description carries its meshes as data: URIs, so that "
                           "a viewer without ROS draws them; the robot_description topic keeps package:// URIs"),
}


def check_live(p: dict) -> tuple:
    """``(host, port)`` of the live server from parameters ``foxglove_host``/``foxglove_port`` (port 0:
    off), or ConfigError naming the parameter."""
    port, host = p.get('foxglove_port', 0), p.get('foxglove_host', '127.0.0.1')
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ConfigError(f"parameter 'foxglove_port' must be a TCP port 1..65535 (0: no live server), got {port!r}")
    if not isinstance(host, str) or not host:
        raise ConfigError(f"parameter 'foxglove_host' must be an address (e.g. 127.0.0.1), got {host!r}")
    return host, port


class ConfigError(ValueError):
    """An invalid parameter value; the message names the parameter and what is accepted."""


@dataclass
class Config:
    """Validated node parameters (see :data:`PARAMETERS`); scene settings already merged."""

    scene: str
    integrator: str
    dt: float | None
    rtol: float | None
    atol: float | None
    publish_rate: float
    mode: str
    rate_factor: float
    max_lag: float
    command_timeout: float | None
    duration: float
    record: str
    scripted_commands: bool
    start_paused: bool
    diagnostics_period: float
    y0: np.ndarray
    publish_tf: bool = True
    backend: str = ''
    auto: str = ''   # why integrator auto chose ``integrator`` ('' when the settings named it)
    step_budget: float | None = None
    embed_meshes: bool = True
    plan: object = None   # the run's IntegratorPlan (runs.plan_run): the Simulator is built from it

    def settings(self, namespace: str) -> dict:
        """The run settings recorded in the MCAP metadata (what ``robodyn resim`` rebuilds from)."""
        from ..systems.base import recorded_backend
        st = {'integrator': self.integrator, 'dt': self.dt, 'rtol': self.rtol, 'atol': self.atol,
              'rate': self.publish_rate, 'duration': self.duration, 'mode': self.mode,
              'rate_factor': self.rate_factor, 'command_timeout': self.command_timeout,
              'scripted_commands': self.scripted_commands, 'namespace': namespace,
              'y0': [float(x) for x in self.y0], 'backend': recorded_backend(self.backend),
              **({'auto': self.auto} if self.auto else {})}
        if self.step_budget is not None:   # (only when given: other recordings keep their bytes)
            st['step_budget'] = self.step_budget
        return st


def check_number(name, v, positive=False, minimum=None) -> float:
    """Parameter ``name``'s value v as a finite float (``positive``: > 0; ``minimum``: >= it), else ConfigError."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f'parameter {name!r} must be a finite number, got {v!r}')
    if positive and v <= 0:
        raise ConfigError(f'parameter {name!r} must be > 0, got {v!r}')
    if minimum is not None and v < minimum:
        raise ConfigError(f'parameter {name!r} must be >= {minimum}, got {v!r}')
    return float(v)


def check_vector(name, v, n, what) -> np.ndarray:
    """Parameter ``name``'s value v as n finite floats (``what`` they are, for the message), else ConfigError."""
    if not isinstance(v, (list, tuple)) or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v):
        raise ConfigError(f'parameter {name!r} must be a list of numbers ({what}), got {v!r}')
    if len(v) != n:
        raise ConfigError(f'parameter {name!r} needs {n} values ({what}), got {len(v)}')
    arr = np.array(v, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f'parameter {name!r} must be finite, got {v!r}')
    return arr


_ROOT_PARAMS = ('initial_root_linear_velocity', 'initial_root_angular_velocity')


def _initial_state_override(p: dict, scene, system, joints: str, y0):
    """The initial state the parameters give (or ``y0``, the scene's): ``initial_positions`` and
    ``initial_velocities`` in the coordinates the scene's initial_state uses (minimal ones for the
    augmented free flyer; the system maps them to its state as the scene loader does), a free root's
    velocity from ``initial_root_linear_velocity``/``_angular_velocity`` in the axes of
    ``initial_root_velocity_frame`` (``scene.state.root_twist``), or the full ``initial_state``.
    A free root's twist given as bare numbers (``initial_velocities``, ``initial_state``) is read
    angular first in body axes, with a warning (``scene.state.VelocityOrderWarning``)."""
    import warnings

    from ..scene.state import _velocities, free_root, root_twist, warn_bare_root_twist
    from ..validation import SceneContext, SceneError
    root = free_root(system)
    roots = [p[k] is not None for k in _ROOT_PARAMS]
    if p['initial_positions'] is not None or p['initial_velocities'] is not None or any(roots):
        nq0, nv0 = getattr(system, 'initial_state_sizes', (system.nq, getattr(system, 'nv', None)))
        given = (scene.data or {}).get('initial_state') or {}
        q0 = given.get('q')
        v0 = given.get('v')
        if p['initial_positions'] is not None:
            q0 = check_vector('initial_positions', p['initial_positions'], nq0, joints)
        ctx = SceneContext(f'scene {scene.name}')
        if v0 is not None and p['initial_velocities'] is None:   # the scene's, as its loader read them
            with warnings.catch_warnings():
                warnings.simplefilter('ignore')
                try:
                    v0 = _velocities(ctx, v0, 'initial_state.v', system, None if q0 is None else np.asarray(q0, float),
                                     nv0, joints)
                except SceneError as e:
                    raise ConfigError(str(e)) from None
        if p['initial_velocities'] is not None:
            if nv0 is None:
                raise ConfigError(f"parameter 'initial_velocities': {type(system).__name__} does not say how many "
                                  f"velocities it has; set 'initial_state' ({system.ny} values) instead")
            v0 = check_vector('initial_velocities', p['initial_velocities'], nv0, joints)
            if root is not None and not any(roots):
                warn_bare_root_twist(v0[root[2]:root[2] + 6], root[0], "parameter 'initial_velocities'")
        if any(roots):
            if root is None:
                raise ConfigError(f"parameters {', '.join(_ROOT_PARAMS)}: scene {scene.name!r} has no free root "
                                  f"({type(system).__name__}); give initial_velocities")
            frame = p['initial_root_velocity_frame']
            value = {'frame': frame, **{k.split('_')[2]: check_vector(k, p[k], 3, '[x, y, z]').tolist()
                                        for k, given_ in zip(_ROOT_PARAMS, roots) if given_}}
            q = np.asarray(q0 if q0 is not None else system.model.neutral(), dtype=float)
            try:
                twist = root_twist(ctx, value, 'initial_root_velocity_frame', q[root[1] + 3:root[1] + 7])
            except SceneError:
                raise ConfigError(f"parameter 'initial_root_velocity_frame' must be world or body (the axes of "
                                  f"{' and '.join(_ROOT_PARAMS)}), got {frame!r}") from None
            v0 = np.zeros(nv0) if v0 is None else np.array(v0, dtype=float)
            v0[root[2]:root[2] + 6] = twist
        try:
            y0 = system.initial_state(None if q0 is None else np.asarray(q0, dtype=float),
                                      None if v0 is None else np.asarray(v0, dtype=float))
        except ValueError as e:
            raise ConfigError(f'initial_positions/initial_velocities: {e}') from None
    if p['initial_state'] is not None:
        y0 = check_vector('initial_state', p['initial_state'], system.ny, 'the full state vector')
        if root is not None and system.nq == system.model.nq:
            k = system.nq + root[2]
            warn_bare_root_twist(y0[k:k + 6], root[0], "parameter 'initial_state'")
    return y0


def resolve_config(p: dict, scene) -> Config:
    """Validate raw parameter values ``p`` (name -> value) against ``scene``; scene defaults fill gaps.

    Raises :class:`ConfigError` naming the parameter. The integrator settings are resolved like
    ``robodyn run`` does (:func:`robodyn_ros.runs.resolve_settings`), so a node run and a
    headless run of the same scene use the same defaults.
    """
    from ..integrator_choice import is_auto
    from ..integrators import CONTROLLABLE, INTEGRATORS
    from ..runs import plan_run, resolve_settings
    if not isinstance(p['integrator'], str):
        raise ConfigError(f"parameter 'integrator' must be a string, got {p['integrator']!r}")
    if p['integrator'] and p['integrator'].lower() not in INTEGRATORS and not is_auto(p['integrator']):
        raise ConfigError(f"parameter 'integrator': unknown integrator {p['integrator']!r}; "
                          f"valid names: auto, {', '.join(INTEGRATORS)}")
    opt = {k: (check_number(k, p[k], minimum=0.0) or None) for k in ('dt', 'rtol', 'atol', 'publish_rate')}
    budget = p.get('step_budget', 0.0)
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or math.isnan(budget) or budget < 0:
        raise ConfigError(f"parameter 'step_budget' must be a number of steps per simulated second > 0 "
                          f"(.inf: none; 0: the scene's or the default), got {budget!r}")
    try:
        st = resolve_settings(scene, p['integrator'].lower() or None, opt['dt'], opt['rtol'], opt['atol'],
                              opt['publish_rate'], step_budget=float(budget) or None)
    except ValueError as e:
        raise ConfigError(f'parameters integrator, rtol, atol: {e}') from None
    mode = p['mode']
    if mode not in MODES:
        raise ConfigError(f"parameter 'mode' must be one of {', '.join(MODES)}, got {mode!r}")
    for name in ('scripted_commands', 'start_paused', 'publish_tf', 'overwrite', 'embed_meshes'):
        if not isinstance(p[name], bool):
            raise ConfigError(f'parameter {name!r} must be true or false, got {p[name]!r}')
    if p['scripted_commands'] and mode == 'lockstep':
        raise ConfigError("scripted_commands needs mode realtime or max: lockstep advances on received commands")
    if mode == 'lockstep' and not scene.system.inputs:
        raise ConfigError(f"mode lockstep advances one period per command, but scene {scene.name!r} "
                          f"({type(scene.system).__name__}) takes no commands; use mode realtime or max")
    if p['scripted_commands'] and scene.script is None:
        raise ConfigError(f'scripted_commands: scene {scene.name!r} has no scripted commands')
    if not isinstance(p['record'], str):
        raise ConfigError(f"parameter 'record' must be a file path string, got {p['record']!r}")
    if p['record']:  # before the simulation starts: never overwrite silently, never fail at the end
        from ..recording.target import RecordPathError, check_record_path, episode_files
        try:
            check_record_path(p['record'], overwrite=p['overwrite'], how_to_overwrite='overwrite:=true',
                              also=episode_files(p['record']))
        except RecordPathError as e:
            raise ConfigError(f"parameter 'record': {e}") from None
    timeout = check_number('command_timeout', p['command_timeout'], minimum=0.0)
    system = scene.system
    y0 = np.array(scene.y0, dtype=float)
    names = getattr(system, 'joint_names', None)
    joints = ', '.join(names) if names else 'configuration coordinates'
    y0 = _initial_state_override(p, scene, system, joints, y0)
    try:   # which integrator, which step, and why, decided once (Config.plan; Config.auto: auto's reason)
        plan, st = plan_run(st, system, y0)
    except ValueError as e:
        raise ConfigError(f'cannot build the simulator: {e}') from None
    kind = INTEGRATORS[st['integrator']].kind
    if kind == 'fixed':   # rosenbrock2 may also run under error control (rtol), dt its largest step
        keep = st['integrator'] in CONTROLLABLE
        dt, rtol, atol = st['dt'], st['rtol'] if keep else None, st['atol'] if keep else None
    else:
        dt, rtol, atol = None, st['rtol'], st['atol']
    return Config(scene=scene.name, integrator=st['integrator'], dt=dt, rtol=rtol, atol=atol, auto=st.get('auto', ''),
                  publish_rate=float(st['rate']), mode=mode,
                  rate_factor=check_number('rate_factor', p['rate_factor'], positive=True),
                  max_lag=check_number('max_lag', p['max_lag'], positive=True),
                  command_timeout=timeout or None,
                  duration=check_number('duration', p['duration'], minimum=0.0),
                  record=p['record'], scripted_commands=p['scripted_commands'], start_paused=p['start_paused'],
                  diagnostics_period=check_number('diagnostics_period', p['diagnostics_period'], positive=True),
                  y0=y0, publish_tf=p['publish_tf'], backend=check_backend(p.get('backend', '')),
                  step_budget=st.get('step_budget'), plan=plan, embed_meshes=p.get('embed_meshes', True))


def urdf_options(raw: dict) -> dict:
    """The ``command_interface`` and ``sensors`` parameters as ``load_scene``/``urdf_scene_text`` keywords
    (for a URDF robot; a scene file gives them itself); ConfigError for a bad value."""
    import yaml
    ci, sensors = raw.get('command_interface', ''), raw.get('sensors', '')
    if not isinstance(ci, str) or ci not in ('', 'effort', 'position', 'velocity'):
        raise ConfigError(f"parameter 'command_interface' must be effort, position or velocity ('' = effort), "
                          f'got {ci!r}')
    if not isinstance(sensors, str):
        raise ConfigError(f"parameter 'sensors' must be a YAML list text, got {sensors!r}")
    items = None
    if sensors.strip():
        try:
            items = yaml.safe_load(sensors)
        except yaml.YAMLError as e:
            raise ConfigError(f"parameter 'sensors': not YAML: {e}") from None
        if not isinstance(items, list):
            raise ConfigError(f"parameter 'sensors' must be a YAML list of sensors, got {sensors!r}")
    return {'command_interface': ci or None, 'sensors': items}


def check_backend(value) -> str:
    """The validated ``backend`` parameter ('' = ROBODYN_BACKEND, else the tools' default)."""
    from ..systems.base import tools_backend
    if not isinstance(value, str):
        raise ConfigError(f"parameter 'backend' must be a string, got {value!r}")
    try:
        return tools_backend(value or None)
    except ValueError as e:
        raise ConfigError(f"parameter 'backend': {e}") from None
