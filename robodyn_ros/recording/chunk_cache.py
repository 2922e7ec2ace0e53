"""Compressed chunks kept on disk by their content: a large chunk a recording writes again is not compressed again.

A recording of a robot with meshes starts with its ``robot_description``, the meshes embedded as ``data:`` URIs
(a1_stand: 27 MB of text, 9.0 MB in zstd, about 0.11 s of compression at level 1 on a 2-core machine, 0.19 s
at level 3). Every run of that robot writes the same chunk, so its compressed bytes are kept in
``$XDG_CACHE_HOME/robodyn_ros/chunks`` (default ``~/.cache``; ``$ROBODYN_CHUNK_CACHE`` names another directory,
``0`` turns the cache off) under the sha256 of the uncompressed chunk, the compression level and the zstandard
version. An entry holds that key, then the sha256 of the rest (after :data:`FORMAT`), then the chunk's CRC-32
(the chunk record's uncompressed CRC) and its compressed bytes, and is used only when both hashes match (a
damaged file, another chunk's entry under this name, or an entry of another layout is replaced): the bytes are
then those ``ZstdCompressor(level=level).compress`` gave for this chunk (zstd is deterministic for a given
input, level and version) and its CRC, so a recording's bytes do not depend on the cache: the same file as
compressing anew. (Checking the two hashes costs about 25 ms for the A1's 27 MB chunk; decompressing it to
compare, about 100 ms; computing its CRC, 14 ms.) Only chunks of at least :data:`MIN_BYTES` are kept (a
recording's 768 KiB chunks differ from run to run); entries beyond :data:`MAX_TOTAL` bytes, oldest first, are
removed when one is added. Anything the file system refuses (a read-only home) just compresses as before.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import zlib

#: smallest uncompressed chunk kept (bytes)
MIN_BYTES = 2 << 20
#: bytes of entries the directory keeps at most
MAX_TOTAL = 512 << 20
#: what an entry's second hash starts with: the layout of the entries (the CRC, then the compressed bytes)
FORMAT = b'robodyn_ros chunk cache 2: crc32 le, zstd frame\n'
#: lookups this process answered from the cache (tests)
HITS = [0]


def directory() -> str | None:
    """The cache directory, or None when ``$ROBODYN_CHUNK_CACHE`` is ``0``."""
    env = os.environ.get('ROBODYN_CHUNK_CACHE')
    if env == '0':
        return None
    if env:
        return env
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return os.path.join(base, 'robodyn_ros', 'chunks')


def compress_zstd(raw: bytes, compressor, level: int, version: str) -> tuple:
    """``(compressor.compress(raw), zlib.crc32(raw))``, from the cache when an entry for raw is there whole
    (module docstring): the chunk record's data and its uncompressed CRC.

    raw: the uncompressed chunk; compressor: a ``zstandard.ZstdCompressor`` at ``level``; level and
    version (``zstandard.__version__``) are part of the key. An entry is the key, the sha256 of :data:`FORMAT`
    and what follows (so an entry of another layout never matches), the CRC (4 bytes, little-endian) and the
    compressed bytes."""
    d = directory() if len(raw) >= MIN_BYTES else None
    if d is None:
        return compressor.compress(raw), zlib.crc32(raw)
    key = hashlib.sha256(raw).digest()
    path = os.path.join(d, f'{key.hex()}.zstd{level}-{version}.2')
    try:
        with open(path, 'rb') as f:
            entry = f.read()
        h = hashlib.sha256(FORMAT)
        h.update(memoryview(entry)[64:])
        if len(entry) > 68 and entry[:32] == key and entry[32:64] == h.digest():
            HITS[0] += 1
            return entry[68:], int.from_bytes(entry[64:68], 'little')
    except OSError:   # missing or unreadable: compress anew
        pass
    data = compressor.compress(raw)
    crc = zlib.crc32(raw)
    body = crc.to_bytes(4, 'little') + data
    _store(d, path, key + hashlib.sha256(FORMAT + body).digest() + body)
    return data, crc


def _store(d: str, path: str, data: bytes) -> None:
    """Write an entry atomically (a temporary file renamed), then trim the directory to :data:`MAX_TOTAL`."""
    try:
        os.makedirs(d, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=d, prefix='.tmp-')
        with os.fdopen(fd, 'wb') as f:
            f.write(data)
        os.replace(tmp, path)
        entries = []
        for name in os.listdir(d):
            if not name.startswith('.'):
                st = os.stat(os.path.join(d, name))
                entries.append((st.st_mtime, st.st_size, name))
        total = sum(e[1] for e in entries)
        for _, size, name in sorted(entries):
            if total <= MAX_TOTAL:
                break
            os.unlink(os.path.join(d, name))
            total -= size
    except OSError:   # a read-only or full cache directory: nothing kept
        pass
