"""A Foxglove WebSocket client for the tests, written from the protocol's specification
(github.com/foxglove/ws-protocol, docs/spec.md: "Foxglove WebSocket protocol v1") on the
``websockets`` package's synchronous client; nothing of robodyn_ros.live is used.

Frames (all integers little-endian):

* server -> client text: JSON with ``op``: serverInfo, status, advertise, unadvertise,
  parameterValues, advertiseServices, serviceCallFailure;
* server -> client binary: 0x01 message data (uint32 subscription id, uint64 receive timestamp ns,
  payload), 0x02 time (uint64 ns), 0x03 service call response (uint32 service id, uint32 call id,
  uint32 encoding length, encoding, payload), 0x04 fetch asset response (uint32 request id, uint8
  status, uint32 error length, error, data);
* client -> server text: subscribe, unsubscribe, advertise, unadvertise, getParameters,
  setParameters, subscribeParameterUpdates, fetchAsset;
* client -> server binary: 0x01 client message data (uint32 channel id, payload), 0x02 service call
  request (uint32 service id, uint32 call id, uint32 encoding length, encoding, payload).
"""
from __future__ import annotations

import json
import struct
import time

from websockets.sync.client import connect

V1 = 'foxglove.websocket.v1'
SDK = 'foxglove.sdk.v1'


