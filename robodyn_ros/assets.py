"""The files a viewer fetches to draw a robot: the meshes a URDF names by ``package://``,
``file://`` or path, for the live server's asset requests and for recordings that carry them.

A browser cannot open ``package://example-robot-data/...`` (Foxglove then draws the robot as TF
axes and marks the mesh with a red badge in the 3D panel's settings). Two ways round it, both
built on :func:`asset_file`, the one place where a mesh reference becomes a file:

* live, the WebSocket server answers the viewer's ``fetchAsset`` requests with the file's bytes
  (:mod:`robodyn_ros.live.server`);
* in a recording, :func:`embed_meshes` replaces each mesh reference of the recorded
  ``robot_description`` by a ``data:`` URI holding the file (media type from its extension), so
  that the MCAP opens with its meshes in any viewer on any machine, without ROS or this package.
  The ``robot_description`` published on ROS keeps the references (RViz resolves ``package://``
  itself and cannot read ``data:`` URIs).

A mesh that is not found, or meshes beyond :data:`EMBED_LIMIT` bytes in all, keep their reference
(with a note saying which and why).
"""
from __future__ import annotations

import base64
import functools
import re
from pathlib import Path

__all__ = ['AssetError', 'asset_file', 'asset_bytes', 'media_type', 'embed_meshes', 'EMBED_LIMIT', 'MEDIA_TYPES']

#: mesh file extension -> media type (the types Foxglove's model loader recognises)
MEDIA_TYPES = {'.dae': 'model/vnd.collada+xml', '.stl': 'model/stl', '.obj': 'model/obj',
               '.glb': 'model/gltf-binary', '.gltf': 'model/gltf+json'}
#: bytes of mesh files a recorded robot_description embeds at most (the A1's five COLLADA meshes
#: are 9.7 MB, 13 MB as base64 and about 4 MB in the recording's zstd chunk)
EMBED_LIMIT = 64 * 1024 * 1024

_MESH_FILENAME = re.compile(r'(<mesh\b[^>]*?\bfilename=")([^"]*)(")')


class AssetError(ValueError):
    """A reference that names no readable file; the message says which and why."""


def asset_file(uri: str) -> Path:
    """The file a mesh reference names: ``package://<package>/<path>`` (the ament index, then
    example-robot-data, as :func:`robodyn_ros.meshes.resolve_uri` finds them), ``file://<path>``
    or an absolute path. Raises :class:`AssetError`."""
    from .meshes import MeshError, resolve_uri
    try:
        return resolve_uri(uri)
    except MeshError as e:
        raise AssetError(str(e)) from None


def asset_bytes(uri: str) -> bytes:
    """The contents of the file :func:`asset_file` finds for ``uri`` (AssetError when unreadable)."""
    p = asset_file(uri)
    try:
        return p.read_bytes()
    except OSError as e:
        raise AssetError(f'{uri}: cannot read {str(p)!r}: {e.strerror or e}') from None


def media_type(name: str) -> str:
    """The media type of a mesh file by its extension (``application/octet-stream`` when unknown)."""
    return MEDIA_TYPES.get(Path(name.split('?')[0]).suffix.lower(), 'application/octet-stream')


@functools.lru_cache(maxsize=8)
def embed_meshes(urdf: str, limit: int = EMBED_LIMIT) -> tuple:
    """``(text, notes)``: the URDF with every mesh ``filename`` replaced by a ``data:`` URI of the file
    it names (``data:<media type>;base64,...``), and the notes of the references left as they were.

    urdf: URDF text as :meth:`System.urdf` exports it (mesh references absolute: ``package://``,
    ``file://`` or absolute paths; a ``data:`` URI stays); limit: bytes of mesh files embedded at most
    (in the order they appear; the references after it are kept). Deterministic: the same text and
    files give the same result. Cached (a node's episodes record the same description).
    """
    files = {}
    notes = []
    total = 0
    for uri in dict.fromkeys(m.group(2) for m in _MESH_FILENAME.finditer(urdf)):
        if uri.startswith('data:'):
            continue
        try:
            data = asset_bytes(uri)
        except AssetError as e:
            notes.append(f'mesh {uri} kept as a reference: {e}')
            continue
        if total + len(data) > limit:
            notes.append(f'mesh {uri} kept as a reference: the meshes embedded so far and it exceed '
                         f'{limit / 2 ** 20:.0f} MiB')
            continue
        total += len(data)
        files[uri] = f'data:{media_type(uri)};base64,{base64.b64encode(data).decode("ascii")}'
    if not files:
        return urdf, tuple(notes)
    pieces, at = [], 0   # what _MESH_FILENAME.sub would build, joined once (the meshes are MBs of text)
    for m in _MESH_FILENAME.finditer(urdf):
        pieces += [urdf[at:m.start()], m.group(1), files.get(m.group(2), m.group(2)), m.group(3)]
        at = m.end()
    pieces.append(urdf[at:])
    return ''.join(pieces), tuple(notes)
