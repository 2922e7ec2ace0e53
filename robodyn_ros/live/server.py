"""A Foxglove WebSocket server for a running simulation, on its own thread.

The protocol is Foxglove's WebSocket protocol v1 (github.com/foxglove/ws-protocol, docs/spec.md).
Both subprotocol names in use are accepted: ``foxglove.websocket.v1`` (Foxglove Studio 1.x,
Lichtblick, foxglove_bridge's clients) and ``foxglove.sdk.v1`` (the Foxglove SDK's, today's app);
their advertise, subscribe, message-data, client-publish, service, parameter and asset frames are
the same, so one implementation serves both (a ``subscribe`` without ``id``, which the SDK's
schema allows, gets the channel id as its subscription id). Built on ``websockets`` (asyncio).

What it offers (``serverInfo`` capabilities): ``time`` (a Time frame, the simulation time, before
the first message of each new time: Foxglove Studio stamps what it receives with the latest Time
it got), ``clientPublish`` (``cdr``), ``services`` and ``parameters``/``parametersSubscribe``
(handed to the application: :mod:`robodyn_ros.live.steering`) and ``assets`` (``fetchAsset`` of
``package://``, ``file://`` and absolute paths: :func:`robodyn_ros.assets.asset_bytes`). Channels
carry ``cdr`` messages with ``ros2msg`` schemas (the recording's).

Threads. The simulation's thread calls :meth:`LiveServer.channel`, :meth:`LiveServer.send` and
:meth:`LiveServer.send_records` (through a :class:`LiveTap`); they append to a bounded outbox and
return at once (no I/O, no encoding: the bytes are the recorder's). The server's thread runs an
asyncio loop: it moves the outbox to each subscribed client's bounded queue (:data:`QUEUE_FRAMES`
frames; when full the oldest is dropped) and sends. A slow or vanished client therefore loses its
oldest messages and never slows the simulation; the recording and the ROS topics are fed before
and apart from this. The loop also keeps its share of the CPU below :data:`CPU_SHARE` (it sleeps
in proportion to the time it worked), so that in a run as fast as possible the Python thread that
serves does not take the interpreter from the one that simulates.

A new subscriber gets the last message of the channel at once (the latched ``robot_description``
and ``/tf_static`` included), so a paused or lockstep run shows its robot.
"""
from __future__ import annotations

import asyncio
import collections
import json
import logging
import socket
import struct
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ['LiveServer', 'LiveTap', 'LivePortError', 'Service', 'Publish', 'ServiceCall', 'SetParameter', 'bind',
           'SUBPROTOCOLS', 'CAPABILITIES']

#: subprotocols accepted, in the order preferred when a client offers several
SUBPROTOCOLS = ('foxglove.sdk.v1', 'foxglove.websocket.v1')
CAPABILITIES = ('clientPublish', 'parameters', 'parametersSubscribe', 'services', 'assets', 'time')
#: server -> client binary opcodes
OP_MESSAGE_DATA, OP_TIME, OP_SERVICE_RESPONSE, OP_FETCH_ASSET_RESPONSE = 1, 2, 3, 4
#: client -> server binary opcodes
OP_CLIENT_MESSAGE, OP_SERVICE_REQUEST = 1, 2
#: data frames a client's queue holds before its oldest are dropped (a few seconds of a robot at 100 Hz)
QUEUE_FRAMES = 4096
#: records (or batches of periods) the simulation may hand over before the server's thread takes them; the
#: oldest are dropped beyond (a run as fast as possible makes far more than a viewer draws; memory stays bounded)
OUTBOX = 256
#: largest share of the CPU the server's thread takes while it has work (it sleeps the rest)
CPU_SHARE = 0.1
#: seconds of owed sleep after which the server's thread sleeps (see CPU_SHARE)
PACE_SLICE = 0.002
#: wall seconds a closing server waits for its clients to take what is queued for them
CLOSE_DRAIN = 2.0
#: largest message a client may send (a command, a service request)
MAX_INCOMING = 1 << 24

_MSG_HEAD = struct.Struct('<BIQ')
_TIME = struct.Struct('<BQ')
_U32 = struct.Struct('<I')


