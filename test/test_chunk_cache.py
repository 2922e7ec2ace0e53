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


def test_the_gltf_of_a_collada_file_comes_from_the_cache_as_the_same_bytes(tmp_path, monkeypatch):
    """The A1's COLLADA meshes as glTF (what a recording embeds), converted with the cache off, then into an empty
    cache and from it: the same bytes; a damaged entry, or one of another file's conversion, is not used and is
    made again; a file the converter refuses (a texture) is remembered as refused (embedded as it is)."""
    from robodyn_ros import assets
    from robodyn_ros.urdf import example_robot_data_dir
    files = sorted(example_robot_data_dir().glob('a1_description/meshes/*.dae'))
    assert len(files) == 5
    data = [f.read_bytes() for f in files]
    monkeypatch.setenv('ROBODYN_CHUNK_CACHE', '0')
    off = [assets._cached_glb_of_collada(x) for x in data]
    assert all(g is not None for g in off) and off == [assets.glb_of_collada(x) for x in data]
    cache = tmp_path / 'cache'
    monkeypatch.setenv('ROBODYN_CHUNK_CACHE', str(cache))
    h0 = assets.GLB_HITS[0]
    assert [assets._cached_glb_of_collada(x) for x in data] == off and assets.GLB_HITS[0] == h0
    entries = sorted(cache.iterdir())
    assert len(entries) == 5
    assert [assets._cached_glb_of_collada(x) for x in data] == off and assets.GLB_HITS[0] == h0 + 5
    good = entries[0].read_bytes()
    entries[0].write_bytes(good[:-1] + bytes([good[-1] ^ 1]))
    entries[1].write_bytes(entries[2].read_bytes())
    assert [assets._cached_glb_of_collada(x) for x in data] == off and assets.GLB_HITS[0] == h0 + 8
    assert entries[0].read_bytes() == good
    colour = b'<color sid="diffuse">'
    textured = data[0].replace(colour, b'<texture texture="t" texcoord="uv"/>' + colour, 1)
    assert b'<texture' in textured
    assert assets._cached_glb_of_collada(textured) is None and assets.GLB_HITS[0] == h0 + 8
    assert assets._cached_glb_of_collada(textured) is None and assets.GLB_HITS[0] == h0 + 9
