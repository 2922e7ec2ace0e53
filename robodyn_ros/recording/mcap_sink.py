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
:func:`robodyn_ros.recording.reader.read_messages`; only the open chunk is lost. With
``chunk_span`` a chunk is also closed once it spans that much log (simulation) time, which bounds
the loss in time as well (the node uses 0.5 s).

Speed: :meth:`McapSink.write_records` takes many complete message records at once (the batched
recorder of headless runs); headers, sequence numbers, chunk boundaries and message indexes are
those of message-by-message writing, byte for byte.
"""
import io
import os
import struct
import zlib
from typing import Dict, Optional

import numpy as np

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER as MCAP_LIBRARY
from mcap.writer import CompressionType, Writer

from ..kernels.records import fill_headers, group_by_channel
from ..version import __version__
from . import cdr, chunk_cache, msgdefs

#: Name of the metadata record holding scene text, integrator settings and package version.
METADATA_NAME = 'robodyn'
#: Topics (last name component) recorded with transient-local durability, like a latched topic.
TRANSIENT_LOCAL_TOPICS = ('robot_description',)
#: Bytes of message records per chunk: what the MCAP C++ writer (and so ``ros2 bag record -s mcap``)
#: uses by default, 768 KiB. A crash loses at most the open chunk (the node also closes one every
#: 0.5 s of simulation).
DEFAULT_CHUNK_SIZE = 768 * 1024
#: zstd level of the chunks: the MCAP C++ writer's ``CompressionLevel::Default`` (rosbag2's), 1.
#: Level 3 (what ``mcap.Writer`` calls, ``zstandard.compress``) writes the same size in 1.6x the time.
ZSTD_LEVEL = 1
#: Bytes a Message record adds to its payload: opcode 1 + length 8 + channel 2 + sequence 4
#: + log_time 8 + publish_time 8.
_MESSAGE_RECORD_OVERHEAD = 31
_MESSAGE_INDEX_OPCODE = 7
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


class _DirectMessages:
    """Message records written straight into ``mcap.Writer``'s open chunk, byte for byte as
    ``Writer.add_message`` writes them.

    ``Writer.add_message`` builds a ``Message`` record object and writes it field by field through
    the chunk's ``RecordBuilder`` (about 2.5 µs per message, the largest part of recording a
    publication). This writes the same record with one ``struct.pack`` and does the same
    bookkeeping: the chunk's time range and message index, the file's statistics. It relies on
    private attributes of mcap's Writer and ChunkBuilder (mcap is pinned in constraints.txt);
    :meth:`attach` checks that they exist *and* that a test file written both ways is identical
    (once per process), else returns None and the sink keeps calling ``Writer.add_message``.
    Chunks are compressed at ``level`` (:data:`ZSTD_LEVEL`; the self-test uses mcap.Writer's 3). In
    the fallback, mcap.Writer compresses them itself at level 3: the same records, other bytes.
    """

    #: opcode, record length, channel id, sequence, log time, publish time
    HEAD = struct.Struct('<BQHIQQ')
    _verified: Optional[bool] = None

    #: chunk record up to the compression string: opcode, length, start, end, uncompressed size,
    #: uncompressed crc, compression string length
    CHUNK_HEAD = struct.Struct('<BQQQQII')

    def __init__(self, writer: Writer, level: Optional[int] = None):
        self.writer = writer
        level = ZSTD_LEVEL if level is None else level
        self.stats = writer._Writer__statistics
        self.chunk = writer._Writer__chunk_builder
        self.chunk_size = writer._Writer__chunk_size
        self.stream = writer._Writer__stream
        self.crcs = writer._Writer__enable_crcs
        from mcap.opcode import Opcode
        from mcap.records import MessageIndex
        from mcap.writer import IndexType
        self.opcode = int(Opcode.MESSAGE)
        self.chunk_opcode = int(Opcode.CHUNK)
        self.chunk_index_opcode = int(Opcode.CHUNK_INDEX)
        self.MessageIndex = MessageIndex
        self.index_message = bool(writer._Writer__index_types & IndexType.MESSAGE)
        kind = writer._Writer__compression
        self.compression = {CompressionType.ZSTD: 'zstd', CompressionType.LZ4: 'lz4', CompressionType.NONE: ''}[kind]
        if self.compression == 'zstd':
            import zstandard
            self._zstd = zstandard.ZstdCompressor(level=level)
            self._level = level
            self._zstandard = zstandard
        elif self.compression == 'lz4':
            import lz4.frame
            self._lz4 = lz4.frame.compress
        if not (isinstance(self.chunk.record_writer._buffer, io.BytesIO)
                and hasattr(self.stats, 'channel_message_counts') and isinstance(self.chunk.message_indices, dict)):
            raise AttributeError('unexpected mcap.Writer internals')

    @classmethod
    def attach(cls, writer: Writer):
        """The direct writer for ``writer``, or None when mcap's internals are not the expected ones."""
        if cls._verified is None:
            cls._verified = cls._self_test()
        if not cls._verified:
            return None
        try:
            return cls(writer)
        except (AttributeError, TypeError):
            return None

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int):
        """``Writer.add_message(channel_id, log_time, data, publish_time, sequence)``."""
        st = self.stats
        if st.message_count == 0:
            st.message_start_time = log_time
        else:
            st.message_start_time = min(log_time, st.message_start_time)
        st.message_end_time = max(log_time, st.message_end_time)
        st.channel_message_counts[channel_id] += 1
        st.message_count += 1
        cb = self.chunk
        if cb.num_messages == 0:
            cb.message_start_time = log_time
        else:
            cb.message_start_time = min(cb.message_start_time, log_time)
        cb.message_end_time = max(cb.message_end_time, log_time)
        index = cb.message_indices.get(channel_id)
        if not index:
            index = cb.message_indices[channel_id] = self.MessageIndex(channel_id=channel_id, records=[])
        buf = cb.record_writer._buffer  # replaced by a new BytesIO whenever a chunk ends
        index.records.append((log_time, buf.tell()))
        cb.num_messages += 1
        buf.write(self.HEAD.pack(self.opcode, 22 + len(data), channel_id, sequence, log_time, publish_time))
        buf.write(data)
        if buf.tell() > self.chunk_size:  # Writer.__maybe_finalize_chunk
            self.writer._Writer__finalize_chunk()

    def flush(self):
        """``Writer.flush()``: close the open chunk (if it holds messages), write it with its
        message indexes, hand everything to the stream. The same records as mcap's
        ``__finalize_chunk``, but zstd through one reused compressor (``zstandard.compress``
        builds a new one per chunk, about a fifth of the compression time of a 64 KiB chunk;
        the bytes are the same) and the chunk record written in one piece."""
        w, cb = self.writer, self.chunk
        if cb.num_messages:
            self.stats.chunk_count += 1
            raw = cb.end()
            if self.compression == 'zstd':   # (a large chunk written before comes from chunk_cache: the same bytes)
                data, crc = chunk_cache.compress_zstd(raw, self._zstd, self._level, self._zstandard.__version__)
            else:
                data = self._lz4(raw) if self.compression == 'lz4' else raw
                crc = zlib.crc32(raw)
            if not self.crcs:
                crc = 0
            flush = w._Writer__flush
            rb = w._Writer__record_builder
            flush()
            start = self.stream.tell()
            comp = self.compression.encode()
            head = self.CHUNK_HEAD.pack(self.chunk_opcode, 8 * 3 + 4 + 4 + len(comp) + 8 + len(data),
                                        cb.message_start_time, cb.message_end_time, len(raw), crc, len(comp))
            rb.write(head + comp + struct.pack('<Q', len(data)))
            rb.write(data)
            chunk_length = rb.count
            flush()
            index_start = self.stream.tell()
            offsets = []
            if self.index_message:
                for cid, idx in cb.message_indices.items():
                    offsets.append((cid, index_start + rb.count))
                    idx.write(rb)
            message_index_length = rb.count
            flush()
            # the summary's ChunkIndex record, kept as its bytes (ChunkIndex.write's), not as an object
            body = [struct.pack('<QQQQI', cb.message_start_time, cb.message_end_time, start, chunk_length,
                                10 * len(offsets))]
            body += [struct.pack('<HQ', cid, off) for cid, off in offsets]
            body.append(struct.pack('<QI', message_index_length, len(comp)) + comp +
                        struct.pack('<QQ', len(data), len(raw)))
            body = b''.join(body)
            indices = w._Writer__chunk_indices
            if not (indices and isinstance(indices[-1], _ChunkIndexRecords)):
                indices.append(_ChunkIndexRecords())
            indices[-1].add(struct.pack('<BQ', self.chunk_index_opcode, len(body)) + body)
            cb.reset()
        w._Writer__flush()
        self.stream.flush()

    def add_records(self, data, offsets, channels, log_times):
        """Append complete message records (headers filled) to the open chunk in one write.

        data: the records' bytes, back to back; offsets: (n,) start of each record in data;
        channels, log_times: (n,) of each record, in order. The same bytes, message index
        entries, chunk time range and file statistics as n calls of :meth:`add_message`.
        """
        n = len(offsets)
        if n == 0:
            return
        lo, hi = int(log_times.min()), int(log_times.max())
        st = self.stats
        st.message_start_time = lo if st.message_count == 0 else min(lo, st.message_start_time)
        st.message_end_time = max(hi, st.message_end_time)
        st.message_count += n
        cb = self.chunk
        cb.message_start_time = lo if cb.num_messages == 0 else min(cb.message_start_time, lo)
        cb.message_end_time = max(cb.message_end_time, hi)
        cb.num_messages += n
        buf = cb.record_writer._buffer
        base = buf.tell()
        buf.write(data)
        counts = st.channel_message_counts
        indices = cb.message_indices
        # entries grouped by channel (stable: in time order within a channel), channels in order of
        # first appearance (the dict insertion order add_message gives)
        entries = np.empty((n, 2), dtype='<u8')
        group_channel = np.empty(n, dtype=np.int64)
        group_start = np.empty(n + 1, dtype=np.int64)
        g = group_by_channel(np.ascontiguousarray(channels, dtype=np.int64), np.ascontiguousarray(log_times, dtype=np.int64),
                             np.ascontiguousarray(offsets, dtype=np.int64), base, entries, group_channel, group_start)
        bounds = group_start[:g + 1].tolist()
        for i, c in enumerate(group_channel[:g].tolist()):
            a, b = bounds[i], bounds[i + 1]
            counts[c] += b - a
            index = indices.get(c)
            if not isinstance(index, _BulkIndex):
                index = indices[c] = _BulkIndex(c, index.records if index else [])
            index.add(entries[a:b])

    @classmethod
    def _self_test(cls) -> bool:
        """True when a small file written through this class (one message at a time, and in
        bulk) equals the one ``add_message`` writes."""
        msgs = [(1, 5), (2, 3), (1, 7), (2, 7), (1, 2), (2, 9), (2, 4), (1, 8)]

        def write(how: str) -> bytes:
            f = io.BytesIO()
            w = Writer(f, chunk_size=2 ** 62, compression=CompressionType.ZSTD)
            w.start(profile='ros2', library='self-test')
            sid = w.register_schema(name='a/msg/B', encoding=SchemaEncoding.ROS2, data=b'float64 x')
            c1 = w.register_channel(topic='/a', message_encoding=MessageEncoding.CDR, schema_id=sid)
            c2 = w.register_channel(topic='/b', message_encoding=MessageEncoding.CDR, schema_id=sid)
            ids = {1: c1, 2: c2}
            d = cls(w, level=3) if how != 'writer' else None   # zstandard.compress's level, as mcap.Writer
            pending = []

            def bulk():
                if pending:
                    data = b''.join(cls.HEAD.pack(d.opcode, 22 + len(x), c, q, t, t) + x for c, t, x, q in pending)
                    sizes = np.array([31 + len(x) for _, _, x, _ in pending])
                    d.add_records(data, np.concatenate([[0], np.cumsum(sizes)[:-1]]),
                                  np.array([c for c, _, _, _ in pending]), np.array([t for _, t, _, _ in pending]))
                    pending.clear()
            for k, (c, t) in enumerate(msgs):
                data = bytes(range(k + 3))
                if how == 'writer':
                    w.add_message(channel_id=ids[c], log_time=t, data=data, publish_time=t, sequence=k)
                elif how == 'direct' or k in (1, 5):   # bulk: mixed with single records
                    bulk()
                    d.add_message(ids[c], t, data, t, k)
                else:
                    pending.append((ids[c], t, data, k))
                if k in (2, 6):
                    bulk()
                    d.flush() if d is not None else w.flush()
            bulk()
            w.finish()
            return f.getvalue()
        try:
            ref = write('writer')
            return write('direct') == ref and write('bulk') == ref
        except Exception:  # any change in mcap's internals: keep the public API
            return False