class LivePortError(OSError):
    """The address cannot be served (in use, not an address of this machine); one-line message."""


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (port 0: a free one), opened now so that a port in use
    is refused before anything runs. Raises :class:`LivePortError`."""
    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        return socket.create_server((host, port), family=family)
    except OSError as e:
        why = e.strerror or str(e)
        if getattr(e, 'errno', None) == 98 or 'in use' in why:
            why = 'address already in use (another server, or an earlier run still listening)'
        raise LivePortError(f'cannot serve on {host}:{port}: {why}') from None


@dataclass(frozen=True)
class Service:
    """A service the server offers: name, ROS type (``std_srvs/srv/Trigger``), the ``ros2msg`` text of
    its request and response (Studio 1.x reads ``requestSchema``/``responseSchema``, newer clients
    ``request``/``response``: both are sent)."""

    name: str
    type: str
    request_schema: str
    response_schema: str


@dataclass
class Publish:
    """A message a client published on a channel it advertised."""

    client: int
    topic: str
    schema_name: str
    encoding: str
    payload: bytes


@dataclass
class ServiceCall:
    """A client's call of a :class:`Service`; ``reply(payload)`` answers it (any thread)."""

    client: int
    service: str
    encoding: str
    payload: bytes
    reply: Callable[[bytes], None]


@dataclass
class SetParameter:
    """A client's ``setParameters`` entry; ``reply(value, error)`` answers it (any thread): the value in
    force after it, and the reason when refused."""

    client: int
    name: str
    value: object
    reply: Callable[[object, str | None], None]


class _Client:
    """One connection: its queues (control: never dropped; data: bounded), subscriptions and channels."""

    def __init__(self, ws, cid: int, maxlen: int):
        self.ws, self.id = ws, cid
        self.control = collections.deque()
        self.data = collections.deque(maxlen=maxlen)
        self.event = asyncio.Event()
        self.sub_of = {}        # subscription id -> server channel id
        self.sub_for = {}       # server channel id -> subscription id
        self.adverts = {}       # client channel id -> (topic, schema name, encoding)
        self.param_subs = set()
        self.dropped = 0

    def push_data(self, frame: bytes):
        if len(self.data) == self.data.maxlen:
            self.dropped += 1
        self.data.append(frame)


