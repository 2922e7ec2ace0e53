"""McapSink: the recorder the simulator calls, writing a rosbag2-layout MCAP file.

Layout (GUIDE section 2): profile ``ros2``; one schema per message type, named ``pkg/msg/Type``,
encoding ``ros2msg`` with the full definition text; one channel per topic, message encoding
``cdr``, channel metadata ``offered_qos_profiles`` (rosbag2 v9 YAML) and ``topic_type_hash``
as rosbag2 Jazzy writes them; a metadata record ``robodyn`` with the caller's key/values;
``log_time`` = simulation time in ns.

Determinism: nothing here reads the wall clock. Schema and channel ids are assigned 1, 2, ... in
order of first use, sequence numbers count per channel from 1, metadata keys are sorted, and the
library string depends only on package versions. zstd (via the ``zstandard`` module that ``mcap``
requires) is deterministic for a given input and level, so equal runs give byte-identical files.

Crash safety: chunks are closed by this class (not by ``mcap.Writer``'s own size check) once the
open chunk holds ``chunk_size`` bytes of message records, and every closed chunk, with its message
indexes, is handed to the operating system at once (optionally fsync'ed). A process killed with
SIGKILL therefore leaves a file whose every closed chunk is readable by
:func:`robodyn_ros.recording.reader.read_messages`; only the open chunk is lost.
"""
import os
from typing import Dict, Optional

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER as MCAP_LIBRARY
from mcap.writer import CompressionType, Writer

from ..version import __version__
from . import cdr, msgdefs

#: Name of the metadata record holding scene text, integrator settings and package version.
METADATA_NAME = 'robodyn'
#: Topics (last name component) recorded with transient-local durability, like a latched topic.
TRANSIENT_LOCAL_TOPICS = ('robot_description',)
#: Bytes of message records per chunk: small, so a crash loses little.
DEFAULT_CHUNK_SIZE = 64 * 1024
#: Bytes a Message record adds to its payload: opcode 1 + length 8 + channel 2 + sequence 4
#: + log_time 8 + publish_time 8.
_MESSAGE_RECORD_OVERHEAD = 31
_COMPRESSIONS = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                 'none': CompressionType.NONE, None: CompressionType.NONE}

# rmw's "infinite" duration as rosbag2 writes it.
_INFINITE = '    sec: 9223372036\n    nsec: 854775807'


def qos_yaml(durability: str = 'volatile', depth: int = 10) -> str:
    """Return one offered QoS profile as rosbag2 (metadata version 9, Jazzy) serialises it.

    The text is what yaml-cpp's ``Dump`` produces for ``[QoS]``: a one-item sequence, keep-last
    history, reliable, default deadline/lifespan/lease (infinite), automatic liveliness.

    Args:
        durability: ``'volatile'`` or ``'transient_local'``.
        depth: history depth.
    """
    if durability not in ('volatile', 'transient_local'):
        raise ValueError(f'durability must be volatile or transient_local, got {durability!r}')
    return (f'- history: keep_last\n'
            f'  depth: {int(depth)}\n'
            f'  reliability: reliable\n'
            f'  durability: {durability}\n'
            f'  deadline:\n{_INFINITE}\n'
            f'  lifespan:\n{_INFINITE}\n'
            f'  liveliness: automatic\n'
            f'  liveliness_lease_duration:\n{_INFINITE}\n'
            f'  avoid_ros_namespace_conventions: false')


def library_string() -> str:
    """Return the MCAP header's library string (package versions only: deterministic)."""
    return f'robodyn_ros/{__version__} {MCAP_LIBRARY}'


