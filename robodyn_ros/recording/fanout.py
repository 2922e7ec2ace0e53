"""Where a run's encoded records go: the MCAP file, live viewers, or both, with the same bytes.

:class:`~robodyn_ros.recording.run_sink.McapRunSink` encodes every message of a run once (canonical
CDR, simulation-time stamps) and hands the records to its ``writer``. Recording alone, that is the
:class:`~robodyn_ros.recording.mcap_sink.McapSink`; with taps (a live WebSocket server's, see
:mod:`robodyn_ros.live`), it is a :class:`Fanout` in front of it (or in place of it, when nothing is
recorded), which passes each record to the file and to every tap unchanged: the same payload bytes,
the same log time. The file is byte for byte what the McapSink alone writes (same calls in the
same order); the taps never change what it gets.

A tap is any object with::

    add_channel(cid, topic, type_name, latched)   # a topic's first record comes (canonical type)
    message(cid, log_time_ns, data)                # one record: its CDR payload
    records(records, offsets, channels, log_times) # many: each payload at offsets[k] + 31 up to the
                                                   # next offset (McapSink.write_records' layout)

Channel ids are the file's (1, 2, ... in order of first use, as McapSink assigns them); without a
file this class numbers them the same way.
"""
from __future__ import annotations

from typing import Optional

from . import cdr, msgdefs
from .mcap_sink import TRANSIENT_LOCAL_TOPICS, McapSink

__all__ = ['Fanout', 'RECORD_HEADER']

#: bytes of the record header before each payload in :meth:`McapSink.write_records`' layout
RECORD_HEADER = 31


def _latched(topic: str, qos: Optional[str]) -> bool:
    """True for a transient-local topic (McapSink.add_topic's rule: robot_description, /tf_static)."""
    if qos is not None:
        return qos == 'transient_local'
    return topic.rstrip('/').rsplit('/', 1)[-1] in TRANSIENT_LOCAL_TOPICS


class Fanout:
    """McapSink's writing interface, feeding an optional McapSink and any taps the same records.

    mcap: the file's sink, or None (live only); taps: see the module docstring.
    """

    def __init__(self, mcap: Optional[McapSink], taps=()):
        self.mcap = mcap
        self.taps = tuple(taps)
        self.path = None if mcap is None else mcap.path
        self._channels = {} if mcap is None else mcap._channels   # topic -> channel id (shared with the file's)
        self._types = {}
        self._known = {}
        self._closed = False
        self.message_count = 0

    def add_topic(self, topic: str, type_name: str, qos: Optional[str] = None) -> int:
        """Register a topic (see :meth:`McapSink.add_topic`); the taps hear of it on first use."""
        self._check_open()
        new = topic not in self._channels
        if self.mcap is not None:
            cid = self.mcap.add_topic(topic, type_name, qos)
            canonical = self.mcap._types[topic]
        else:
            canonical = msgdefs.canonical_name(type_name)
            if qos not in (None, 'default', 'transient_local'):
                raise ValueError(f"qos must be 'default' or 'transient_local', got {qos!r}")
            if not new:
                if self._types[topic] != canonical:
                    raise ValueError(f'topic {topic!r} already has type {self._types[topic]}, not {canonical}')
                return self._channels[topic]
            cid = len(self._channels) + 1
            self._channels[topic] = cid
            self._types[topic] = canonical
        if new:
            for t in self.taps:
                t.add_channel(cid, topic, canonical, _latched(topic, qos))
        return cid

    def channel(self, topic: str, type_name: str) -> int:
        """The channel id of ``topic`` (registered on first use)."""
        known = self._known.get((topic, type_name))
        if known is None:
            known = self._known[(topic, type_name)] = self.add_topic(topic, type_name)
        return known

    def write(self, topic: str, type_name: str, msg, log_time_ns: int, publish_time_ns: Optional[int] = None):
        """Encode (unless ``msg`` is bytes) and write one message (see :meth:`McapSink.write`)."""
        cid = self.channel(topic, type_name)
        canonical = self.mcap._types[topic] if self.mcap is not None else self._types[topic]
        data = bytes(msg) if isinstance(msg, (bytes, bytearray, memoryview)) else cdr.encode(canonical, msg)
        self.write_data(cid, data, log_time_ns, publish_time_ns)

    def write_data(self, channel_id: int, data: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None):
        """One encoded record to the file and the taps (see :meth:`McapSink.write_data`)."""
        if self._closed:
            self._check_open()
        if self.mcap is not None:
            self.mcap.write_data(channel_id, data, log_time_ns, publish_time_ns)
        t = int(log_time_ns)
        for tap in self.taps:
            tap.message(channel_id, t, data)
        self.message_count += 1

    def write_records(self, records, offsets, channels, log_times):
        """Many records in :meth:`McapSink.write_records`' layout to the file and the taps."""
        if self._closed:
            self._check_open()
        if self.mcap is not None:
            self.mcap.write_records(records, offsets, channels, log_times)
        if len(offsets):
            for tap in self.taps:
                tap.records(records, offsets, channels, log_times)
        self.message_count += len(offsets)

    def room(self):
        """The file's :meth:`McapSink.room`; None without a file."""
        return None if self.mcap is None else self.mcap.room()

    def flush(self):
        """Hand the file's open chunk to the OS (nothing to do for the taps)."""
        if self.mcap is not None:
            self.mcap.flush()

    def close(self):
        """Finish the file (the taps stay: a live server outlives a node's episodes); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self.mcap is not None:
            self.mcap.close()

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self):
        if self._closed:
            raise ValueError(f'the writer of {self.path or "a live run"} is closed')
