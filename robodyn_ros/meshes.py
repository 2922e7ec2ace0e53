"""Mesh files for contact geometry: where a URDF's mesh is, and a sphere that encloses it.

A ground part replaces a ``<collision>`` mesh by a sphere that encloses it (with a warning): the
centre of the mesh's axis-aligned bounding box and the largest distance of a vertex from it (not the
smallest enclosing sphere, which is at most that much smaller). Read here with numpy and the standard
library: STL (binary and ASCII), Wavefront OBJ (``v`` lines) and COLLADA ``.dae`` (the vertices of its
triangles as :func:`collada_primitives` places them: the visual scene's node transforms, then ``<unit meter>``;
the up axis is not applied, as RViz and coal, which read COLLADA through assimp, do not; a file that reader
refuses: the ``<float_array>`` of every ``<source>`` whose id names positions, times its unit, with a
warning). For a viewer, :func:`collada_primitives` reads a COLLADA file's drawn surfaces whole (node
transforms, polygons, colours), which a recording embeds as glTF (:func:`robodyn_ros.assets.glb_of_collada`).

Where: an absolute path, ``file://`` URI, or ``package://<package>/<path>``, found through the ament
index (a sourced ROS install), the example-robot-data wheel (its package name), the copy of two of
its robots bundled with this package (:func:`bundled_robot_data_dir`), or a directory named
``<package>`` above the URDF file. :func:`resolve_uri` is the one place that knows this order: the
importer, a ground part's meshes, a scene's ``file: package://...`` and a viewer serving the meshes
of ``robot_description`` all ask it.

The bundled copy (``robodyn_ros/data/example-robot-data``, 1.6 MB, with example-robot-data's
licence, each robot's README naming its upstream licence, and a README on the selection) holds
what the bundled scenes ``a1_stand`` and ``solo12_drop`` need from a plain install: ``a1.urdf``
(its collision shapes are primitives) and ``solo12.urdf`` with the STL meshes it names (its feet's
collision meshes give the ground contact; the same files are its visuals). A1's visual meshes
(9.7 MB of COLLADA) are left out: :func:`resolve_uri` raises :class:`MeshError` for them unless
example-robot-data is installed, and a viewer draws the collision shapes instead.
"""
from __future__ import annotations

import re
import struct
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

__all__ = ['MeshError', 'resolve_uri', 'mesh_vertices', 'mesh_triangles', 'collada_primitives', 'ColladaPrimitive',
           'bounding_sphere', 'mesh_sphere',
           'example_robot_data_dir', 'bundled_robot_data_dir']


def example_robot_data_dir() -> Path | None:
    """Directory of the URDFs shipped by the ``example-robot-data`` wheel (test extras), or None."""
    try:
        from importlib.metadata import PackageNotFoundError, distribution
        d = distribution('example-robot-data')
    except (ImportError, PackageNotFoundError):
        return None
    p = Path(d.locate_file('cmeel.prefix/share/example-robot-data/robots'))
    return p if p.is_dir() else None


def bundled_robot_data_dir() -> Path:
    """``robots`` directory of the part of example-robot-data bundled with this package (module docstring)."""
    return Path(__file__).resolve().parent / 'data' / 'example-robot-data' / 'robots'


class MeshError(ValueError):
    """A mesh that cannot be found or read; the message says which and why."""


def resolve_uri(name: str, urdf_dir: Path | None = None) -> Path:
    """The file of a URDF mesh reference, or of a scene's ``file: package://...`` (see the module
    docstring); raises MeshError when not found. ``package:///<package>/<path>`` (a slash too many, as
    example-robot-data's talos_full_v2 writes it) is read as ``package://<package>/<path>``, as Pinocchio
    finds it (it appends what follows ``package://`` to each package directory)."""
    if name.startswith('file://'):
        p = Path(name[len('file://'):])
    elif name.startswith('package://'):
        pkg, _, rest = name[len('package://'):].lstrip('/').partition('/')
        p = None
        for base in _package_dirs(pkg, urdf_dir):
            if (base / rest).is_file():
                p = base / rest
                break
        if p is None:
            raise MeshError(f'{name}: not found: package {pkg!r} has no such file (looked in the ament index, the '
                            f'installed and the bundled example-robot-data, and directories named {pkg!r} above the URDF)')
    elif '://' in name:
        raise MeshError(f'{name}: only file://, package:// and plain paths are read')
    else:
        p = Path(name) if urdf_dir is None else urdf_dir / name
    if not p.is_file():
        raise MeshError(f'{name}: no such file {str(p)!r}')
    return p