class _ChunkIndexRecords:
    """Consecutive ChunkIndex records of the file summary, kept as bytes (about 180 per chunk
    instead of a ChunkIndex object and its dict, some 3 KiB: what made a long recording's memory
    grow). ``mcap.Writer.finish`` calls :meth:`write` for each entry of its chunk index list; the
    chunks mcap closes itself stay ChunkIndex objects in that list, in file order."""

    __slots__ = ('data',)

    def __init__(self):
        self.data = bytearray()

    def add(self, record: bytes):
        self.data += record

    def write(self, stream):
        stream.write(bytes(self.data))


class _BulkIndex:
    """A chunk's message index of one channel, kept as arrays and written in one piece (what
    ``mcap.records.MessageIndex.write`` writes entry by entry). ``records`` takes single
    ``(log_time, offset)`` entries as ``MessageIndex.records`` does; :meth:`add` appends arrays."""

    HEAD = struct.Struct('<BQHI')

    def __init__(self, channel_id: int, records=()):
        self.channel_id = channel_id
        self.records = list(records)
        self.parts = []

    def _settle(self):
        if self.records:
            self.parts.append(np.array(self.records, dtype='<u8').reshape(-1, 2))
            self.records = []

    def add(self, entries):
        """Append ``(n, 2)`` entries ``(log_time, offset)`` after those already held."""
        self._settle()
        self.parts.append(entries)

    def write(self, stream):
        """The MessageIndex record (opcode, length, channel, entries) on an mcap RecordBuilder."""
        self._settle()
        body = b''.join(p.astype('<u8', copy=False).tobytes() for p in self.parts)
        stream.write(self.HEAD.pack(_MESSAGE_INDEX_OPCODE, 6 + len(body), self.channel_id, len(body)) + body)