class Client:
    """One connection; every frame received is kept (``frames``) and interpreted as it comes.

    messages: ``[(topic, receive timestamp ns, payload bytes)]`` of the subscribed channels, in
    arrival order; times: the time frames' ns; channels: id -> advertised channel dict; services:
    name -> advertised service dict; statuses: status messages; info: the serverInfo.
    """

    def __init__(self, url: str, subprotocol: str = V1, timeout: float = 30.0):
        self._connection = connect(url, subprotocols=[subprotocol], max_size=None, open_timeout=timeout)
        self.ws = self._connection.__enter__()
        self.subprotocol = self.ws.subprotocol
        self.info = None
        self.channels, self.services, self.statuses = {}, {}, []
        self.messages, self.times, self.parameter_values = [], [], []
        self.subscriptions = {}         # subscription id -> channel id
        self.responses, self.failures, self.assets = {}, {}, {}
        self.order = []                 # ('time', t) / ('message', topic, t) in arrival order
        self.closed = False
        self._next_sub, self._next_chan, self._next_call, self._next_asset = 1, 1, 1, 1
        self.pump_until(lambda: self.info is not None, timeout)

    # -- receiving -------------------------------------------------------------------------
    def _handle(self, frame):
        if isinstance(frame, str):
            msg = json.loads(frame)
            op = msg['op']
            if op == 'serverInfo':
                self.info = msg
            elif op == 'advertise':
                for ch in msg['channels']:
                    self.channels[ch['id']] = ch
            elif op == 'unadvertise':
                for i in msg['channelIds']:
                    self.channels.pop(i, None)
            elif op == 'advertiseServices':
                for s in msg['services']:
                    self.services[s['name']] = s
            elif op == 'status':
                self.statuses.append(msg)
            elif op == 'parameterValues':
                self.parameter_values.append(msg)
            elif op == 'serviceCallFailure':
                self.failures[msg['callId']] = msg['message']
            return
        op = frame[0]
        if op == 0x01:
            sub, t = struct.unpack_from('<IQ', frame, 1)
            topic = self.channels[self.subscriptions[sub]]['topic']
            self.messages.append((topic, t, bytes(frame[13:])))
            self.order.append(('message', topic, t))
        elif op == 0x02:
            (t,) = struct.unpack_from('<Q', frame, 1)
            self.times.append(t)
            self.order.append(('time', t))
        elif op == 0x03:
            service, call, n = struct.unpack_from('<III', frame, 1)
            self.responses[call] = (bytes(frame[13:13 + n]).decode(), bytes(frame[13 + n:]))
        elif op == 0x04:
            req, status, n = struct.unpack_from('<IBI', frame, 1)
            self.assets[req] = (status, bytes(frame[10:10 + n]).decode(), bytes(frame[10 + n:]))
        else:
            raise AssertionError(f'unknown binary opcode {op}')

    def pump(self, timeout: float) -> bool:
        """Handle the frames that arrive within ``timeout`` s of each other; False once the server closed."""
        from websockets.exceptions import ConnectionClosed
        try:
            while True:
                self._handle(self.ws.recv(timeout=timeout))
        except TimeoutError:
            return True
        except ConnectionClosed:
            self.closed = True
            return False

    def pump_until(self, cond, timeout: float = 30.0) -> bool:
        """Handle frames until ``cond()`` holds (True) or ``timeout`` s pass or the server closes (False)."""
        from websockets.exceptions import ConnectionClosed
        end = time.monotonic() + timeout
        while not cond():
            left = end - time.monotonic()
            if left <= 0:
                return False
            try:
                self._handle(self.ws.recv(timeout=min(left, 1.0)))
            except TimeoutError:
                continue
            except ConnectionClosed:
                self.closed = True
                return cond()
        return True

    def until_closed(self, timeout: float = 60.0) -> bool:
        """Handle frames until the server closes the connection (True) or ``timeout`` s pass."""
        return self.pump_until(lambda: self.closed, timeout)

    # -- requests ----------------------------------------------------------------------------
    def send_json(self, **msg):
        self.ws.send(json.dumps(msg))

    def subscribe(self, topics=None):
        """Subscribe to the advertised channels (of ``topics``, or all); returns their topics."""
        subs = []
        for cid, ch in sorted(self.channels.items()):
            if (topics is None or ch['topic'] in topics) and cid not in self.subscriptions.values():
                self.subscriptions[self._next_sub] = cid
                subs.append({'id': self._next_sub, 'channelId': cid})
                self._next_sub += 1
        if subs:
            self.send_json(op='subscribe', subscriptions=subs)
        return [self.channels[s['channelId']]['topic'] for s in subs]

    def advertise(self, topic: str, schema_name: str, encoding: str = 'cdr') -> int:
        cid = self._next_chan
        self._next_chan += 1
        self.send_json(op='advertise', channels=[{'id': cid, 'topic': topic, 'encoding': encoding,
                                                  'schemaName': schema_name}])
        return cid

    def publish(self, channel: int, payload: bytes):
        self.ws.send(struct.pack('<BI', 0x01, channel) + payload)

    def call(self, name: str, payload: bytes, timeout: float = 30.0) -> bytes:
        """Call an advertised service with a CDR request; the response payload (AssertionError on a failure)."""
        service = self.services[name]
        call = self._next_call
        self._next_call += 1
        self.ws.send(struct.pack('<BIII', 0x02, service['id'], call, 3) + b'cdr' + payload)
        assert self.pump_until(lambda: call in self.responses or call in self.failures, timeout), f'{name}: no answer'
        assert call not in self.failures, self.failures[call]
        encoding, data = self.responses[call]
        assert encoding == 'cdr'
        return data

    def fetch_asset(self, uri: str, timeout: float = 30.0):
        req = self._next_asset
        self._next_asset += 1
        self.send_json(op='fetchAsset', uri=uri, requestId=req)
        assert self.pump_until(lambda: req in self.assets, timeout), f'no answer for {uri}'
        return self.assets[req]

    def close(self):
        self._connection.__exit__(None, None, None)


# -- CDR of the two std_srvs services (the request and response layouts of std_srvs' .srv files) --
def set_bool_request(data: bool) -> bytes:
    """CDR (little-endian) of std_srvs/srv/SetBool_Request."""
    return b'\x00\x01\x00\x00' + struct.pack('<?', data)


def trigger_request() -> bytes:
    """CDR of std_srvs/srv/Trigger_Request (an empty message: one placeholder byte)."""
    return b'\x00\x01\x00\x00\x00'


def response_fields(payload: bytes):
    """``(success, message)`` of a CDR Trigger_Response / SetBool_Response."""
    assert payload[:4] == b'\x00\x01\x00\x00', payload[:4]
    success = payload[4] != 0
    (n,) = struct.unpack_from('<I', payload, 8)
    return success, payload[12:12 + n - 1].decode()
