"""``robodyn run --live``: a headless run paced to real time x ``rate_factor``, served live and steered.

:class:`LiveRun` is a sink of :func:`robodyn_ros.simulation.run_headless`, after the recorder (whose
records the server streams: :class:`~robodyn_ros.recording.fanout.Fanout`). At the end of each
control period it

1. applies what clients sent (:class:`~robodyn_ros.live.steering.Steering`): a command enters its
   port through ``Simulator.set_command`` and is recorded as received, at the current simulation
   time, as the node does with a ROS message; from then on the scene's scripted command no longer
   writes that port (the client has taken it over); ``pause`` holds the run at this period
   boundary, ``reset`` starts it again at t = 0 (the recording continues in ``<stem>-1.mcap``,
   ``-2``, ... as the node's), ``rate_factor`` changes the pace;
2. waits until the wall clock reaches the period's end at the chosen pace (``rate_factor`` 0: no
   wait, and the compiled many-period blocks of the headless path stay on; a period in which a
   client request waits is run on the per-period path, which gives the same numbers).

Before it waits it hands the recorder's held periods over (:meth:`McapRunSink.hand_over`), so the
viewers see every period written so far. Ctrl-C stops the run at the next period boundary
(:class:`LiveStop`); the recording is finished as at the end of a run.
"""
from __future__ import annotations

import math
import sys
import time

from ..simulation import CommandError
from .server import Publish, ServiceCall, SetParameter
from .steering import RATE_FACTOR, RefusedCommand, set_bool_data, trigger_response

__all__ = ['LiveRun', 'LiveReset', 'LiveStop', 'MAX_LAG', 'check_rate_factor']

#: wall seconds behind schedule after which a paced run stops catching up (re-anchors; the node's max_lag)
MAX_LAG = 0.25
#: wall seconds between looks at the clients while paused
IDLE = 0.05
#: wall seconds between repeats of the same refused-command line
LOG_THROTTLE = 2.0


class LiveReset(Exception):
    """A client called ``reset``: the run starts again at t = 0; ``reply(message)`` answers it."""

    def __init__(self, reply):
        super().__init__('reset')
        self.reply = reply


class LiveStop(Exception):
    """Ctrl-C: the run stops at this period boundary."""