def _package_dirs(pkg: str, urdf_dir: Path | None):
    """Candidate directories of ROS package ``pkg``, in the order :func:`resolve_uri` tries them."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            yield Path(get_package_share_directory(pkg))
        except (PackageNotFoundError, OSError, ValueError):
            pass
    except ImportError:
        pass
    erd = example_robot_data_dir()
    if erd is not None and pkg == erd.parent.name:
        yield erd.parent
    own = bundled_robot_data_dir().parent
    if pkg == own.name and own.is_dir():
        yield own
    d = urdf_dir
    while d is not None and d != d.parent:
        if d.name == pkg:
            yield d
        if (d / pkg).is_dir():
            yield d / pkg
        d = d.parent


def mesh_vertices(path) -> np.ndarray:
    """The vertices (n, 3) of an STL, OBJ or DAE file (see the module docstring); raises MeshError."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise MeshError(f'{path}: cannot read: {e.strerror or e}') from None
    ext = path.suffix.lower()
    try:
        if ext == '.stl':
            v = _stl(data)
        elif ext == '.obj':
            v = np.array([[float(x) for x in line.split()[1:4]] for line in data.decode('utf-8', 'replace').splitlines()
                          if line.startswith('v ')], dtype=float).reshape(-1, 3)
        elif ext == '.dae':
            v = _dae(data, path)
        else:
            raise MeshError(f'{path}: unknown mesh format {ext!r} (STL, OBJ and DAE are read)')
    except (ValueError, struct.error, ET.ParseError) as e:
        if isinstance(e, MeshError):
            raise
        raise MeshError(f'{path}: cannot read the mesh: {e}') from None
    v = v[np.all(np.isfinite(v), axis=1)]
    if not len(v):
        raise MeshError(f'{path}: no vertices')
    return v


def _stl(data: bytes) -> np.ndarray:
    """Vertices of a binary or ASCII STL."""
    if len(data) >= 84:
        n = struct.unpack_from('<I', data, 80)[0]
        if 84 + 50 * n == len(data):   # binary: 80-byte header, count, 50 bytes per triangle
            rec = np.frombuffer(data, dtype=np.dtype([('n', '<f4', 3), ('v', '<f4', (3, 3)), ('a', '<u2')]),
                                count=n, offset=84)
            return rec['v'].reshape(-1, 3).astype(float)
    text = data.decode('ascii', 'replace')
    return np.array([[float(x) for x in m.split()] for m in re.findall(r'vertex\s+(\S+\s+\S+\s+\S+)', text)],
                    dtype=float).reshape(-1, 3)


def mesh_triangles(data: bytes, ext: str) -> np.ndarray:
    """The triangles (n, 3, 3) of an STL (binary or ASCII) or Wavefront OBJ file's bytes (``ext``: ``.stl`` or
    ``.obj``; an OBJ face of k corners becomes a fan of k − 2 triangles; its ``v/vt/vn`` and negative indices
    are read), in the file's own coordinates; raises MeshError (no triangles, an index out of range)."""
    try:
        if ext == '.stl':
            tri = _stl(data).reshape(-1, 3, 3)
        elif ext == '.obj':
            tri = _obj_triangles(data.decode('utf-8', 'replace'))
        else:
            raise MeshError(f'triangles are read from STL and OBJ, not {ext!r}')
    except (ValueError, IndexError, struct.error) as e:
        if isinstance(e, MeshError):
            raise
        raise MeshError(f'cannot read the {ext} mesh: {e}') from None
    if not len(tri) or not np.isfinite(tri).all():
        raise MeshError(f'the {ext} mesh has no triangles, or non-finite vertices')
    return tri