class McapSink:
    """Record ROS 2 messages, stamped with simulation time, into an MCAP file.

    Use as a context manager, or call :meth:`close` (idempotent) when done; the nodes and CLI
    call it on shutdown and on SIGINT/SIGTERM. Attributes ``message_count`` (messages accepted)
    and ``flushed_message_count`` (messages in chunks already handed to the OS) report progress.
    """

    def __init__(self, path, metadata: Optional[Dict[str, str]] = None,
                 chunk_size: Optional[int] = None, compression: Optional[str] = 'zstd',
                 fsync: bool = False, chunk_span: Optional[float] = None):
        """Create (truncate) the file and write the header and the ``robodyn`` metadata record.

        Args:
            path: output file path (``str`` or path-like).
            metadata: key/value strings for the ``robodyn`` metadata record (scene file text,
                integrator settings, package version, ...); keys are written sorted.
            chunk_size: bytes of message records after which the open chunk is closed and
                written out; the most a crash can lose (None: :data:`DEFAULT_CHUNK_SIZE`).
            compression: ``'zstd'`` (default), ``'lz4'``, or ``'none'``/None, per chunk.
            fsync: also ``os.fsync`` after each chunk (survives power loss, not only a killed
                process; slower).
            chunk_span: also close the open chunk after the first message logged at least this
                many seconds (of log time, i.e. simulation time) after the chunk's first message
                (None: by size only). Bounds what a crash loses in time as well as in bytes.
        """
        if compression not in _COMPRESSIONS:
            raise ValueError(f'compression must be one of zstd, lz4, none; got {compression!r}')
        if chunk_size is None:
            chunk_size = DEFAULT_CHUNK_SIZE
        if chunk_size <= 0:
            raise ValueError(f'chunk_size must be positive, got {chunk_size}')
        metadata = dict(metadata or {})
        for key, value in metadata.items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise TypeError(f'metadata keys and values must be str, got {key!r}: {value!r}')
        self.path = os.fspath(path)
        self.chunk_size = int(chunk_size)
        if chunk_span is not None and not chunk_span > 0:
            raise ValueError(f'chunk_span must be a positive number of seconds or None, got {chunk_span!r}')
        self.chunk_span_ns = None if chunk_span is None else int(round(chunk_span * 1e9))
        self._chunk_start = None   # log time of the open chunk's first message
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
        self._known: Dict[tuple, tuple] = {}   # (topic, type as given) -> (channel id, canonical type)
        self._direct = _DirectMessages.attach(self._writer)
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
        known = self._known.get((topic, type_name))
        if known is None:
            channel_id = self.add_topic(topic, type_name)
            known = self._known[(topic, type_name)] = (channel_id, self._types[topic])
        channel_id, canonical = known
        data = bytes(msg) if isinstance(msg, (bytes, bytearray, memoryview)) else cdr.encode(canonical, msg)
        self.write_data(channel_id, data, log_time_ns, publish_time_ns)

    def channel(self, topic: str, type_name: str) -> int:
        """The channel id of ``topic`` (registered on first use, see :meth:`add_topic`), for :meth:`write_data`."""
        known = self._known.get((topic, type_name))
        if known is None:
            channel_id = self.add_topic(topic, type_name)
            known = self._known[(topic, type_name)] = (channel_id, self._types[topic])
        return known[0]

    def write_data(self, channel_id: int, data: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None):
        """Record one message already encoded as canonical CDR on a channel of :meth:`channel`.

        The fast path of :meth:`write` (the same record, sequence number and chunking).
        """
        if self._closed:
            self._check_open()
        log_time_ns = int(log_time_ns)
        if log_time_ns < 0:
            raise ValueError(f'log_time_ns must be >= 0, got {log_time_ns}')
        seq = self._sequence[channel_id] + 1
        self._sequence[channel_id] = seq
        publish = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        if self._direct is not None:
            self._direct.add_message(channel_id, log_time_ns, data, publish, seq)
        else:
            self._writer.add_message(channel_id=channel_id, log_time=log_time_ns, data=data, publish_time=publish,
                                     sequence=seq)
        self.message_count += 1
        self._open_chunk_bytes += _MESSAGE_RECORD_OVERHEAD + len(data)
        if self._chunk_start is None:
            self._chunk_start = log_time_ns
        if self._open_chunk_bytes >= self.chunk_size or \
                (self.chunk_span_ns is not None and log_time_ns - self._chunk_start >= self.chunk_span_ns):
            self.flush()

    def write_records(self, records: np.ndarray, offsets: np.ndarray, channels: np.ndarray, log_times: np.ndarray):
        """Record many messages at once: the vectorised form of :meth:`write_data` (same file).

        records: writable uint8 array holding the messages back to back, each as a 31-byte gap
        for its record header followed by its CDR payload; offsets: (n,) start of each message
        in records (ascending, the first 0, each message ending where the next starts);
        channels: (n,) channel ids of :meth:`channel`; log_times: (n,) integer ns (publish time =
        log time). The headers (sequence numbers per channel included) are written here, and the
        open chunk is closed after the message that fills it, exactly as message-by-message calls
        of :meth:`write_data` would.
        """
        if self._closed:
            self._check_open()
        n = len(offsets)
        if n == 0:
            return
        offsets = np.asarray(offsets, dtype=np.int64)
        channels = np.asarray(channels, dtype=np.int64)
        log_times = np.asarray(log_times, dtype=np.int64)
        if int(log_times.min()) < 0:
            raise ValueError(f'log_time_ns must be >= 0, got {int(log_times.min())}')
        sizes = np.empty(n, dtype=np.int64)
        sizes[:-1] = offsets[1:] - offsets[:-1]
        sizes[-1] = len(records) - offsets[-1]
        if self._direct is None:   # mcap.Writer.add_message, one message at a time
            for k in range(n):
                a = int(offsets[k])
                self.write_data(int(channels[k]), bytes(records[a + 31:a + int(sizes[k])]), int(log_times[k]))
            return
        # headers, sequence numbers counting per channel (channel ids are small integers, uint16)
        seq = np.array([self._sequence.get(c, 0) for c in range(int(channels.max()) + 1)], dtype=np.int64)
        fill_headers(records, offsets, sizes, channels, log_times, seq)
        for c, s in enumerate(seq.tolist()):
            if c in self._sequence:
                self._sequence[c] = s
        # close chunks where write_data would: after the message that brings the open bytes to
        # chunk_size or (with chunk_span) that is logged chunk_span after the chunk's first message
        span = self.chunk_span_ns
        i = 0
        while i < n:
            cum = np.cumsum(sizes[i:])
            cum += self._open_chunk_bytes
            j = int(np.searchsorted(cum, self.chunk_size, side='left'))   # first message reaching it
            start = int(log_times[i]) if self._chunk_start is None else self._chunk_start
            if span is not None:
                late = np.flatnonzero(log_times[i:] - start >= span)
                if late.size:
                    j = min(j, int(late[0]))
            end = n if j >= n - i else i + j + 1
            a, b = int(offsets[i]), int(offsets[end]) if end < n else len(records)
            self._direct.add_records(records[a:b].data, offsets[i:end] - a, channels[i:end], log_times[i:end])
            self.message_count += end - i
            self._open_chunk_bytes = int(cum[end - i - 1])
            self._chunk_start = start
            if self._open_chunk_bytes >= self.chunk_size or \
                    (span is not None and int(log_times[end - 1]) - start >= span):
                self.flush()
            i = end

    def room(self) -> int:
        """Bytes of message records (31-byte headers included) the open chunk takes before it is closed:
        the record that brings it to ``chunk_size`` closes it."""
        return max(0, self.chunk_size - self._open_chunk_bytes)

    def flush(self):
        """Close the open chunk (if it holds messages) and hand everything written to the OS."""
        self._check_open()
        # mcap.Writer.flush: finalize the chunk and its message indexes, then flush the stream.
        if self._direct is not None:
            self._direct.flush()
        else:
            self._writer.flush()
        if self._open_chunk_bytes:
            self.chunk_count += 1
        self._open_chunk_bytes = 0
        self._chunk_start = None
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
                if self._direct is not None:   # the last chunk at the sink's level (mcap.Writer.finish would close it at 3)
                    self._direct.flush()
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