def check_rate_factor(value) -> float:
    """A rate factor as given (a finite number >= 0; 0 = as fast as possible), else ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f'rate_factor must be a finite number >= 0 (0: as fast as possible), got {value!r}')
    return float(value)


class _Unowned:
    """The scene's script without the ports a client has taken over (its compiled programs and its messages' times
    kept: :class:`LiveRun` stops the block path when a programmed port is taken over)."""

    def __init__(self, script, owned: set):
        self.script, self.owned = script, owned
        self.programs = getattr(script, 'programs', None)
        self.next_send = getattr(script, 'next_send', None)

    def __call__(self, t, y):
        return {p: v for p, v in self.script(t, y).items() if p not in self.owned}


class LiveRun:
    """The pacing and steering sink (see the module docstring).

    server: the :class:`~robodyn_ros.live.server.LiveServer`; steering: its
    :class:`~robodyn_ros.live.steering.Steering`; values: ``(port, message) -> values`` (the ROS
    subscriptions' check, :func:`robodyn_ros.nodes.ports.command_values`); rate_factor: simulated
    seconds per wall second (0: as fast as possible); paused: start paused (``pause`` with
    data: false resumes); log: where one-line notices go.
    """

    def __init__(self, server, steering, values, rate_factor: float = 1.0, paused: bool = False, log=None):
        self.server, self.steering, self.values = server, steering, values
        self.rate_factor = check_rate_factor(rate_factor)
        self.paused = bool(paused)
        self.log = log or (lambda text: print(text, file=sys.stderr, flush=True))
        self.recorder = None   # the current episode's McapRunSink (set by the caller)
        self.owned = set()     # ports a client has commanded
        self.programmed = set()
        self._anchor_wall = self._anchor_sim = 0.0
        self._logged = {}
        self.refused = 0
        self.paused_wall = 0.0   # wall seconds spent paused (left out of the summary's wall time)

    def script(self, script):
        """The scene's script as this run feeds it (None stays None)."""
        if script is None:
            self.programmed = set()
            return None
        self.programmed = set((getattr(script, 'programs', None) or {}).keys())
        return _Unowned(script, self.owned)

    # -- the sink ------------------------------------------------------------------------
    @property
    def takes_blocks(self) -> bool:
        return True

    def on_start(self, sim):
        self._anchor(sim.t)

    def on_command(self, t, port, values):
        pass

    def on_output(self, t, out, sim, level=0, message='running'):
        self._boundary(sim)

    def block_periods(self, t_out, template, cmd_kind) -> int:
        """All of them in a run as fast as possible with nothing to apply; else none (per-period path)."""
        if self.rate_factor > 0 or self.paused or self.steering.pending or (self.owned & self.programmed):
            return 0
        return len(t_out)

    def on_block(self, blk, sim, level=0, message='running'):
        # requests wait for the next period boundary of the per-period path (block_periods says 0
        # while they wait), where on_output applies them: a piece of a block ends where the block's
        # later periods are already computed with the commands in force
        if self.steering.stop_requested:
            raise LiveStop()

    def close(self):
        pass

    # -- between two periods -------------------------------------------------------------
    def _anchor(self, t_sim: float):
        self._anchor_wall, self._anchor_sim = time.monotonic(), t_sim

    def _boundary(self, sim):
        """Apply the requests, then wait (paused, or for the pace) taking requests as they come."""
        while True:
            self._steer(sim)
            if self.paused:
                self._hand_over()
                w = time.monotonic()
                self.steering.event.wait(IDLE)
                self.paused_wall += time.monotonic() - w
                continue
            rf = self.rate_factor
            if rf <= 0:
                return
            now = time.monotonic()
            target = self._anchor_wall + (sim.t - self._anchor_sim) / rf
            if now >= target:
                if now - target > MAX_LAG:   # far behind: go on from here instead of racing to catch up
                    self._anchor(sim.t)
                return
            self._hand_over()
            self.steering.event.wait(target - now)

    def _hand_over(self):
        if self.recorder is not None:
            self.recorder.hand_over()

    def _steer(self, sim):
        reset = None
        for req in self.steering.take():
            if isinstance(req, Publish):
                self._command(sim, req)
            elif isinstance(req, ServiceCall):
                if req.service.endswith('/reset'):
                    reset = req.reply
                elif req.service.endswith('/pause'):
                    try:
                        pause = set_bool_data(req.payload)
                    except ValueError as e:
                        req.reply(trigger_response(False, f'pause: {e}'))
                        continue
                    if self.paused and not pause:
                        self._anchor(sim.t)
                    self.paused = pause
                    req.reply(trigger_response(True, f'{"paused" if pause else "running"} at t={sim.t:g} s'))
            elif isinstance(req, SetParameter):
                if req.name != RATE_FACTOR:
                    req.reply(None, f'robodyn_ros: no parameter {req.name!r} (this run has {RATE_FACTOR})')
                    continue
                try:
                    self.rate_factor = check_rate_factor(req.value)
                except ValueError as e:
                    req.reply(self.rate_factor, f'robodyn_ros: {e}')
                    continue
                self._anchor(sim.t)
                self.server.set_parameter(RATE_FACTOR, self.rate_factor)
                req.reply(self.rate_factor, None)
        if self.steering.stop_requested:
            raise LiveStop()
        if reset is not None:
            raise LiveReset(reset)

    def _command(self, sim, req: Publish):
        """A client's message on a command topic: the ROS subscription's checks, then the port."""
        try:
            got = self.steering.command(req)
            if got is None:
                self.server.status(req.client, 1, f'robodyn_ros: {req.topic} is not a command topic of this run '
                                                  f'(it takes {", ".join(self.steering.commands) or "none"})')
                return
            port, msg = got
            try:
                values = self.values(port, msg)
            except CommandError:
                sim.ports[port].rejected += 1   # refused before reaching the simulator, as the node counts it
                raise
            sim.set_command(port, values)
        except RefusedCommand as e:
            sim.ports[e.port].rejected += 1
            self._refused(sim, e, req.client)
        except CommandError as e:
            self._refused(sim, e, req.client)
        else:
            self.owned.add(port)
            if self.recorder is not None:
                self.recorder.on_command(sim.t, port, sim.ports[port].value)

    def _refused(self, sim, err, client):
        self.refused += 1
        text = f'live command refused ({sim.rejected_commands} so far), last valid command stays: {err}'
        self.server.status(client, 2, f'robodyn_ros: {text}')
        now = time.monotonic()
        key = str(err)
        if now - self._logged.get(key, -math.inf) >= LOG_THROTTLE:
            self._logged[key] = now
            self.log(f'robodyn run: {text}')