def _obj_triangles(text: str) -> np.ndarray:
    """Triangles of an OBJ's ``f`` lines over its ``v`` lines (1-based, or negative: from the last vertex)."""
    verts, faces = [], []
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == 'v':
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == 'f':
            idx = []
            for c in parts[1:]:
                i = int(c.split('/')[0])
                idx.append(i - 1 if i > 0 else len(verts) + i)
            if min(idx) < 0 or max(idx) >= len(verts):
                raise MeshError(f'face {line.strip()!r} names a vertex that is not there ({len(verts)} so far)')
            faces += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
    v = np.array(verts, dtype=float).reshape(-1, 3)
    return v[np.array(faces, dtype=np.int64).reshape(-1, 3)]


def _dae(data: bytes, path) -> np.ndarray:
    """Vertices of a COLLADA file's triangles as :func:`collada_primitives` places them (the visual scene's node
    transforms and ``<unit meter>`` applied, the up axis not: as assimp-based ROS tools, RViz and coal, read
    them); a file it refuses: its position sources' float arrays times the unit, with a warning."""
    try:
        prims, _ = collada_primitives(data, materials=False)
        used = [p[0][np.unique(p[1])] for p in prims if len(p[1]) and p[1].shape[1] == 3]
        if used:
            return np.vstack(used)
        why = 'no triangles in its visual scene'
    except MeshError as e:
        why = str(e)
    warnings.warn(f'{path}: {why}; its vertices are read without the scene\'s node transforms', stacklevel=3)
    root = ET.fromstring(data)
    out = []
    for src in root.iter():
        if not (isinstance(src.tag, str) and src.tag.endswith('source')) or \
                'position' not in (src.get('id') or '').lower():
            continue
        for fa in src:
            if isinstance(fa.tag, str) and fa.tag.endswith('float_array') and fa.text:
                out.append(np.array(fa.text.split(), dtype=float).reshape(-1, 3))
    if not out:
        raise MeshError('no <source> of positions')
    unit = next((u for u in root.iter() if isinstance(u.tag, str) and u.tag.endswith('unit')), None)
    return np.vstack(out) * float(unit.get('meter', 1.0) if unit is not None else 1.0)


#: what :func:`collada_primitives` reads of a COLLADA scene (anything else: MeshError, the file is used as it is)
COLLADA_PRIMITIVES = ('triangles', 'polylist', 'polygons', 'lines')
#: image files a textured COLLADA primitive may name (the formats glTF holds): extension -> media type
TEXTURE_TYPES = {'.png': 'image/png', '.jpg': 'image/jpeg', '.jpeg': 'image/jpeg'}


class ColladaPrimitive(tuple):
    """One primitive of :func:`collada_primitives`: ``(positions (n, 3), faces (m, 3) or segments (m, 2) int64,
    rgba (4,), uv (n, 2) or None, image (file name, bytes, media type) or None)``."""
    __slots__ = ()

    def __new__(cls, positions, faces, rgba, uv=None, image=None):
        return tuple.__new__(cls, (positions, faces, rgba, uv, image))


