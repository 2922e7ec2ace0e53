"""Compressed chunks kept on disk by their content: a large chunk a recording writes again is not compressed again.

A recording of a robot with meshes starts with its ``robot_description``, the meshes embedded as ``data:`` URIs
(a1_stand: 3.5 MB of text, its COLLADA meshes as glTF, 2.1 MB in zstd; 27 MB and 0.11 s of compression when they
went as COLLADA). Every run of that robot writes the same chunk, so its compressed bytes are kept in
``$XDG_CACHE_HOME/robodyn_ros/chunks`` (default ``~/.cache``; ``$ROBODYN_CHUNK_CACHE`` names another directory,
``0`` turns the cache off) under the sha256 of the uncompressed chunk, the compression level and the zstandard
version. An entry holds that key, then the sha256 of the rest (after :data:`FORMAT`), then the chunk's CRC-32
(the chunk record's uncompressed CRC) and its compressed bytes, and is used only when both hashes match (a
damaged file, another chunk's entry under this name, or an entry of another layout is replaced): the bytes are
then those ``ZstdCompressor(level=level).compress`` gave for this chunk (zstd is deterministic for a given
input, level and version) and its CRC, so a recording's bytes do not depend on the cache: the same file as
compressing anew. (Checking the two hashes costs about 1 ms a MB; decompressing to compare would cost about 4.)
Only chunks of at least :data:`MIN_BYTES` are kept (a recording's 768 KiB chunks differ from run to run); entries
beyond :data:`robodyn_ros.disk_cache.MAX_TOTAL` bytes, oldest first, are removed when one is added
(:mod:`robodyn_ros.disk_cache`, whose directory the glTF of COLLADA meshes shares). Anything the file system
refuses (a read-only home) just compresses as before.
"""
from __future__ import annotations

import hashlib
import os
import zlib

from .. import disk_cache

#: smallest uncompressed chunk kept (bytes)
MIN_BYTES = 2 << 20
#: what an entry's second hash starts with: the layout of the entries (the CRC, then the compressed bytes)
FORMAT = b'robodyn_ros chunk cache 2: crc32 le, zstd frame\n'
#: lookups this process answered from the cache (tests)
HITS = [0]


def compress_zstd(raw: bytes, compressor, level: int, version: str) -> tuple:
    """``(compressor.compress(raw), zlib.crc32(raw))``, from the cache when an entry for raw is there whole
    (module docstring): the chunk record's data and its uncompressed CRC.

    raw: the uncompressed chunk; compressor: a ``zstandard.ZstdCompressor`` at ``level``; level and
    version (``zstandard.__version__``) are part of the key. An entry (:mod:`robodyn_ros.disk_cache`) is the key,
    the sha256 of :data:`FORMAT` and what follows (so an entry of another layout never matches), the CRC (4 bytes,
    little-endian) and the compressed bytes."""
    d = disk_cache.directory() if len(raw) >= MIN_BYTES else None
    if d is None:
        return compressor.compress(raw), zlib.crc32(raw)
    key = hashlib.sha256(raw).digest()
    path = os.path.join(d, f'{key.hex()}.zstd{level}-{version}.2')
    body = disk_cache.load(path, key, FORMAT)
    if body is not None and len(body) > 4:
        HITS[0] += 1
        return body[4:], int.from_bytes(body[:4], 'little')
    data = compressor.compress(raw)
    crc = zlib.crc32(raw)
    disk_cache.store(d, path, key, FORMAT, crc.to_bytes(4, 'little') + data)
    return data, crc
