"""Files kept on disk under the hash of what they were made from: work a run would repeat, done once per machine.

Two kinds of entry share one directory, ``$XDG_CACHE_HOME/robodyn_ros/chunks`` (default ``~/.cache``;
``$ROBODYN_CHUNK_CACHE`` names another directory, ``0`` turns the cache off): a recording's large compressed
chunks (:mod:`robodyn_ros.recording.chunk_cache`) and the glTF of COLLADA meshes a recording embeds
(:func:`robodyn_ros.assets.embed_meshes_parts`). An entry is a 32-byte key (the sha256 of everything the
result depends on), the sha256 of the entry's layout (its ``fmt``) and body, and the body; it is used only when
both hashes match (a damaged file, another entry under this name, or an entry of another layout is made
again), so a result never depends on the cache. Entries beyond :data:`MAX_TOTAL` bytes, oldest first, are
removed when one is added. Anything the file system refuses (a read-only home) just computes as before.
"""
from __future__ import annotations

import hashlib
import os
import tempfile

#: bytes of entries the directory keeps at most
MAX_TOTAL = 512 << 20


def directory() -> str | None:
    """The cache directory, or None when ``$ROBODYN_CHUNK_CACHE`` is ``0``."""
    env = os.environ.get('ROBODYN_CHUNK_CACHE')
    if env == '0':
        return None
    if env:
        return env
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return os.path.join(base, 'robodyn_ros', 'chunks')


def load(path: str, key: bytes, fmt: bytes) -> bytes | None:
    """The body of the entry at path when it is whole and for this key and layout (module docstring), else None."""
    try:
        with open(path, 'rb') as f:
            entry = f.read()
    except OSError:   # missing or unreadable
        return None
    h = hashlib.sha256(fmt)
    h.update(memoryview(entry)[64:])
    if len(entry) >= 64 and entry[:32] == key and entry[32:64] == h.digest():
        return entry[64:]
    return None


def store(d: str, path: str, key: bytes, fmt: bytes, body: bytes) -> None:
    """Write the entry of body under key (a temporary file renamed), then trim the directory to :data:`MAX_TOTAL`."""
    try:
        os.makedirs(d, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=d, prefix='.tmp-')
        with os.fdopen(fd, 'wb') as f:
            f.write(key + hashlib.sha256(fmt + body).digest() + body)
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
