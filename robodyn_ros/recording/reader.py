"""Read recordings back: decoded messages, and a summary that also works on truncated files.

Everything here streams the file from the start (mcap's ``StreamReader``) instead of seeking
through the summary section, so a file whose writer was killed (no summary, no footer) is read
up to the last complete chunk: messages in complete chunks are recovered, the open chunk is lost.
Messages come out in file order, which for our sink is the order they were written.
"""
import struct
from typing import Dict, Iterable, Iterator, Optional, Tuple

from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema, Statistics
from mcap.stream_reader import StreamReader, breakup_chunk
from zstandard import ZstdError

#: Errors meaning "the bytes here are not valid MCAP" (as opposed to "the file ends here").
_CORRUPTION_ERRORS = (McapError, ValueError, struct.error, ZstdError)


class _StrictFile:
    """File wrapper whose short reads raise EndOfFile, so a cut record is never half-parsed."""

    def __init__(self, f):
        self._f = f

    def read(self, n: int) -> bytes:
        """Read exactly n bytes.

        Args:
            n: byte count.

        Raises:
            EndOfFile: fewer than n bytes remain.
        """
        data = self._f.read(n)
        if len(data) != n:
            raise EndOfFile(f'file ends {n - len(data)} bytes into a {n}-byte read')
        return data


class _Scan:
    """State of one sequential pass: what was read and why reading stopped."""

    def __init__(self):
        self.header: Optional[Header] = None
        self.schemas: Dict[int, Schema] = {}
        self.channels: Dict[int, Channel] = {}
        self.metadata: Dict[str, Dict[str, str]] = {}
        self.statistics: Optional[Statistics] = None
        self.chunk_count = 0
        self.finished = False
        self.error: Optional[str] = None


def _scan(path, scan: _Scan, strict: bool) -> Iterator[Tuple[Channel, Message]]:
    """Yield (channel, message) for every readable message, filling ``scan`` as it goes.

    Args:
        path: MCAP file path.
        scan: receives header, schemas, channels, metadata, chunk count, and how reading ended.
        strict: raise on truncation or corruption instead of recording it in ``scan.error``.
    """
    with open(path, 'rb') as f:
        reader = StreamReader(_StrictFile(f), emit_chunks=True, validate_crcs=True)
        records = reader.records
        while True:
            try:
                record = next(records)
                inner = (breakup_chunk(record, validate_crc=True)
                         if isinstance(record, Chunk) else [record])
            except StopIteration:
                scan.finished = True
                return
            except EndOfFile as exc:
                scan.error = f'truncated: {exc}' if str(exc) else 'truncated'
                if strict:
                    raise
                return
            except _CORRUPTION_ERRORS as exc:
                scan.error = f'corrupt: {type(exc).__name__}: {exc}'
                if strict:
                    raise
                return
            if isinstance(record, Chunk):
                scan.chunk_count += 1
            for rec in inner:
                if isinstance(rec, Message):
                    yield scan.channels[rec.channel_id], rec
                elif isinstance(rec, Schema):
                    scan.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    scan.channels[rec.id] = rec
                elif isinstance(rec, Metadata):
                    scan.metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Header):
                    scan.header = rec
                elif isinstance(rec, Statistics):
                    scan.statistics = rec
                elif isinstance(rec, Footer):
                    scan.finished = True


def read_raw_messages(path, topics: Optional[Iterable[str]] = None,
                      strict: bool = False) -> Iterator[Tuple[str, str, int, bytes]]:
    """Yield ``(topic, type_name, log_time_ns, cdr_bytes)`` for each message, in file order.

    Args:
        path: MCAP file path.
        topics: only these topics (all when None).
        strict: raise ``mcap.exceptions.EndOfFile`` on a truncated file (and the underlying
            error on a corrupt one) instead of stopping after the last complete chunk.
    """
    wanted = None if topics is None else set(topics)
    scan = _Scan()
    for channel, message in _scan(path, scan, strict):
        if wanted is None or channel.topic in wanted:
            schema = scan.schemas.get(channel.schema_id)
            yield (channel.topic, schema.name if schema else '', message.log_time,
                   message.data)


def read_messages(path, topics: Optional[Iterable[str]] = None,
                  strict: bool = False) -> Iterator[Tuple[str, str, int, object]]:
    """Yield ``(topic, type_name, log_time_ns, message)`` decoded by mcap-ros2-support.

    Messages are the dynamic classes of ``mcap_ros2`` (attributes named like the fields).

    Args:
        path: MCAP file path.
        topics: only these topics (all when None).
        strict: see :func:`read_raw_messages`.
    """
    from mcap_ros2.decoder import DecoderFactory
    factory = DecoderFactory()
    wanted = None if topics is None else set(topics)
    scan = _Scan()
    for channel, message in _scan(path, scan, strict):
        if wanted is not None and channel.topic not in wanted:
            continue
        schema = scan.schemas.get(channel.schema_id)
        decoder = factory.decoder_for(channel.message_encoding, schema)
        if decoder is None:
            raise McapError(f'no decoder for topic {channel.topic!r} (message encoding '
                            f'{channel.message_encoding!r}, schema {schema and schema.name!r})')
        yield channel.topic, schema.name, message.log_time, decoder(message.data)


def summarize(path) -> dict:
    """Describe a recording by reading it sequentially (works without a summary section).

    Args:
        path: MCAP file path.

    Returns:
        dict with ``finished`` (footer and closing magic read: the writer finished cleanly),
        ``error`` (None, or why reading stopped: ``truncated: ...`` / ``corrupt: ...``),
        ``profile``, ``library``, ``message_count`` (messages recovered), ``chunk_count``
        (complete chunks read), ``start_time_ns``/``end_time_ns`` (log-time range, None when
        empty), ``topics`` (topic -> ``{'type', 'count', 'offered_qos_profiles'}``),
        ``metadata`` (record name -> key/values), and ``statistics_message_count`` (the count
        in the Statistics record of a finished file, else None).
    """
    scan = _Scan()
    counts: Dict[int, int] = {}
    start = end = None
    for channel, message in _scan(path, scan, strict=False):
        counts[channel.id] = counts.get(channel.id, 0) + 1
        start = message.log_time if start is None else min(start, message.log_time)
        end = message.log_time if end is None else max(end, message.log_time)
    topics = {}
    for cid, channel in scan.channels.items():
        schema = scan.schemas.get(channel.schema_id)
        entry = topics.setdefault(channel.topic, {
            'type': schema.name if schema else '', 'count': 0,
            'offered_qos_profiles': channel.metadata.get('offered_qos_profiles', '')})
        entry['count'] += counts.get(cid, 0)
    return {
        'path': str(path),
        'finished': scan.finished and scan.error is None,
        'error': scan.error,
        'profile': scan.header.profile if scan.header else None,
        'library': scan.header.library if scan.header else None,
        'message_count': sum(counts.values()),
        'chunk_count': scan.chunk_count,
        'start_time_ns': start,
        'end_time_ns': end,
        'topics': topics,
        'metadata': scan.metadata,
        'statistics_message_count': scan.statistics.message_count if scan.statistics else None,
    }
