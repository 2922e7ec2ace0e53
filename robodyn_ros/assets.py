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

  STL and OBJ files are embedded as binary glTF (:func:`glb_of_mesh`: the same triangles, flat
  normals). URDF meshes are Z-up (REP-103); Foxglove turns an STL or OBJ up only when its 3D panel's
  *Mesh up axis* is set to Z-up (its default is Y-up, which scatters a robot's links), but turns glTF,
  Y-up by its specification, to Z-up always. So the triangles are written Y-up, ``(x, y, z) → (x, z, −y)``,
  and a recording draws right in any Foxglove, with or without our layout. COLLADA files are embedded as
  binary glTF too (:func:`glb_of_collada`: their triangles where Foxglove draws the file, in its colours or
  with its textures' images inside, a fifth of the bytes; kept on disk once converted), except those with
  what the converter does not read, which go as they are, as glTF files do (a COLLADA file's textures,
  files beside it, cannot be loaded from a ``data:`` URI).

A mesh that is not found, or meshes beyond :data:`EMBED_LIMIT` bytes in all, keep their reference
(with a note saying which and why).
"""
from __future__ import annotations

import base64
import functools
import hashlib
import json
import os
import re
import struct
from pathlib import Path

import numpy as np

__all__ = ['AssetError', 'asset_file', 'asset_bytes', 'media_type', 'embed_meshes', 'embed_meshes_parts', 'glb_of_mesh',
           'glb_of_collada', 'srgb_to_linear', 'EMBED_LIMIT', 'MEDIA_TYPES']

#: mesh file extension -> media type (the types Foxglove's model loader recognises)
MEDIA_TYPES = {'.dae': 'model/vnd.collada+xml', '.stl': 'model/stl', '.obj': 'model/obj',
               '.glb': 'model/gltf-binary', '.gltf': 'model/gltf+json'}
#: bytes of mesh files a recorded robot_description embeds at most (counted as the files are: the A1's five
#: COLLADA meshes are 9.7 MB; as glTF, 1.1 MB, 1.5 MB as base64)
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


#: mesh formats :func:`embed_meshes` embeds as binary glTF (their up axis is the URDF's, Z)
GLB_FORMATS = ('.stl', '.obj')


def glb_of_mesh(data: bytes, ext: str) -> bytes:
    """A binary glTF 2.0 file (GLB) of an STL or OBJ file's triangles (``meshes.mesh_triangles``), Y-up as glTF
    wants (``(x, y, z) → (x, z, −y)``: a viewer that turns glTF to Z-up gets the file's own coordinates
    back): one mesh of unindexed triangles, float32 positions (with their bounds) and flat unit normals (a
    degenerate triangle's: +y), a white non-metallic double-sided material. Deterministic. Raises
    ``meshes.MeshError`` for a file without triangles."""
    from .meshes import mesh_triangles
    tri = mesh_triangles(data, ext)
    g = np.stack([tri[..., 0], tri[..., 2], -tri[..., 1]], axis=-1)           # Z-up -> Y-up
    n = np.cross(g[:, 1] - g[:, 0], g[:, 2] - g[:, 0])
    length = np.linalg.norm(n, axis=1)
    n = np.where(length[:, None] > 0.0, n / np.where(length > 0.0, length, 1.0)[:, None], [0.0, 1.0, 0.0])
    pos = g.reshape(-1, 3).astype('<f4')
    nor = np.repeat(n, 3, axis=0).astype('<f4')
    count = pos.shape[0]
    binary = pos.tobytes() + nor.tobytes()
    doc = {'asset': {'version': '2.0', 'generator': 'robodyn_ros'}, 'scene': 0, 'scenes': [{'nodes': [0]}],
           'nodes': [{'mesh': 0}],
           'meshes': [{'primitives': [{'attributes': {'POSITION': 0, 'NORMAL': 1}, 'material': 0, 'mode': 4}]}],
           'materials': [{'pbrMetallicRoughness': {'baseColorFactor': [1.0, 1.0, 1.0, 1.0], 'metallicFactor': 0.0,
                                                   'roughnessFactor': 1.0}, 'doubleSided': True}],
           'buffers': [{'byteLength': len(binary)}],
           'bufferViews': [{'buffer': 0, 'byteOffset': 0, 'byteLength': 12 * count, 'target': 34962},
                           {'buffer': 0, 'byteOffset': 12 * count, 'byteLength': 12 * count, 'target': 34962}],
           'accessors': [{'bufferView': 0, 'componentType': 5126, 'count': count, 'type': 'VEC3',
                          'min': [float(x) for x in pos.min(axis=0)], 'max': [float(x) for x in pos.max(axis=0)]},
                         {'bufferView': 1, 'componentType': 5126, 'count': count, 'type': 'VEC3'}]}
    return _glb(doc, binary)


def _glb(doc: dict, binary: bytes) -> bytes:
    """The GLB container of a glTF document and its one binary buffer (each chunk 4-byte aligned: the JSON padded
    with spaces, the binary with zeros); deterministic (keys sorted)."""
    text = json.dumps(doc, separators=(',', ':'), sort_keys=True).encode('ascii')
    text += b' ' * (-len(text) % 4)
    binary += b'\0' * (-len(binary) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack('<4sII', b'glTF', 2, total) + struct.pack('<I4s', len(text), b'JSON') + text
            + struct.pack('<I4s', len(binary), b'BIN\0') + binary)


def srgb_to_linear(c):
    """An sRGB colour component (0..1) as the linear one glTF's ``baseColorFactor`` holds (IEC 61966-2-1)."""
    c = np.clip(np.asarray(c, dtype=float), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def glb_of_collada(data: bytes, read=None) -> bytes:
    """A binary glTF 2.0 file (GLB) of what a viewer draws of a COLLADA file (``meshes.collada_primitives``; read:
    the bytes of a file it names, for its textures): per primitive its vertices (float32, with their bounds) and
    indexed triangles (uint16, or uint32 past 65 535 vertices; a ``<lines>`` primitive's segments as glTF lines),
    no normals (a glTF viewer then shades each triangle flat), and a non-metallic double-sided material of the
    primitive's diffuse colour (``baseColorFactor``: the COLLADA colour as sRGB made linear,
    :func:`srgb_to_linear`, as three.js reads COLLADA colours) or its texture (the PNG or JPEG file in the GLB,
    ``TEXCOORD_0`` with v turned, ``(u, 1 − v)``: glTF's images start at the top, COLLADA's at the bottom).
    Foxglove draws a Z-up COLLADA file as it is and turns a Y-up one, as every glTF file, to Z-up; so a Z-up
    file's vertices are written Y-up, ``(x, y, z) → (x, z, −y)``, a Y-up file's as they are, and the GLB is drawn
    where the COLLADA file was. About a seventh of the A1's COLLADA text (its trunk: 4.7 MB → 0.6 MB).
    Deterministic. Raises ``meshes.MeshError`` for a file it does not read (the caller embeds that one as it
    is)."""
    from .meshes import collada_primitives
    prims, z_up = collada_primitives(data, read)
    binary = bytearray()
    doc_prims, accessors, views, materials, images = [], [], [], {}, {}

    def put(chunk: bytes, count: int, target, **accessor) -> int:
        view = {'buffer': 0, 'byteOffset': len(binary), 'byteLength': len(chunk)}
        if target is not None:
            view['target'] = target
        views.append(view)
        binary.extend(chunk + b'\0' * (-len(chunk) % 4))
        if count is None:
            return len(views) - 1
        accessors.append({'bufferView': len(views) - 1, 'count': count, **accessor})
        return len(accessors) - 1

    for pos, faces, rgba, uv, image in prims:
        if not len(faces):   # (an empty primitive draws nothing)
            continue
        used, inverse = np.unique(faces.ravel(), return_inverse=True)
        p = pos[used]
        if z_up:
            p = np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1)
        p = p.astype('<f4')
        small = len(used) < 65536
        idx = inverse.astype('<u2' if small else '<u4')
        attributes = {'POSITION': put(p.tobytes(), len(p), 34962, type='VEC3', componentType=5126,
                                      min=[float(x) for x in p.min(axis=0)], max=[float(x) for x in p.max(axis=0)])}
        if image is None:
            key = tuple(float(x) for x in srgb_to_linear(rgba[:3])) + (float(np.clip(rgba[3], 0.0, 1.0)),)
        else:
            t = np.stack([uv[used, 0], 1.0 - uv[used, 1]], axis=1).astype('<f4')
            attributes['TEXCOORD_0'] = put(t.tobytes(), len(t), 34962, type='VEC2', componentType=5126)
            if image[0] not in images:
                images[image[0]] = (put(image[1], None, None), image[2])
            key = ('image', list(images).index(image[0]))
        material = materials.setdefault(key, len(materials))
        indices = put(idx.tobytes(), idx.size, 34963, type='SCALAR', componentType=5123 if small else 5125)
        doc_prims.append({'attributes': attributes, 'indices': indices, 'material': material,
                          'mode': 4 if faces.shape[1] == 3 else 1})   # triangles, lines

    def pbr(key):
        if key[0] == 'image':
            return {'baseColorTexture': {'index': key[1]}, 'metallicFactor': 0.0, 'roughnessFactor': 1.0}
        return {'baseColorFactor': list(key), 'metallicFactor': 0.0, 'roughnessFactor': 1.0}

    doc = {'asset': {'version': '2.0', 'generator': 'robodyn_ros'}, 'scene': 0, 'scenes': [{'nodes': [0]}],
           'nodes': [{'mesh': 0}], 'meshes': [{'primitives': doc_prims}],
           'materials': [{'pbrMetallicRoughness': pbr(k), 'doubleSided': True} for k in materials],
           'buffers': [{'byteLength': len(binary)}], 'bufferViews': views, 'accessors': accessors}
    if images:   # (repeat wrapping, linear mipmaps: glTF's and three.js' defaults, as ColladaLoader's textures)
        doc['images'] = [{'bufferView': v, 'mimeType': kind} for v, kind in images.values()]
        doc['samplers'] = [{'wrapS': 10497, 'wrapT': 10497}]
        doc['textures'] = [{'source': k, 'sampler': 0} for k in range(len(images))]
    return _glb(doc, bytes(binary))


#: the layout of a cached glTF of a COLLADA file (:mod:`robodyn_ros.disk_cache`): the GLB, or b'' for a refused file
_GLB_CACHE_FORMAT = b'robodyn_ros glTF of COLLADA 1: the GLB, empty when refused\n'
#: cached conversions this process used (tests)
GLB_HITS = [0]


@functools.lru_cache(maxsize=1)
def _converter_digest(meshes_file: str) -> bytes:
    """sha256 of what a cached glTF of a COLLADA file depends on besides the file: the cache layout, numpy's
    version, this module's and ``meshes``' source (read once a process)."""
    h = hashlib.sha256(_GLB_CACHE_FORMAT + np.__version__.encode())
    for source in (__file__, meshes_file):
        with open(source, 'rb') as f:
            h.update(f.read())
    return h.digest()


def _cached_glb_of_collada(data: bytes, read=None) -> bytes | None:
    """:func:`glb_of_collada` of a COLLADA file's bytes (read: its texture files), None where it raises MeshError;
    kept on disk (:mod:`robodyn_ros.disk_cache`) under the sha256 of the file, of every file it names that read
    gives (its textures), of this module's and ``meshes``' source and of numpy's version (all the GLB depends
    on): reading it and the files costs about a tenth of converting them (the A1's five files: 0.10 s of XML and
    numbers). The same bytes with or without the cache."""
    from . import disk_cache
    from . import meshes
    from .meshes import MeshError
    d = disk_cache.directory()
    if d is not None:
        h = hashlib.sha256(_converter_digest(meshes.__file__))
        h.update(len(data).to_bytes(8, 'little') + data)
        for name in sorted(set(re.findall(rb'<(?:init_from|ref)>\s*([^<]+?)\s*</', data))) if read else ():
            try:
                named = read(name.decode('utf-8', 'replace'))
            except (OSError, MeshError):
                named = b''
            h.update(name + b'\0' + len(named).to_bytes(8, 'little') + named)
        key = h.digest()
        path = os.path.join(d, f'{key.hex()}.glb')
        body = disk_cache.load(path, key, _GLB_CACHE_FORMAT)
        if body is not None:
            GLB_HITS[0] += 1
            return body or None
    try:
        glb = glb_of_collada(data, read)
    except MeshError:
        glb = None
    if d is not None:
        disk_cache.store(d, path, key, _GLB_CACHE_FORMAT, glb or b'')
    return glb


def _files_beside(uri: str):
    """read(name): the bytes of a file a mesh names relative to itself (its textures), where the mesh is a file."""
    base = asset_file(uri).parent

    def read(name: str) -> bytes:
        from urllib.parse import unquote
        return (base / unquote(name)).read_bytes()
    return read


def _data_uri(uri: str, data: bytes) -> tuple:
    """``(data: URI, note or None)`` of a mesh file's bytes, the URI as two pieces of ASCII bytes (``data:<media
    type>;base64,`` and the base64), not joined (the meshes are MBs): STL and OBJ as binary glTF
    (:func:`glb_of_mesh`; one that cannot be read is embedded as it is, with a note), others as they are."""
    from .meshes import MeshError
    ext = Path(uri.split('?')[0]).suffix.lower()
    note = None
    if ext == '.dae':   # as glTF when it reads it, its textures from beside it; else as it is (no note)
        glb = _cached_glb_of_collada(data, _files_beside(uri))
        if glb is not None:
            return (b'data:model/gltf-binary;base64,', base64.b64encode(glb)), None
    if ext in GLB_FORMATS:
        try:
            return (b'data:model/gltf-binary;base64,', base64.b64encode(glb_of_mesh(data, ext))), None
        except MeshError as e:
            note = f'mesh {uri} embedded as it is, not as glTF: {e}'
    return (f'data:{media_type(uri)};base64,'.encode('ascii'), base64.b64encode(data)), note


def embed_meshes(urdf: str, limit: int = EMBED_LIMIT) -> tuple:
    """``(text, notes)``: the URDF with every mesh ``filename`` replaced by a ``data:`` URI of the file
    it names (``data:<media type>;base64,...``; STL and OBJ as binary glTF, ``model/gltf-binary``, see the
    module docstring), and the notes of the references left as they were (or embedded as they are).

    urdf: URDF text as :meth:`System.urdf` exports it (mesh references absolute: ``package://``,
    ``file://`` or absolute paths; a ``data:`` URI stays); limit: bytes of mesh files embedded at most
    (in the order they appear; the references after it are kept). Deterministic: the same text and
    files give the same result. The text of :func:`embed_meshes_parts`' UTF-8 pieces.
    """
    parts, notes = embed_meshes_parts(urdf, limit)
    return (b''.join(parts).decode('utf-8') if len(parts) > 1 else urdf), notes


@functools.lru_cache(maxsize=8)
def embed_meshes_parts(urdf: str, limit: int = EMBED_LIMIT) -> tuple:
    """``(parts, notes)``: :func:`embed_meshes`' text as the UTF-8 bytes of its pieces (a tuple: the URDF's
    text between the mesh references, the data URIs' pieces, one object per mesh file however often it is
    named), which the recorder joins once into its message (the A1's 13 references to 5 COLLADA files were
    27 MB of text as COLLADA, each copy of it on its way to the file about 14 ms; 3.5 MB as glTF).
    ``(urdf.encode('utf-8'),)`` when no mesh is embedded. Cached (a node's episodes record the same description)."""
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
        files[uri], note = _data_uri(uri, data)
        if note:
            notes.append(note)
    if not files:
        return (urdf.encode('utf-8'),), tuple(notes)
    pieces, at = [], 0   # what _MESH_FILENAME.sub would build, as bytes, never joined here
    for m in _MESH_FILENAME.finditer(urdf):
        uri = files.get(m.group(2))
        pieces.append((urdf[at:m.start()] + m.group(1)).encode('utf-8'))
        pieces += uri if uri is not None else [m.group(2).encode('utf-8')]
        pieces.append(m.group(3).encode('utf-8'))
        at = m.end()
    pieces.append(urdf[at:].encode('utf-8'))
    return tuple(pieces), tuple(notes)