def collada_primitives(data: bytes, read=None, materials: bool = True) -> tuple:
    """The surfaces a viewer draws of a COLLADA (``.dae``) file, as ``([ColladaPrimitive, ...], z_up)``: per
    instanced geometry and primitive, its vertices in the file's coordinates (every node transform of the visual
    scene applied, in the order the file lists them, then ``<unit meter>``), its triangles (a polygon of k
    corners as a fan of k − 2, as three.js' ColladaLoader does; a ``<lines>`` primitive's segments instead,
    faces (m, 2)), the diffuse colour its material binds (as the file writes it; white without one) or, for a
    textured one, its texture coordinates (as the file writes them, a vertex per distinct position and
    coordinate pair) and image (``read(name)``: the bytes of a file the COLLADA file names, relative to it;
    PNG or JPEG), and whether the file is Z-up (else Y-up, COLLADA's default). Reads what robot meshes use:
    ``<triangles>``, ``<polylist>``, ``<polygons>`` and ``<lines>`` of ``<instance_geometry>`` and
    ``<instance_node>`` under ``<matrix>``, ``<translate>``, ``<rotate>`` and ``<scale>``, lambert, phong,
    blinn and constant materials with a colour or a texture. Raises MeshError, naming what it does not read (an
    X-up file, a texture without read or of another format, a skin, line strips), for a file it cannot draw
    the same way. ``materials=False``: the geometry alone (every primitive white, untextured; no material read)."""
    try:
        return _collada_primitives(data, read, materials)
    except MeshError:
        raise
    except (ValueError, IndexError, KeyError, AttributeError, OSError) as e:
        raise MeshError(f'cannot read the COLLADA file: {type(e).__name__}: {e}') from None


def _numbers(text, dtype) -> np.ndarray:
    """The whitespace-separated numbers of an XML element's text (MeshError when one is not a number)."""
    with warnings.catch_warnings():
        warnings.simplefilter('error', DeprecationWarning)   # numpy's word for text it could not read to its end
        try:
            return np.fromstring(text or '', dtype=dtype, sep=' ')
        except (DeprecationWarning, ValueError):
            raise MeshError(f'not a list of numbers: {(text or "")[:40]!r}...') from None