class LiveServer:
    """The server; :meth:`start` it, feed it from the simulation's thread, :meth:`close` it.

    sock: the listening socket (:func:`bind`); name: shown by clients; on_request: called on the
    server's thread with each :class:`Publish`, :class:`ServiceCall` and :class:`SetParameter` (it
    must only hand them over: :class:`robodyn_ros.live.steering.Steering`); services: the
    :class:`Service` list; parameters: name -> value (float) of the parameters offered;
    asset: ``uri -> bytes`` for ``fetchAsset`` (raises ValueError when not found);
    queue_frames, cpu_share: see :data:`QUEUE_FRAMES`, :data:`CPU_SHARE`.
    """

    def __init__(self, sock: socket.socket, name: str, on_request=None, services=(), parameters=None,
                 asset=None, queue_frames: int = QUEUE_FRAMES, cpu_share: float = CPU_SHARE):
        self.sock, self.name = sock, name
        self.on_request = on_request or (lambda request: None)
        self.services = tuple(services)
        self._params = dict(parameters or {})
        if asset is None:
            from ..assets import asset_bytes
            asset = asset_bytes
        self.asset = asset
        self.queue_frames, self.cpu_share = int(queue_frames), float(cpu_share)
        host, port = sock.getsockname()[:2]
        self.host, self.port = host, port
        self.url = f'ws://{host}:{port}' if ':' not in host else f'ws://[{host}]:{port}'
        self.session = str(time.time_ns())
        # channels: registered from any thread (under the lock), advertised from the loop
        self._lock = threading.Lock()
        self._topics = {}          # topic -> server channel id
        self._adverts = {}         # server channel id -> its advertisement
        self._latched_ids = set()  # transient-local channels
        self._latched = {}         # server channel id -> (t, data) of its last message
        self._outbox = collections.deque(maxlen=OUTBOX)
        self._kick_pending = False
        self.dropped_outbox = 0
        # loop-thread state
        self._loop = None
        self._clients = []
        self._subs = {}            # server channel id -> [(client, subscription id)]
        self._last = {}            # server channel id -> (t, data): what a new subscriber gets
        self._advertised = []      # advertisements sent so far (a new client gets them all)
        self._time = -1            # time of the last Time frame (ns)
        self._debt = 0.0
        self._next_client = 1
        self._thread = None
        self._ready = threading.Event()
        self._failed = None
        self.clients_seen = 0
        self._dropped_gone = 0     # dropped for clients that left

    # -- life cycle (main thread) ------------------------------------------------------------
    def start(self):
        """Serve on a daemon thread; returns once the server accepts connections."""
        self._thread = threading.Thread(target=self._thread_main, name='robodyn-live', daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._failed is not None:
            raise self._failed
        return self

    def close(self, timeout: float = 5.0):
        """Close every connection and stop serving; idempotent."""
        loop = self._loop
        if loop is not None and self._thread is not None and self._thread.is_alive():
            try:
                loop.call_soon_threadsafe(self._stop.set)
            except RuntimeError:   # the loop already closed
                pass
            self._thread.join(timeout)
        try:
            self.sock.close()
        except OSError:
            pass

    @property
    def client_count(self) -> int:
        """Clients connected now."""
        return len(self._clients)

    @property
    def dropped(self) -> int:
        """Messages dropped so far: from full client queues (slow or vanished clients) and the outbox."""
        return self._dropped_gone + sum(c.dropped for c in list(self._clients)) + self.dropped_outbox

    # -- feeding (any thread) ----------------------------------------------------------------
    def channel(self, topic: str, type_name: str, latched: bool = False) -> int:
        """The server channel id of ``topic`` (``pkg/msg/Type``, cdr with its ros2msg schema),
        advertised to every client on first use."""
        with self._lock:
            sid = self._topics.get(topic)
            if sid is not None:
                return sid
            from ..recording import msgdefs
            sid = len(self._topics) + 1
            self._topics[topic] = sid
            advert = {'id': sid, 'topic': topic, 'encoding': 'cdr', 'schemaName': type_name,
                      'schema': msgdefs.full_text(type_name), 'schemaEncoding': 'ros2msg'}
            self._adverts[sid] = advert
            if latched:
                self._latched_ids.add(sid)
        self._call(self._advertise, advert)
        return sid

    def send(self, sid: int, t_ns: int, data: bytes):
        """One message on channel ``sid`` stamped ``t_ns`` (simulation time); returns at once."""
        if sid in self._latched_ids:
            self._latched[sid] = (t_ns, data)
        self._put((sid, t_ns, data))

    def send_records(self, records, offsets, sids, log_times):
        """Many messages in McapSink.write_records' layout (payload at ``offsets[k] + 31`` up to the
        next offset); sids: their server channel ids; returns at once (the array is not copied: the
        recorder does not reuse it)."""
        self._put((records, offsets, sids, log_times))

    def set_parameter(self, name: str, value):
        """A parameter's value changed (any thread): clients that subscribed to it hear of it."""
        self._params[name] = value
        self._call(self._parameter_changed, name, value)

    def status(self, client: int | None, level: int, message: str):
        """A status message (0 info, 1 warning, 2 error) to one client (by id) or all (None)."""
        self._call(self._status, client, level, message)

    def _put(self, item):
        outbox = self._outbox
        if len(outbox) == OUTBOX:
            self.dropped_outbox += 1
        outbox.append(item)
        if not self._kick_pending and self._loop is not None:
            self._kick_pending = True
            self._call(self._kick)

    def _call(self, fn, *args):
        loop = self._loop
        if loop is None:
            return
        try:
            loop.call_soon_threadsafe(fn, *args)
        except RuntimeError:   # closed
            pass

    # -- the loop -------------------------------------------------------------------------------
    def _thread_main(self):
        try:
            asyncio.run(self._main())
        except BaseException as e:   # reported to start() if it never got ready
            if not self._ready.is_set():
                self._failed = e
                self._ready.set()

    async def _main(self):
        from websockets.asyncio.server import serve
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        self._wake = asyncio.Event()
        log = logging.getLogger('robodyn_ros.live.websockets')
        log.addHandler(logging.NullHandler())
        log.propagate = False
        async with serve(self._session, sock=self.sock, subprotocols=list(SUBPROTOCOLS), compression=None,
                         max_size=MAX_INCOMING, logger=log, ping_interval=None, close_timeout=1.0):
            self._ready.set()
            pump = asyncio.create_task(self._pump())
            await self._stop.wait()
            pump.cancel()
            # what the run wrote last reaches the clients that keep reading (a vanished one: CLOSE_DRAIN s)
            while self._outbox:
                item = self._outbox.popleft()
                self._dispatch(*item) if len(item) == 3 else self._dispatch_records(*item)
            end = time.monotonic() + CLOSE_DRAIN
            while time.monotonic() < end and any(c.control or c.data for c in self._clients):
                await asyncio.sleep(0.01)
            for c in list(self._clients):
                await c.ws.close(1001, 'the simulation ended')

    def _kick(self):
        self._wake.set()

    async def _pace(self, spent: float):
        """Sleep in proportion to ``spent`` seconds of work (CPU_SHARE): CPU seconds of this thread, not
        wall time, which on a busy machine includes the waits for the CPU and the interpreter."""
        self._debt += spent * (1.0 / self.cpu_share - 1.0)
        if self._debt >= PACE_SLICE:
            d, self._debt = self._debt, 0.0
            await asyncio.sleep(d)

    async def _pump(self):
        """Move the outbox to the clients' queues (and the last-message cache)."""
        outbox = self._outbox
        while True:
            await self._wake.wait()
            self._wake.clear()
            self._kick_pending = False
            t0 = time.thread_time()
            while outbox:
                item = outbox.popleft()
                if len(item) == 3:
                    self._dispatch(*item)
                else:
                    self._dispatch_records(*item)
                now = time.thread_time()
                if now - t0 > PACE_SLICE:
                    await self._pace(now - t0)
                    t0 = time.thread_time()
            await self._pace(time.thread_time() - t0)

    def _tick(self, t_ns: int):
        """A Time frame to every client before the first message of another time (a later one; an
        earlier one after a reset, which Foxglove takes as a seek)."""
        self._time = t_ns
        frame = _TIME.pack(OP_TIME, t_ns)
        for c in self._clients:
            c.push_data(frame)
            c.event.set()

    def _dispatch(self, sid, t_ns, data):
        if t_ns != self._time:
            self._tick(t_ns)
        self._last[sid] = (t_ns, data)
        for c, subid in self._subs.get(sid, ()):
            c.push_data(_MSG_HEAD.pack(OP_MESSAGE_DATA, subid, t_ns) + data)
            c.event.set()

    def _dispatch_records(self, records, offsets, sids, log_times):
        n = len(offsets)
        ends = np.empty(n, dtype=np.int64)
        ends[:-1] = offsets[1:]
        ends[-1] = len(records)
        buf = memoryview(records)
        subs, last = self._subs, self._last
        for a, b, sid, t in zip((np.asarray(offsets) + 31).tolist(), ends.tolist(), np.asarray(sids).tolist(),
                                np.asarray(log_times).tolist()):
            if t != self._time:
                self._tick(t)
            data = bytes(buf[a:b])
            last[sid] = (t, data)
            for c, subid in subs.get(sid, ()):
                c.push_data(_MSG_HEAD.pack(OP_MESSAGE_DATA, subid, t) + data)
                c.event.set()

    def _advertise(self, advert):
        self._advertised.append(advert)
        text = json.dumps({'op': 'advertise', 'channels': [advert]})
        for c in self._clients:
            self._control(c, text)

    def _control(self, c: _Client, frame):
        c.control.append(frame)
        c.event.set()

    def _status(self, client, level, message):
        text = json.dumps({'op': 'status', 'level': int(level), 'message': str(message)})
        for c in self._clients:
            if client is None or c.id == client:
                self._control(c, text)

    def _parameter_changed(self, name, value):
        text = json.dumps({'op': 'parameterValues', 'parameters': [_param(name, value)]})
        for c in self._clients:
            if name in c.param_subs:
                self._control(c, text)

    async def _sender(self, c: _Client):
        """Send a client's control frames, then its data frames, as they come."""
        from websockets.exceptions import ConnectionClosed
        ws = c.ws
        try:
            while True:
                await c.event.wait()
                c.event.clear()
                while c.control or c.data:
                    t0 = time.thread_time()
                    while c.control:
                        await ws.send(c.control.popleft())
                    n = 0
                    while c.data and n < 64:
                        await ws.send(c.data.popleft())
                        n += 1
                    await self._pace(time.thread_time() - t0)
        except (ConnectionClosed, OSError):   # the client left; its session ends too
            return

    # -- a connection ----------------------------------------------------------------------------
    async def _session(self, ws):
        sock = ws.transport.get_extra_info('socket')
        if sock is not None:   # asyncio sets it only on sockets made with proto IPPROTO_TCP (create_server's are 0)
            try:   # without it the second of two small frames waits for the client's delayed ACK (40 ms)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass
        c = _Client(ws, self._next_client, self.queue_frames)
        self._next_client += 1
        self.clients_seen += 1
        info = {'op': 'serverInfo', 'name': self.name, 'capabilities': list(CAPABILITIES),
                'supportedEncodings': ['cdr'], 'metadata': {'ROS_DISTRO': 'jazzy'}, 'sessionId': self.session}
        self._control(c, json.dumps(info))
        if self._time >= 0:   # the simulation's time now (what the messages it gets on subscribing are stamped)
            self._control(c, _TIME.pack(OP_TIME, self._time))
        if self._advertised:
            self._control(c, json.dumps({'op': 'advertise', 'channels': list(self._advertised)}))
        if self.services:
            self._control(c, json.dumps({'op': 'advertiseServices', 'services': [
                {'id': k + 1, 'name': s.name, 'type': s.type,
                 'request': {'encoding': 'cdr', 'schemaName': s.type + '_Request', 'schemaEncoding': 'ros2msg',
                             'schema': s.request_schema},
                 'response': {'encoding': 'cdr', 'schemaName': s.type + '_Response', 'schemaEncoding': 'ros2msg',
                              'schema': s.response_schema},
                 'requestSchema': s.request_schema, 'responseSchema': s.response_schema}
                for k, s in enumerate(self.services)]}))
        self._clients.append(c)
        sender = asyncio.create_task(self._sender(c))
        try:
            async for message in ws:
                try:
                    if isinstance(message, str):
                        self._on_json(c, json.loads(message))
                    else:
                        self._on_binary(c, message)
                except (ValueError, KeyError, TypeError, IndexError, struct.error) as e:
                    self._control(c, json.dumps({'op': 'status', 'level': 2,
                                                 'message': f'robodyn_ros: bad request: {type(e).__name__}: {e}'}))
        except Exception as e:   # the connection broke (ConnectionClosed*, OSError): this client is done
            from websockets.exceptions import ConnectionClosed
            if not isinstance(e, (ConnectionClosed, OSError)):
                raise
        finally:
            sender.cancel()
            self._clients.remove(c)
            self._dropped_gone += c.dropped
            for sid in c.sub_for:
                self._subs[sid] = [(x, s) for x, s in self._subs.get(sid, ()) if x is not c]

    def _on_json(self, c: _Client, msg: dict):
        op = msg['op']
        if op == 'subscribe':
            for s in msg['subscriptions']:
                sid = int(s['channelId'])
                subid = int(s['id']) if s.get('id') is not None else sid
                if sid not in self._adverts or sid in c.sub_for or subid in c.sub_of:
                    self._control(c, json.dumps({'op': 'status', 'level': 1, 'message':
                                   f'robodyn_ros: subscription {subid} to channel {sid} ignored (unknown channel, '
                                   f'or already subscribed)'}))
                    continue
                c.sub_of[subid], c.sub_for[sid] = sid, subid
                self._subs[sid] = self._subs.get(sid, []) + [(c, subid)]
                held = self._latched.get(sid) if sid in self._latched_ids else self._last.get(sid)
                if held is not None:   # the last message at once (never dropped: the control queue)
                    self._control(c, _MSG_HEAD.pack(OP_MESSAGE_DATA, subid, held[0]) + held[1])
        elif op == 'unsubscribe':
            for subid in msg['subscriptionIds']:
                sid = c.sub_of.pop(int(subid), None)
                if sid is not None:
                    del c.sub_for[sid]
                    self._subs[sid] = [(x, s) for x, s in self._subs.get(sid, ()) if x is not c]
        elif op == 'advertise':
            for ch in msg['channels']:
                c.adverts[int(ch['id'])] = (str(ch['topic']), str(ch.get('schemaName', '')), str(ch['encoding']))
        elif op == 'unadvertise':
            for i in msg['channelIds']:
                c.adverts.pop(int(i), None)
        elif op == 'getParameters':
            names = msg.get('parameterNames') or list(self._params)
            out = {'op': 'parameterValues', 'parameters': [_param(n, self._params[n]) for n in names
                                                           if n in self._params]}
            if msg.get('id') is not None:
                out['id'] = msg['id']
            self._control(c, json.dumps(out))
        elif op == 'setParameters':
            for p in msg['parameters']:
                self.on_request(SetParameter(c.id, str(p['name']), p.get('value'),
                                             self._parameter_reply(c, str(p['name']), msg.get('id'))))
        elif op == 'subscribeParameterUpdates':
            c.param_subs.update(msg.get('parameterNames') or list(self._params))
        elif op == 'unsubscribeParameterUpdates':
            names = msg.get('parameterNames')
            c.param_subs.difference_update(names if names else set(c.param_subs))
        elif op == 'fetchAsset':
            asyncio.get_running_loop().create_task(self._fetch(c, str(msg['uri']), int(msg['requestId'])))
        else:
            self._control(c, json.dumps({'op': 'status', 'level': 1,
                                         'message': f'robodyn_ros: op {op!r} not supported'}))

    def _parameter_reply(self, c, name, request_id):
        def reply(value, error=None):   # any thread
            self._call(self._parameter_answer, c, name, value, error, request_id)
        return reply

    def _parameter_answer(self, c, name, value, error, request_id):
        if error:
            self._status(c.id, 2, error)
        if request_id is not None and c in self._clients:
            self._control(c, json.dumps({'op': 'parameterValues', 'parameters': [_param(name, value)],
                                         'id': request_id}))

    def _on_binary(self, c: _Client, data: bytes):
        op = data[0]
        if op == OP_CLIENT_MESSAGE:
            (cid,) = _U32.unpack_from(data, 1)
            if cid not in c.adverts:
                raise ValueError(f'message on channel {cid}, which this client did not advertise')
            topic, schema, encoding = c.adverts[cid]
            self.on_request(Publish(c.id, topic, schema, encoding, bytes(data[5:])))
        elif op == OP_SERVICE_REQUEST:
            service_id, call_id, n = struct.unpack_from('<III', data, 1)
            encoding = bytes(data[13:13 + n]).decode()
            payload = bytes(data[13 + n:])
            if not 1 <= service_id <= len(self.services) or encoding != 'cdr':
                self._control(c, json.dumps({'op': 'serviceCallFailure', 'serviceId': service_id, 'callId': call_id,
                                             'message': 'unknown service' if encoding == 'cdr' else
                                             f'encoding {encoding!r} not supported (cdr)'}))
                return
            s = self.services[service_id - 1]

            def reply(response: bytes, sid=service_id, call=call_id):   # any thread
                frame = struct.pack('<BIII', OP_SERVICE_RESPONSE, sid, call, 3) + b'cdr' + response
                self._call(self._control_if_connected, c, frame)
            self.on_request(ServiceCall(c.id, s.name, encoding, payload, reply))
        else:
            raise ValueError(f'unknown binary opcode {op}')

    def _control_if_connected(self, c, frame):
        if c in self._clients:
            self._control(c, frame)

    async def _fetch(self, c: _Client, uri: str, request_id: int):
        loop = asyncio.get_running_loop()
        try:
            data = await loop.run_in_executor(None, self.asset, uri)
            frame = struct.pack('<BIBI', OP_FETCH_ASSET_RESPONSE, request_id, 0, 0) + data
        except ValueError as e:   # robodyn_ros.assets.AssetError
            err = str(e).encode()
            frame = struct.pack('<BIBI', OP_FETCH_ASSET_RESPONSE, request_id, 1, len(err)) + err
        self._control_if_connected(c, frame)


def _param(name, value) -> dict:
    """A parameter entry of ``parameterValues`` (floats typed float64, as the spec allows)."""
    out = {'name': name, 'value': value}
    if isinstance(value, float):
        out['type'] = 'float64'
    return out


class LiveTap:
    """What a run's :class:`~robodyn_ros.recording.fanout.Fanout` feeds: its channel ids mapped to the
    server's (by topic, so that a node's episodes, each a new file numbering its channels from 1,
    stream on the same channels)."""

    def __init__(self, server: LiveServer):
        self.server = server
        self._map = np.zeros(8, dtype=np.int64)   # file channel id -> server channel id

    def add_channel(self, cid: int, topic: str, type_name: str, latched: bool):
        sid = self.server.channel(topic, type_name, latched)
        if cid >= len(self._map):
            self._map = np.concatenate([self._map, np.zeros(max(cid + 1, 2 * len(self._map)) - len(self._map),
                                                            dtype=np.int64)])
        self._map[cid] = sid

    def message(self, cid: int, t_ns: int, data: bytes):
        self.server.send(int(self._map[cid]), t_ns, data)

    def records(self, records, offsets, channels, log_times):
        self.server.send_records(records, np.asarray(offsets), self._map[np.asarray(channels)], np.asarray(log_times))
