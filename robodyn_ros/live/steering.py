"""What live clients send back, handed from the server's thread to the simulation's.

The server (:mod:`.server`) calls :class:`Steering` with each request on its own thread; requests
wait in a queue until the simulation's thread takes them (:meth:`Steering.take`) between two
control periods, where the node or ``robodyn run --live`` applies them exactly as they apply a ROS
message or a ROS service call:

* a message a client publishes on a command topic (``effort_commands``, ``wheel_voltage_commands``,
  ``base_wrench_command``, any the run has) is decoded (canonical CDR, :func:`robodyn_ros.recording.
  cdr.decode`) and enters the same command port with the same checks (:meth:`Steering.command`, then
  ``Simulator.set_command``): a wrong type or length, a NaN, is refused, counted and logged, and the
  last valid command stays;
* ``reset`` (std_srvs/Trigger) and ``pause`` (std_srvs/SetBool, data: true pauses) are services
  (:data:`SERVICES`, their CDR here: :func:`trigger_response`, :func:`set_bool_data`);
* ``rate_factor`` is a parameter (:data:`RATE_FACTOR`).
"""
from __future__ import annotations

import queue
import struct
import threading

from ..simulation import CommandError
from .server import Publish, Service

__all__ = ['Steering', 'RefusedCommand', 'SERVICES', 'RATE_FACTOR', 'trigger_response', 'set_bool_data',
           'service_set']

#: the parameter a client may set: simulated seconds per wall second (robodyn run: 0 = as fast as possible)
RATE_FACTOR = 'rate_factor'
TRIGGER = 'std_srvs/srv/Trigger'
SET_BOOL = 'std_srvs/srv/SetBool'
_RESPONSE_TEXT = ('bool success   # indicate successful run of triggered service\n'
                  'string message # informational, e.g. for error messages')


class RefusedCommand(CommandError):
    """A client's message on a command topic that is no command of its port (``port``)."""

    def __init__(self, port: str, message: str):
        super().__init__(message)
        self.port = port


def service_set(prefix: str) -> tuple:
    """The :class:`Service` list: ``<prefix>reset`` (Trigger) and ``<prefix>pause`` (SetBool); prefix
    e.g. the node's ``/robodyn_sim/`` (its ROS service names)."""
    return (Service(prefix + 'reset', TRIGGER, '', _RESPONSE_TEXT),
            Service(prefix + 'pause', SET_BOOL, 'bool data # e.g. for hardware enabling / disabling', _RESPONSE_TEXT))


#: the services of ``robodyn run --live``
SERVICES = service_set('/robodyn/')


def trigger_response(success: bool, message: str) -> bytes:
    """CDR of std_srvs Trigger_Response / SetBool_Response (``bool success``, ``string message``)."""
    text = message.encode('utf-8') + b'\x00'
    return b'\x00\x01\x00\x00' + struct.pack('<?3xI', bool(success), len(text)) + text


def set_bool_data(payload: bytes) -> bool:
    """``data`` of a CDR std_srvs SetBool_Request (ValueError when it is not one)."""
    if len(payload) < 5 or payload[:2] not in (b'\x00\x01', b'\x00\x00'):
        raise ValueError('not a little- or big-endian CDR SetBool request')
    return payload[4] != 0


class Steering:
    """The queue of client requests; the server's ``on_request``.

    commands: topic as clients see it (resolved, e.g. ``/effort_commands``) -> ``(port, type)``;
    values: ``(port, message) -> values`` (:func:`robodyn_ros.nodes.ports.command_values`: the ROS
    subscriptions' check); wake: called (server thread) after each request is queued, e.g. a ROS
    guard condition's ``trigger`` so that the node's executor takes it at once.
    """

    def __init__(self, commands: dict, values, wake=None):
        from ..recording import msgdefs
        self.commands = {topic: (port, msgdefs.canonical_name(t)) for topic, (port, t) in commands.items()}
        self.values = values
        self.wake = wake
        self._q = queue.SimpleQueue()
        self.event = threading.Event()   # set while requests wait (robodyn run waits on it)
        self.stop_requested = False

    def advertise(self, server):
        """Advertise the command topics now (a viewer subscribes to them, and learns their types, before
        the first command is recorded); their channels are the ones the recorder's records then use."""
        for topic, (_, type_name) in self.commands.items():
            server.channel(topic, type_name)

    def __call__(self, request):
        """Queue a request (server thread)."""
        self._q.put(request)
        self.event.set()
        if self.wake is not None:
            self.wake()

    def request_stop(self):
        """Ctrl-C (signal handler): the run stops at the next period boundary."""
        self.stop_requested = True
        self.event.set()

    @property
    def pending(self) -> bool:
        return not self._q.empty() or self.stop_requested

    def take(self) -> list:
        """Every request queued so far (simulation thread), oldest first."""
        self.event.clear()
        out = []
        while True:
            try:
                out.append(self._q.get_nowait())
            except queue.Empty:
                return out

    def command(self, req: Publish):
        """``(port, message dict)`` of a client's message on a command topic, None for another topic;
        raises :class:`RefusedCommand` (its ``port``) when it cannot be one (wrong type or encoding,
        undecodable bytes): the caller counts it as refused, as the node does a ROS message that
        ``command_values`` refuses."""
        entry = self.commands.get(req.topic)
        if entry is None:
            return None
        port, type_name = entry
        from ..recording import cdr, msgdefs
        try:
            given = msgdefs.canonical_name(req.schema_name) if req.schema_name else ''
        except ValueError:
            given = req.schema_name
        if req.encoding != 'cdr' or given != type_name:
            raise RefusedCommand(port, f'{port}: {req.topic} takes {type_name} in cdr, got '
                                       f'{req.schema_name or "no schema"} in {req.encoding}')
        try:
            msg = cdr.decode(type_name, req.payload)
        except (ValueError, IndexError, KeyError, struct.error, UnicodeDecodeError) as e:
            raise RefusedCommand(port, f'{port}: {req.topic}: not a CDR {type_name} '
                                       f'({type(e).__name__}: {e})') from None
        return port, msg