def _collada_primitives(data: bytes, read, materials: bool) -> tuple:
    """:func:`collada_primitives` without its error handling."""
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise MeshError(f'not XML: {e}') from None
    for el in root.iter():
        if isinstance(el.tag, str):
            el.tag = el.tag.rsplit('}', 1)[-1]
    ids = {el.get('id'): el for el in root.iter() if el.get('id')}

    def target(el, attr='url'):
        ref = (el.get(attr) or '').lstrip('#')
        if ref not in ids:
            raise MeshError(f'<{el.tag}> names {ref!r}, which the file does not hold')
        return ids[ref]

    def floats(el, n=None):
        x = _numbers(el.text, float)
        if n is not None and x.size != n:
            raise MeshError(f'<{el.tag}> holds {x.size} numbers, not {n}')
        return x

    def columns(src, least):
        """The values of a <source> as rows of its accessor's stride, the first ``least`` columns."""
        acc = src.find('technique_common/accessor')
        step = int(acc.get('stride', str(least))) if acc is not None else least
        fa = src.find('float_array')
        if fa is None or step < least:
            raise MeshError(f'source {src.get("id")!r} is not a float array of {least} or more a row')
        x = floats(fa)
        return x[:x.size // step * step].reshape(-1, step)[:, :least]

    up = root.find('asset/up_axis')
    axis = (up.text or '').strip().upper() if up is not None else 'Y_UP'   # (COLLADA's default)
    if axis not in ('Y_UP', 'Z_UP'):
        raise MeshError(f'up axis {axis}')
    unit = root.find('asset/unit')
    meter = float(unit.get('meter', '1')) if unit is not None else 1.0
    scene = root.find('scene/instance_visual_scene')
    if scene is None:
        raise MeshError('no <scene><instance_visual_scene>')
    out = []

    def node_matrix(node):
        m = np.eye(4)
        for t in node:
            if t.tag == 'matrix':
                step = floats(t, 16).reshape(4, 4)
            elif t.tag == 'translate':
                step = np.eye(4)
                step[:3, 3] = floats(t, 3)
            elif t.tag == 'scale':
                step = np.diag(np.append(floats(t, 3), 1.0))
            elif t.tag == 'rotate':
                x = floats(t, 4)
                direction, angle = x[:3], np.radians(x[3])
                norm = np.linalg.norm(direction)
                if norm == 0.0:
                    raise MeshError('<rotate> about a zero axis')
                k = direction / norm
                kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
                step = np.eye(4)
                step[:3, :3] = np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * kx @ kx
            elif t.tag in ('lookat', 'skew'):
                raise MeshError(f'a <{t.tag}> node transform')
            else:
                continue
            m = m @ step
        return m

    def texture_image(effect, name):
        """(file name, bytes, media type) of the image a <texture texture=name> of effect samples: its sampler,
        surface and image, as ColladaLoader follows them (or an image named directly)."""
        params = {p.get('sid'): p for p in effect.iter('newparam')}
        for _ in range(4):
            p = params.get(name)
            if p is None:
                break
            nxt = p.find('sampler2D/source')
            if nxt is None:
                nxt = p.find('surface/init_from')
            if nxt is None:
                break
            name = (nxt.text or '').strip()
        image = ids.get(name)
        init = image.find('init_from') if image is not None and image.tag == 'image' else None
        if init is not None and init.find('ref') is not None:   # (COLLADA 1.5)
            init = init.find('ref')
        file = (init.text or '').strip() if init is not None else ''
        if file.startswith('file://'):
            file = file[len('file://'):]
        kind = TEXTURE_TYPES.get(Path(file).suffix.lower())
        if not file or kind is None or read is None:
            raise MeshError(f'a texture ({file or name!r})' if file or name else 'a texture')
        try:
            return file, read(file), kind
        except (OSError, MeshError) as e:
            raise MeshError(f'a texture ({file!r}) that cannot be read: {e}') from None

    def material(mat):
        """(rgba, image or None) of a material."""
        effect = target(mat.find('instance_effect'))
        for technique in effect.iter('technique'):
            for shading in technique:
                if shading.tag not in ('lambert', 'phong', 'blinn', 'constant'):
                    continue
                diffuse = shading.find('diffuse' if shading.tag != 'constant' else 'emission')
                if diffuse is None:
                    return np.ones(4), None
                tex = diffuse.find('texture')
                if tex is not None:
                    return np.ones(4), texture_image(effect, tex.get('texture') or '')
                c = diffuse.find('color')
                return (floats(c, 4) if c is not None else np.ones(4)), None
        raise MeshError('a material without a common-profile technique')

    def geometry(inst, m):
        geo = target(inst)
        mesh = geo.find('mesh')
        if mesh is None:
            raise MeshError(f'geometry {geo.get("id")!r} is not a <mesh>')
        bound = {im.get('symbol'): im for im in inst.iter('instance_material')}
        for prim in mesh:
            if prim.tag in ('source', 'vertices', 'extra'):
                continue
            if prim.tag not in COLLADA_PRIMITIVES:
                raise MeshError(f'a <{prim.tag}> primitive')
            inputs = prim.findall('input')
            stride = 1 + max(int(i.get('offset', '0')) for i in inputs)
            vin = next((i for i in inputs if i.get('semantic') == 'VERTEX'), None)
            if vin is None:
                raise MeshError(f'a <{prim.tag}> without VERTEX input')
            vert = target(vin, 'source')
            pin = next((i for i in vert.findall('input') if i.get('semantic') == 'POSITION'), None)
            if pin is None:
                raise MeshError(f'vertices {vert.get("id")!r} without POSITION')
            pos = columns(target(pin, 'source'), 3)
            sym = prim.get('material')
            rgba, image = material(target(bound[sym], 'target')) if sym in bound and materials else (np.ones(4), None)
            polys = prim.findall('p')
            if prim.find('ph') is not None:
                raise MeshError('a polygon with holes (<ph>)')
            if prim.tag != 'polygons' and len(polys) > 1:
                raise MeshError(f'a <{prim.tag}> of {len(polys)} <p>')
            per_p = [_numbers(p.text, np.int64).reshape(-1, stride) for p in polys]
            rows = np.concatenate(per_p) if per_p else np.zeros((0, stride), dtype=np.int64)
            idx = rows[:, int(vin.get('offset', '0'))]   # each corner's position
            with np.errstate(all='ignore'):   # (a non-finite vertex is refused below, once)
                world = (pos @ m[:3, :3].T + m[:3, 3]) * meter
            if prim.tag == 'lines':   # segments: pairs of corners
                if idx.size % 2:
                    raise MeshError(f'a <lines> of {idx.size} corners')
                if idx.size and (idx.min() < 0 or idx.max() >= len(pos)):
                    raise MeshError(f'a <lines> index beyond its {len(pos)} positions')
                out.append(ColladaPrimitive(world, idx.reshape(-1, 2), rgba))
                continue
            if prim.tag == 'triangles':
                counts = np.full(idx.size // 3, 3)
            elif prim.tag == 'polylist':
                vc = prim.find('vcount')
                counts = _numbers(vc.text if vc is not None else '', np.int64)
            else:
                counts = np.array([len(r) for r in per_p], dtype=np.int64)   # (one polygon a <p>)
            if counts.sum() != idx.size or (counts < 3).any():
                raise MeshError(f'a <{prim.tag}> whose corner counts do not match its indices')
            fan = counts - 2                                  # triangles per polygon
            first = np.repeat(np.cumsum(counts) - counts, fan)   # each triangle's polygon's first corner
            k = np.arange(fan.sum()) - np.repeat(np.cumsum(fan) - fan, fan) + 1
            corners = np.stack([first, first + k, first + k + 1], axis=1)   # triangles of corner numbers
            if idx.size and (idx.min() < 0 or idx.max() >= len(pos)):
                raise MeshError(f'a <{prim.tag}> index beyond its {len(pos)} positions')
            if image is None:
                out.append(ColladaPrimitive(world, idx[corners], rgba))
                continue
            tin = sorted((i for i in inputs if i.get('semantic') == 'TEXCOORD'), key=lambda i: int(i.get('set', '0')))
            if not tin:
                raise MeshError(f'a textured <{prim.tag}> without TEXCOORD input')
            uv = columns(target(tin[0], 'source'), 2)
            uidx = rows[:, int(tin[0].get('offset', '0'))]
            if uidx.size and (uidx.min() < 0 or uidx.max() >= len(uv)):
                raise MeshError(f'a <{prim.tag}> texture coordinate index beyond its {len(uv)}')
            pairs, vertex = np.unique(np.stack([idx, uidx], axis=1), axis=0, return_inverse=True)
            vertex = vertex.reshape(-1)
            out.append(ColladaPrimitive(world[pairs[:, 0]], vertex[corners], rgba, uv[pairs[:, 1]], image))

    def visit(node, parent, depth=0):
        if depth > 64:
            raise MeshError('nodes nested deeper than 64 (a cycle of <instance_node>?)')
        m = parent @ node_matrix(node)
        for child in node:
            if child.tag == 'instance_geometry':
                geometry(child, m)
            elif child.tag == 'instance_controller':
                raise MeshError('a skinned <instance_controller>')
            elif child.tag == 'instance_node':
                visit(target(child), m, depth + 1)
            elif child.tag == 'node':
                visit(child, m, depth + 1)

    for node in target(scene).findall('node'):
        visit(node, np.eye(4))
    if not out or not any(len(p[1]) for p in out):
        raise MeshError('no triangles or lines in the visual scene')
    for p in out:   # (the vertices and coordinates drawn: a glTF holds finite numbers only)
        used = np.unique(p[1])
        if not np.isfinite(p[0][used]).all() or (p[3] is not None and not np.isfinite(p[3][used]).all()):
            raise MeshError('a vertex or texture coordinate that is not a finite number')
    return out, axis == 'Z_UP'


def bounding_sphere(vertices, scale=(1.0, 1.0, 1.0)):
    """``(centre (3,), radius)`` of a sphere enclosing the scaled vertices: the centre of their bounding
    box and the largest distance from it."""
    v = np.asarray(vertices, dtype=float) * np.asarray(scale, dtype=float)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return c, float(np.sqrt(((v - c) ** 2).sum(axis=1).max()))


def mesh_sphere(name: str, scale=(1.0, 1.0, 1.0), urdf_dir: Path | None = None):
    """:func:`bounding_sphere` of a URDF mesh reference (resolved by :func:`resolve_uri`); raises MeshError."""
    return bounding_sphere(mesh_vertices(resolve_uri(name, urdf_dir)), scale)