class McapSink:
    """Record ROS 2 messages, stamped with simulation time, into an MCAP file.

    Use as a context manager, or call :meth:`close` (idempotent) when done; the nodes and CLI
    call it on shutdown and on SIGINT/SIGTERM. Attributes ``message_count`` (messages accepted)
    and ``flushed_message_count`` (messages in chunks already handed to the OS) report progress.
    """

    def __init__(self, path, metadata: Optional[Dict[str, str]] = None,
                 chunk_size: int = DEFAULT_CHUNK_SIZE, compression: Optional[str] = 'zstd',
                 fsync: bool = False):
        """Create (truncate) the file and write the header and the ``robodyn`` metadata record.

        Args:
            path: output file path (``str`` or path-like).
            metadata: key/value strings for the ``robodyn`` metadata record (scene file text,
                integrator settings, package version, ...); keys are written sorted.
            chunk_size: bytes of message records after which the open chunk is closed and
                written out; the most a crash can lose.
            compression: ``'zstd'`` (default), ``'lz4'``, or ``'none'``/None, per chunk.
            fsync: also ``os.fsync`` after each chunk (survives power loss, not only a killed
                process; slower).
        """
        if compression not in _COMPRESSIONS:
            raise ValueError(f'compression must be one of zstd, lz4, none; got {compression!r}')
        if chunk_size <= 0:
            raise ValueError(f'chunk_size must be positive, got {chunk_size}')
        metadata = dict(metadata or {})
        for key, value in metadata.items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise TypeError(f'metadata keys and values must be str, got {key!r}: {value!r}')
        self.path = os.fspath(path)
        self.chunk_size = int(chunk_size)
        self.fsync = fsync
        self._file = open(self.path, 'wb')
        # chunk_size for mcap.Writer is effectively infinite: this class closes chunks itself
        # (see _maybe_close_chunk) so it knows exactly when a chunk reached the OS.
        self._writer = Writer(self._file, chunk_size=2 ** 62,
                              compression=_COMPRESSIONS[compression])
        self._schemas: Dict[str, int] = {}
        self._channels: Dict[str, int] = {}
        self._types: Dict[str, str] = {}
        self._sequence: Dict[int, int] = {}
        self._open_chunk_bytes = 0
        self._closed = False
        self.message_count = 0
        self.flushed_message_count = 0
        self.chunk_count = 0
        self._writer.start(profile='ros2', library=library_string())
        self.add_metadata(METADATA_NAME, metadata)

    def add_metadata(self, name: str, data: Dict[str, str]):
        """Write a metadata record (outside chunks, so it is on disk at once).

        Args:
            name: record name, e.g. ``robodyn``.
            data: key/value strings; written with keys sorted.
        """
        self._check_open()
        self._writer.add_metadata(name, {k: data[k] for k in sorted(data)})
        self._file.flush()

    def add_topic(self, topic: str, type_name: str, qos: Optional[str] = None) -> int:
        """Register a topic (schema on first use of its type, then a channel); return channel id.

        Args:
            topic: topic name as published (relative names stay relative).
            type_name: ``pkg/msg/Type`` or ``pkg/Type``.
            qos: ``'default'`` (reliable, volatile, depth 10) or ``'transient_local'`` (depth 1);
                None picks transient_local for ``robot_description`` and default otherwise.

        Raises:
            ValueError: the topic is already registered with another type, or qos is unknown.
        """
        self._check_open()
        type_name = msgdefs.canonical_name(type_name)
        if topic in self._channels:
            if self._types[topic] != type_name:
                raise ValueError(f'topic {topic!r} already has type {self._types[topic]}, '
                                 f'not {type_name}')
            return self._channels[topic]
        if qos is None:
            last = topic.rstrip('/').rsplit('/', 1)[-1]
            qos = 'transient_local' if last in TRANSIENT_LOCAL_TOPICS else 'default'
        if qos == 'default':
            profile = qos_yaml('volatile', 10)
        elif qos == 'transient_local':
            profile = qos_yaml('transient_local', 1)
        else:
            raise ValueError(f"qos must be 'default' or 'transient_local', got {qos!r}")
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            schema_id = self._writer.register_schema(
                name=type_name, encoding=SchemaEncoding.ROS2,
                data=msgdefs.full_text(type_name).encode('utf-8'))
            self._schemas[type_name] = schema_id
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=MessageEncoding.CDR, schema_id=schema_id,
            metadata={'offered_qos_profiles': profile,
                      'topic_type_hash': msgdefs.type_hash(type_name)})
        self._channels[topic] = channel_id
        self._types[topic] = type_name
        self._sequence[channel_id] = 0
        return channel_id

    def write(self, topic: str, type_name: str, msg, log_time_ns: int,
              publish_time_ns: Optional[int] = None):
        """Encode and record one message.

        Args:
            topic: topic name; registered on first use (see :meth:`add_topic`).
            type_name: ``pkg/msg/Type`` or ``pkg/Type``.
            msg: dict or attribute object (see :func:`robodyn_ros.recording.cdr.encode`), or
                ``bytes`` already holding canonical CDR (written unchanged).
            log_time_ns: simulation time of the message in ns (never the wall clock).
            publish_time_ns: publication time in ns; defaults to ``log_time_ns``.
        """
        self._check_open()
        channel_id = self.add_topic(topic, type_name)
        data = bytes(msg) if isinstance(msg, (bytes, bytearray, memoryview)) else \
            cdr.encode(self._types[topic], msg)
        log_time_ns = int(log_time_ns)
        if log_time_ns < 0:
            raise ValueError(f'log_time_ns must be >= 0, got {log_time_ns}')
        self._sequence[channel_id] += 1
        self._writer.add_message(
            channel_id=channel_id, log_time=log_time_ns, data=data,
            publish_time=log_time_ns if publish_time_ns is None else int(publish_time_ns),
            sequence=self._sequence[channel_id])
        self.message_count += 1
        self._open_chunk_bytes += _MESSAGE_RECORD_OVERHEAD + len(data)
        if self._open_chunk_bytes >= self.chunk_size:
            self.flush()

    def flush(self):
        """Close the open chunk (if it holds messages) and hand everything written to the OS."""
        self._check_open()
        # mcap.Writer.flush: finalize the chunk and its message indexes, then flush the stream.
        self._writer.flush()
        if self._open_chunk_bytes:
            self.chunk_count += 1
        self._open_chunk_bytes = 0
        self.flushed_message_count = self.message_count
        if self.fsync:
            os.fsync(self._file.fileno())

    def close(self):
        """Finish the file (last chunk, summary, footer) and close it; later calls do nothing."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._open_chunk_bytes:
                self.chunk_count += 1
            self._writer.finish()
            self.flushed_message_count = self.message_count
            self._file.flush()
            if self.fsync:
                os.fsync(self._file.fileno())
        finally:
            self._file.close()

    def _check_open(self):
        """Raise ValueError when the sink was closed."""
        if self._closed:
            raise ValueError(f'McapSink for {self.path} is closed')

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    def __enter__(self):
        """Return self (the file is already open)."""
        return self

    def __exit__(self, exc_type, exc, tb):
        """Finish and close the file, also when the block raised."""
        self.close()
