"""A large chunk a recording writes again comes from the chunk cache, and the file is the same bytes.

The oracle is the recording made with the cache off (``ROBODYN_CHUNK_CACHE=0``: every chunk compressed anew).
"""
from __future__ import annotations

import contextlib
import hashlib
import io

from robodyn_ros.cli import main
from robodyn_ros.recording import chunk_cache, mcap_sink


def _record(path) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(['run', 'stanford_arm', '--duration', '3', '--record', str(path)]) == 0


def test_a_chunk_written_again_comes_from_the_cache_and_the_file_is_the_same(tmp_path, monkeypatch):
    monkeypatch.setattr(chunk_cache, 'MIN_BYTES', 1000)   # every chunk of this recording is large enough
    monkeypatch.setattr(mcap_sink, 'DEFAULT_CHUNK_SIZE', 64 * 1024)   # and there are several
    monkeypatch.setenv('ROBODYN_CHUNK_CACHE', '0')
    _record(tmp_path / 'off.mcap')
    cache = tmp_path / 'cache'
    monkeypatch.setenv('ROBODYN_CHUNK_CACHE', str(cache))
    h0 = chunk_cache.HITS[0]
    _record(tmp_path / 'first.mcap')
    entries = sorted(cache.iterdir())
    assert len(entries) >= 4 and chunk_cache.HITS[0] == h0          # filled, nothing found in an empty cache
    _record(tmp_path / 'second.mcap')
    assert chunk_cache.HITS[0] - h0 == len(entries)                   # every chunk found
    off = (tmp_path / 'off.mcap').read_bytes()
    assert (tmp_path / 'first.mcap').read_bytes() == off and (tmp_path / 'second.mcap').read_bytes() == off

    # a damaged entry, an entry holding another chunk's bytes and an entry whose hash does not cover the
    # layout (the previous one: key, sha256 of the rest, the rest) are not used, and are replaced
    good = entries[0].read_bytes()
    entries[0].write_bytes(good[:len(good) // 2])
    entries[1].write_bytes(entries[2].read_bytes())
    e3 = entries[3].read_bytes()
    entries[3].write_bytes(e3[:32] + hashlib.sha256(e3[64:]).digest() + e3[64:])
    h1 = chunk_cache.HITS[0]
    _record(tmp_path / 'third.mcap')
    assert chunk_cache.HITS[0] - h1 == len(entries) - 3
    assert (tmp_path / 'third.mcap').read_bytes() == off
    assert entries[0].read_bytes() == good


def test_a_cache_directory_that_cannot_be_written_changes_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(chunk_cache, 'MIN_BYTES', 1000)
    monkeypatch.setenv('ROBODYN_CHUNK_CACHE', '0')
    _record(tmp_path / 'off.mcap')
    blocker = tmp_path / 'file'
    blocker.write_text('not a directory')
    monkeypatch.setenv('ROBODYN_CHUNK_CACHE', str(blocker / 'cache'))
    _record(tmp_path / 'on.mcap')
    assert (tmp_path / 'on.mcap').read_bytes() == (tmp_path / 'off.mcap').read_bytes()
