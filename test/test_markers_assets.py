"""What a viewer draws beside the joints: the contact markers, and the meshes a recording carries.

Markers (``markers``, visualization_msgs/MarkerArray) of an A1 landing are read back from the
recording by rosbags (its own CDR decoder and the recorded schema): a DELETEALL, the touching points
on the ground plane, one arrow per point whose vectors add up to the ground's total force of the
``contact_wrenches`` topics (computed per link by the contact kernel's link sums). Meshes: the
recorded ``robot_description`` holds each mesh as a ``data:`` URI whose bytes are the file's or, as binary
glTF, its triangles (STL, OBJ and COLLADA; read back by trimesh, COLLADA files by trimesh's own reader of them,
pycollada, over every COLLADA file of example-robot-data); the rest of the URDF is unchanged; a mesh that cannot
be found, or beyond the size limit, keeps its reference.
"""
from __future__ import annotations

import base64
import json
import re
import struct
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from robodyn_ros.assets import asset_file, embed_meshes
from robodyn_ros.recording.run_sink import McapRunSink
from robodyn_ros.runs import plan_run, resolve_settings
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator, run_headless

MEDIA = {'.dae': 'model/gltf-binary', '.stl': 'model/stl'}


def _record(path, name, duration):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        scene = load_scene(name)
    plan, st = plan_run(resolve_settings(scene, duration=duration), scene.system, scene.y0)
    sim = Simulator(scene.system, scene.y0, plan=plan)
    sink = McapRunSink(path, scene, {**st, 'mode': 'headless'}, batch=64)
    try:
        run_headless(sim, duration, st['rate'], scene.script, [sink])
    finally:
        sink.close()
    return scene


@pytest.fixture(scope='module')
def a1(tmp_path_factory):
    """(scene, {topic: [(log time, message)]}) of 0.4 s of a1_stand read by rosbags."""
    from rosbags.highlevel import AnyReader
    path = tmp_path_factory.mktemp('a1') / 'a1.mcap'
    scene = _record(path, 'a1_stand', 0.4)
    msgs = {}
    with AnyReader([path]) as reader:
        for c, t, raw in reader.messages():
            msgs.setdefault(c.topic, []).append((t, reader.deserialize(raw, c.msgtype)))
    return scene, msgs


def test_markers_draw_the_touching_points_and_the_grounds_force(a1):
    scene, msgs = a1
    markers = msgs['/markers']
    assert len(markers) == len(msgs['/joint_states']) == 81     # one per publication (200 Hz)
    weight = scene.system.model.total_mass() * 9.81
    touching = 0
    for (t, m), (tw, *_) in zip(markers, msgs['/joint_states']):
        assert t == tw
        first, rest = m.markers[0], m.markers[1:]
        assert first.action == 3                                  # DELETEALL: the last period's markers go
        assert all(x.header.frame_id == scene.system.contact.frame and
                   x.header.stamp.sec * 10**9 + x.header.stamp.nanosec == t for x in m.markers)
        if not rest:
            continue
        touching += 1
        spheres = [x for x in rest if x.type == 7]
        arrows = [x for x in rest if x.type == 0]
        assert len(spheres) == 1 and len(arrows) == len(spheres[0].points) == len(rest) - 1 >= 1
        pts = np.array([[p.x, p.y, p.z] for p in spheres[0].points])
        assert np.all(pts[:, 2] <= 0.0) and np.all(pts[:, 2] > -0.02)   # on the plane z = 0, a few mm in
        tails = np.array([[a.points[0].x, a.points[0].y, a.points[0].z] for a in arrows])
        tips = np.array([[a.points[1].x, a.points[1].y, a.points[1].z] for a in arrows])
        np.testing.assert_array_equal(tails, pts)
        # the arrows at 0.5 m per weight add up to the ground's force on the links (contact_wrenches)
        total = (tips - tails).sum(axis=0) * weight / 0.5
        links = [k for k in msgs if k.startswith('/contact_wrenches/')]
        f = sum(np.array([w.wrench.force.x, w.wrench.force.y, w.wrench.force.z])
                for k in links for tw2, w in msgs[k] if tw2 == t)
        np.testing.assert_allclose(total, f, rtol=1e-9, atol=1e-9 * weight)
        assert f[2] > 0.0
    assert touching >= 40     # dropped from 0.1 m, the A1 stands on its feet within 0.2 s


def test_a_robot_off_the_ground_has_no_markers(tmp_path):
    from robodyn_ros.recording.reader import summarize
    _record(tmp_path / 'arm.mcap', 'stanford_arm', 0.05)
    assert '/markers' not in summarize(tmp_path / 'arm.mcap')['topics']


def test_the_recorded_description_carries_the_meshes(a1):
    scene, msgs = a1
    original = scene.system.urdf()
    (_, desc), = msgs['/robot_description']
    text = desc.data
    refs = re.findall(r'<mesh\b[^>]*filename="([^"]*)"', original)
    embedded = re.findall(r'<mesh\b[^>]*filename="([^"]*)"', text)
    assert len(refs) == len(embedded) == 13 and all(r.startswith('package://') for r in refs)
    assert len(text.encode()) < 6_000_000   # 3.5 MB with the COLLADA files as glTF (27 MB as they are)
    for ref, uri in zip(refs, embedded):   # the A1's COLLADA files, as glTF of their triangles
        head, _, b64 = uri.partition(',')
        assert head == f'data:{MEDIA[Path(ref).suffix]};base64'
        _assert_collada_drawn_as_gltf(asset_file(ref), base64.b64decode(b64))
    # nothing else changed: the same XML with the references put back
    a, b = ET.fromstring(original), ET.fromstring(text)
    for m, ref in zip(b.iter('mesh'), refs):
        m.set('filename', ref)
    assert ET.tostring(a) == ET.tostring(b)


def test_meshes_not_found_or_beyond_the_limit_keep_their_reference(tmp_path):
    stl = tmp_path / 'part.stl'
    stl.write_bytes(b'solid x\nendsolid x\n')
    urdf = (f'<robot name="r"><link name="a"><visual><geometry><mesh filename="file://{stl}"/></geometry></visual>'
            f'<visual><geometry><mesh filename="package://no_such_pkg/m.dae" scale="1 1 1"/></geometry></visual>'
            f'</link></robot>')
    text, notes = embed_meshes(urdf)
    # an STL without triangles cannot become glTF: embedded as it is, with a note saying so
    assert f'data:model/stl;base64,{base64.b64encode(stl.read_bytes()).decode()}' in text
    assert len(notes) == 2 and 'embedded as it is, not as glTF' in notes[0] and 'no triangles' in notes[0]
    assert 'package://no_such_pkg/m.dae' in text and 'no_such_pkg' in notes[1]
    text, notes = embed_meshes(urdf, limit=5)
    assert text.count('data:') == 0 and f'file://{stl}' in text and len(notes) == 2 and 'MiB' in notes[0]
    assert embed_meshes('<robot name="r"/>') == ('<robot name="r"/>', ())


def _foxglove_turn(v):
    """What Foxglove does to a glTF model (Studio 1.48 ``ModelCache.loadGltf``: ``rotateX(π/2)``, glTF's Y-up to
    ROS's Z-up): (x, y, z) -> (x, −z, y)."""
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def _erd_meshes(pattern):
    from robodyn_ros.urdf import example_robot_data_dir
    return sorted(example_robot_data_dir().glob(pattern))


def test_stl_and_obj_meshes_are_embedded_as_gltf_that_foxglove_turns_back_into_the_file():
    """STL and OBJ meshes are embedded as binary glTF written Y-up, so that Foxglove, which turns glTF to Z-up
    (and STL or OBJ only when told to), draws the file's own triangles. Read back by trimesh (its own GLB, STL
    and OBJ readers): every STL of solo12 and xarm7 and every OBJ of laikago (example-robot-data), turned as
    Foxglove turns glTF, is the file's triangles (float32, exactly, for STL; OBJ: the same area and bounds, its
    polygons fanned), with unit normals on the triangles' own side."""
    import io

    import trimesh
    from robodyn_ros.assets import glb_of_mesh
    stls = _erd_meshes('solo_description/meshes/stl/solo12/*.stl') + _erd_meshes('xarm_description/meshes/**/*.stl')
    objs = _erd_meshes('laikago_description/meshes/*.obj')
    assert len(stls) >= 10 and len(objs) >= 5, (len(stls), len(objs))
    for path in stls + objs:
        data = path.read_bytes()
        scene = trimesh.load(io.BytesIO(glb_of_mesh(data, path.suffix)), file_type='glb', process=False)
        (g,) = scene.geometry.values()
        tri = _foxglove_turn(g.vertices[g.faces])
        ref = trimesh.load(io.BytesIO(data), file_type=path.suffix[1:], process=False, force='mesh')
        if path.suffix == '.stl':
            np.testing.assert_array_equal(tri, ref.vertices[ref.faces].astype(np.float32), err_msg=str(path))
        else:
            assert abs(trimesh.triangles.area(tri).sum() - ref.area) < 1e-5 * ref.area, path
            np.testing.assert_allclose(tri.reshape(-1, 3).min(0), ref.bounds[0], atol=1e-6, err_msg=str(path))
            np.testing.assert_allclose(tri.reshape(-1, 3).max(0), ref.bounds[1], atol=1e-6, err_msg=str(path))
        normals = _foxglove_turn(np.asarray(g.vertex_normals))
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        ok = np.linalg.norm(cross, axis=1) > 1e-12
        per_corner = normals[g.faces[:, 0]]
        assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
        assert (np.einsum('ij,ij->i', per_corner[ok], cross[ok]) > 0).all(), path


def _collada_reference(path):
    """pycollada's reading of a COLLADA file (its own parser; its bound primitives: node transforms applied), as
    Foxglove draws it, times the file's ``<unit meter>``, in ROS's Z-up (a Y-up file turned as Foxglove turns it,
    ``ModelCache.loadCollada``: rotateX(π/2); a Z-up file as it is): ``(triangles (n, 3, 3), colours, ends,
    textured, images)``: the set of its primitives' diffuse colours (RGB) as pycollada reads them, the ends
    (k, 3) of its ``<lines>`` segments, the corners of its textured triangles as rows (x, y, z, u, v) and the
    bytes of their images (pycollada's, placed the same way)."""
    import io

    import collada
    data = path.read_bytes()
    dae = collada.Collada(str(path), ignore=[collada.common.DaeBrokenRefError])   # (from its file: with the images)
    unit = dae.assetInfo.unitmeter or 1.0     # (three.js scales the scene by it)
    turn = (lambda v: v) if b'<up_axis>Z_UP</up_axis>' in data else _foxglove_turn
    tri, colours, ends, textured, images = [], set(), [], [], set()
    for g in dae.scene.objects('geometry'):   # bound: the nodes' transforms applied
        for p in g.primitives():
            if isinstance(p, collada.lineset.BoundLineSet):   # (drawn in its colour, white without a material)
                ends += [line.vertices for line in p]
                m = getattr(p, 'material', None)
                colours.add(tuple(float(x) for x in (m.effect.diffuse if m is not None else (1.0, 1.0, 1.0))[:3]))
                continue
            t = p.triangleset() if hasattr(p, 'triangleset') else p
            xyz = turn(t.vertex[t.vertex_index].reshape(-1, 3) * unit)
            tri.append(xyz.reshape(-1, 3, 3))
            diffuse = p.material.effect.diffuse if p.material is not None else (1.0, 1.0, 1.0)
            if isinstance(diffuse, collada.material.Map):
                images.add(diffuse.sampler.surface.image.data)
                textured.append(np.hstack([xyz, t.texcoordset[0][t.texcoord_indexset[0]].reshape(-1, 2)]))
            else:
                colours.add(tuple(float(x) for x in diffuse[:3]))
    if not tri and not ends:   # a material pycollada cannot follow (a sampler naming no surface, which three.js
        # reads as the image it names): its geometry alone, without the materials (colours and textures unread)
        bare = re.sub(rb'<bind_material>.*?</bind_material>', b'', data, flags=re.S)
        ref = _collada_reference_bare(bare, unit, turn)
        return ref, None, np.zeros((0, 3)), None, None
    tri = np.concatenate(tri) if tri else np.zeros((0, 3, 3))
    ends = turn(np.concatenate(ends).astype(float) * unit) if ends else np.zeros((0, 3))
    return tri, colours, ends, np.concatenate(textured) if textured else np.zeros((0, 5)), images


def _collada_reference_bare(data, unit, turn):
    """The triangles pycollada reads from a COLLADA file's text (its materials left out)."""
    import io

    import collada
    dae = collada.Collada(io.BytesIO(data), ignore=[collada.common.DaeBrokenRefError])
    tri = [turn(t.vertex[t.vertex_index].reshape(-1, 3) * unit).reshape(-1, 3, 3)
           for g in dae.scene.objects('geometry') for p in g.primitives()
           for t in [p.triangleset() if hasattr(p, 'triangleset') else p]]
    return np.concatenate(tri)


def _assert_collada_drawn_as_gltf(path, glb):
    """The GLB of a COLLADA file (read back by trimesh), turned as Foxglove turns glTF, holds the triangles
    pycollada reads from the file (float32; compared as sorted vertex rows, since the order of primitives may
    differ) and its line segments (their ends), each in a material of the file's colour made linear (the sRGB transfer
    function, IEC 61966-2-1, as three.js reads COLLADA colours) or of its texture: the image file's bytes, and at
    each corner of a textured triangle the texture coordinates pycollada reads there (glTF's v turned back:
    ``1 − v``)."""
    import io

    import trimesh
    from scipy.spatial import cKDTree
    gl = trimesh.load(io.BytesIO(glb), file_type='glb', force='scene', process=False)
    got = np.concatenate([_foxglove_turn(g.vertices[g.faces]) for g in gl.geometry.values() if hasattr(g, 'faces')])
    ends = [_foxglove_turn(g.vertices[e.points]) for g in gl.geometry.values() if hasattr(g, 'entities')
            for e in g.entities]
    ref, colours, ref_ends, ref_textured, images = _collada_reference(path)
    ends = np.unique(np.concatenate(ends).astype(np.float32), axis=0) if ends else np.zeros((0, 3), np.float32)
    np.testing.assert_allclose(ends, np.unique(ref_ends.astype(np.float32), axis=0), atol=1e-6, err_msg=str(path))
    assert got.shape == ref.shape, (path, got.shape, ref.shape)
    scale = max(1.0, np.abs(ref).max())
    np.testing.assert_allclose(np.sort(got.reshape(-1, 3), axis=0), np.sort(ref.reshape(-1, 3), axis=0),
                               rtol=0, atol=1e-6 * scale, err_msg=str(path))
    if colours is None:
        return False   # (pycollada could not read its materials: its triangles checked only)
    doc = json.loads(glb[20:20 + struct.unpack_from('<I', glb, 12)[0]])    # the GLB's JSON chunk (glTF 2.0)
    pbr = [m['pbrMetallicRoughness'] for m in doc['materials']]
    linear = {tuple(np.round(m['baseColorFactor'][:3], 9)) for m in pbr if 'baseColorTexture' not in m}
    srgb = np.array(sorted(colours)).reshape(-1, 3)
    expected = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    assert linear == {tuple(np.round(c, 9)) for c in expected}, (path, linear, expected)
    # textures: trimesh's glTF reader gives each vertex its TEXCOORD_0 with v turned back (1 − v)
    corners = [np.hstack([_foxglove_turn(g.vertices[g.faces]).reshape(-1, 3), g.visual.uv[g.faces].reshape(-1, 2)])
               for g in gl.geometry.values() if hasattr(g, 'faces') and getattr(g.visual, 'uv', None) is not None]
    corners = np.concatenate(corners) if corners else np.zeros((0, 5))
    assert len(corners) == len(ref_textured), (path, len(corners), len(ref_textured))
    if len(corners):
        near, _ = cKDTree(ref_textured).query(corners)
        back, _ = cKDTree(corners).query(ref_textured)
        assert near.max() < 1e-5 * scale and back.max() < 1e-5 * scale, (path, near.max(), back.max())
    stored = set()
    for image in doc.get('images', []):
        view = doc['bufferViews'][image['bufferView']]
        start = 20 + struct.unpack_from('<I', glb, 12)[0] + 8 + view.get('byteOffset', 0)
        stored.add(glb[start:start + view['byteLength']])
    assert stored == images, path
    return True


def test_every_collada_file_of_example_robot_data_is_drawn_as_gltf_or_kept_as_it_is():
    """Every COLLADA file example-robot-data ships (262 in 6.0.0) is converted to glTF: the triangles, lines,
    colours and textures (the image files beside it) trimesh and pycollada read from the file, placed and scaled as
    Foxglove places the file. Among them the Y-up and Z-up files with nodes placed by transforms (61 files use
    ``<translate>``/``<rotate>``), those with stray ``<lines>``, the textured ones (ANYmal's, a Tiago camera);
    the glTF is less than a third of the files' bytes."""
    from robodyn_ros.assets import glb_of_collada
    from robodyn_ros.meshes import MeshError
    files = _erd_meshes('**/*.dae')
    assert len(files) >= 200, len(files)
    converted, refused, raw, small, bare = 0, {}, 0, 0, []
    for path in files:
        data = path.read_bytes()
        try:
            glb = glb_of_collada(data, lambda name, d=path.parent: (d / name).read_bytes())
        except MeshError as e:
            refused[path] = str(e)
            continue
        if not _assert_collada_drawn_as_gltf(path, glb):
            bare.append(path.name)
        converted += 1
        raw += len(data)
        small += len(glb)
    print(f'{converted} of {len(files)} COLLADA files as glTF ({raw / 1e6:.1f} -> {small / 1e6:.1f} MB); '
          f'materials pycollada cannot read: {bare}')
    assert not refused and len(bare) <= 2, (refused, bare)
    assert sum(b'<lines' in p.read_bytes() for p in files) >= 5
    assert sum(b'<texture' in p.read_bytes() for p in files) >= 20
    assert small < raw / 3 and sum(b'<rotate' in p.read_bytes() for p in files) >= 50, (small, raw)


def test_every_mesh_of_every_example_robot_data_urdf_is_recorded_as_gltf():
    """The whole table: every example-robot-data URDF that loads (67 of 69; two are refused, as
    docs/urdf_robots.md says) records each of its mesh references (its root link's included, and Talos v2's
    ``package:///`` ones) as a glTF ``data:`` URI, with no note; about 1 400 references in all."""
    import glob
    from robodyn_ros.assets import embed_meshes_parts
    from robodyn_ros.scene import SceneError
    from robodyn_ros.urdf import example_robot_data_dir
    files = sorted(glob.glob(str(example_robot_data_dir() / '**' / '*.urdf'), recursive=True))
    loaded, refused, kinds, kept = 0, [], {}, []
    for f in files:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter('ignore')
                scene = load_scene(f)
        except SceneError:
            refused.append(Path(f).name)
            continue
        loaded += 1
        parts, notes = embed_meshes_parts(scene.system.urdf())
        text = b''.join(parts)
        for kind in re.findall(rb'<mesh\b[^>]*filename="data:([^;"]*)', text):
            kinds[kind] = kinds.get(kind, 0) + 1
        kept += [(Path(f).name, r) for r in re.findall(rb'<mesh\b[^>]*filename="(?!data:)([^"]*)"', text)]
        kept += [(Path(f).name, n) for n in notes]
    print(f'{loaded} of {len(files)} URDFs, meshes embedded: {kinds}; refused: {refused}')
    assert len(files) >= 60 and len(refused) <= 2 and not kept, (refused, kept[:5])
    assert set(kinds) == {b'model/gltf-binary'} and kinds[b'model/gltf-binary'] >= 1000, kinds


def test_a_damaged_collada_file_becomes_gltf_or_is_refused_never_an_error():
    """400 seeded damages of a textured COLLADA file (ANYmal C's hatch): elements removed, attributes dropped or
    pointed nowhere, texts made non-numbers, NaN, huge or negative, one number of an array made NaN or infinite:
    each gives a GLB whose JSON is strict (no
    NaN or infinity) or a MeshError naming what it could not read -- never another exception (a recording
    then embeds the file as it is)."""
    import random

    from robodyn_ros.assets import glb_of_collada
    from robodyn_ros.meshes import MeshError
    (src,) = _erd_meshes('anymal_c_simple_description/meshes/hatch.dae')
    base, rng, made, refused = src.read_bytes(), random.Random(7), 0, 0

    def strict(x):
        raise ValueError(f'{x} in the glTF JSON')
    for _ in range(400):
        root = ET.fromstring(base)
        parents = {c: p for p in root.iter() for c in p}
        for _ in range(rng.randint(1, 3)):
            e = rng.choice(list(root.iter()))
            r = rng.random()
            if r < 0.3 and e in parents:
                parents[e].remove(e)
            elif r < 0.5 and e.attrib:
                del e.attrib[rng.choice(sorted(e.attrib))]
            elif r < 0.65:
                e.text = rng.choice(['x', '', '-1', '1e999', 'nan', '0 0', '99999999999'])
            elif r < 0.8:   # one number of a position or texture coordinate array made NaN or infinite
                arrays = [a for a in root.iter() if a.tag.endswith('float_array') and a.text]
                a = rng.choice(arrays)
                words = a.text.split()
                words[rng.randrange(len(words))] = rng.choice(['nan', '1e999', '-inf'])
                a.text = ' '.join(words)
            elif e.attrib:
                e.set(rng.choice(sorted(e.attrib)), rng.choice(['#nope', '0', '-3', 'x', '']))
        try:
            glb = glb_of_collada(ET.tostring(root), lambda name: (src.parent / name).read_bytes())
        except MeshError:
            refused += 1
            continue
        json.loads(glb[20:20 + struct.unpack_from('<I', glb, 12)[0]], parse_constant=strict)
        made += 1
    assert made >= 50 and refused >= 50, (made, refused)


def test_collada_polygons_nodes_and_what_is_refused():
    """A hand-written COLLADA file with what example-robot-data does not use: a ``<polygons>`` primitive (a quad:
    two triangles), a node placed by ``<translate>``, ``<rotate>`` and ``<scale>`` whose geometry comes through
    ``<instance_node>``, a ``<unit>`` of centimetres: the glTF holds what trimesh reads. A texture, an X-up file,
    line strips and a non-number are refused by name; the caller then embeds the file as it is."""
    from robodyn_ros.assets import embed_meshes, glb_of_collada
    from robodyn_ros.meshes import MeshError

    quad = '<polygons count="1" material="m"><input semantic="VERTEX" source="#v" offset="0"/><p>0 1 2 3</p></polygons>'

    def dae(up='Z_UP', prim=quad, diffuse='<color>0.5 0.25 1 1</color>', pos='0 0 0 1 0 0 1 1 0 0 1 0'):
        return (f'<?xml version="1.0"?><COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">'
                f'<asset><unit meter="0.01"/><up_axis>{up}</up_axis></asset>'
                f'<library_effects><effect id="e"><profile_COMMON><technique sid="c"><phong>'
                f'<diffuse>{diffuse}</diffuse></phong></technique></profile_COMMON></effect></library_effects>'
                f'<library_materials><material id="mat"><instance_effect url="#e"/></material></library_materials>'
                f'<library_geometries><geometry id="g"><mesh><source id="s"><float_array id="fa" count="12">{pos}'
                f'</float_array><technique_common><accessor source="#fa" count="4" stride="3">'
                f'<param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>'
                f'</accessor></technique_common>'
                f'</source><vertices id="v"><input semantic="POSITION" source="#s"/></vertices>{prim}</mesh></geometry>'
                f'</library_geometries><library_nodes><node id="n"><instance_geometry url="#g"><bind_material>'
                f'<technique_common><instance_material symbol="m" target="#mat"/></technique_common></bind_material>'
                f'</instance_geometry></node></library_nodes>'
                f'<library_visual_scenes><visual_scene id="vs"><node id="top"><translate>1 2 3</translate>'
                f'<rotate>0 0 1 90</rotate><scale>2 2 2</scale><instance_node url="#n"/></node></visual_scene>'
                f'</library_visual_scenes><scene><instance_visual_scene url="#vs"/></scene></COLLADA>').encode()

    import tempfile
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / 'quad.dae'
        path.write_bytes(dae())
        glb = glb_of_collada(path.read_bytes())
        _assert_collada_drawn_as_gltf(path, glb)
        ref = _collada_reference(path)[0]
        assert ref.shape == (2, 3, 3)   # (trimesh read the quad, in the place the nodes put it)
        np.testing.assert_allclose(ref.reshape(-1, 3).min(0), [0.01 - 0.02, 0.02, 0.03], atol=1e-8)   # (float32)
        assert glb == glb_of_collada(path.read_bytes())   # deterministic
        empty = '<triangles count="0" material="m"><input semantic="VERTEX" source="#v" offset="0"/><p></p></triangles>'
        assert glb_of_collada(dae(prim=quad + empty)) == glb   # an empty primitive beside it adds nothing
        for kw, why in [({'diffuse': '<texture texture="img" texcoord="uv"/>'}, 'a texture'),
                        ({'up': 'X_UP'}, 'up axis X_UP'),
                        ({'prim': '<linestrips count="1"><input semantic="VERTEX" source="#v" offset="0"/>'
                                  '<p>0 1 2</p></linestrips>'},
                         'a <linestrips> primitive'),
                        ({'pos': '0 0 0 1 0 0 1 1 0 0 1 x'}, 'not a list of numbers')]:
            with pytest.raises(MeshError, match=re.escape(why)):
                glb_of_collada(dae(**kw))
        path.write_bytes(dae(diffuse='<texture texture="img" texcoord="uv"/>'))
        text, notes = embed_meshes(f'<robot name="r"><link name="a"><visual><geometry><mesh filename="file://{path}"/>'
                                   f'</geometry></visual></link></robot>')
        as_it_is = base64.b64encode(path.read_bytes()).decode()
        assert notes == () and f'data:model/vnd.collada+xml;base64,{as_it_is}' in text


def test_an_obj_with_polygons_texture_and_negative_indices_becomes_its_triangles():
    """OBJ faces as files write them (``v/vt/vn``, ``v//vn``, negative indices, a quad): the glTF holds the fan of
    each polygon (a unit square and a triangle: area 1.5), as trimesh reads the same file."""
    import io

    import trimesh
    from robodyn_ros.assets import glb_of_mesh
    text = ('v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n'
            'f 1/1/1 2/1/1 3/1/1 4/1/1\nv 0 0 1\nf -1//1 -5//1 -4//1\n')
    glb = glb_of_mesh(text.encode(), '.obj')
    (g,) = trimesh.load(io.BytesIO(glb), file_type='glb', process=False).geometry.values()
    tri = _foxglove_turn(g.vertices[g.faces])
    ref = trimesh.load(io.BytesIO(text.encode()), file_type='obj', process=False, force='mesh')
    assert len(tri) == 3 and abs(trimesh.triangles.area(tri).sum() - 1.5) < 1e-12 and abs(ref.area - 1.5) < 1e-12
    assert glb == glb_of_mesh(text.encode(), '.obj')     # deterministic


def test_the_block_paths_markers_of_many_periods_are_the_bytes_of_each_periods_message():
    """Markers.state_messages (the block path draws a piece of periods at once, grouped by the number of
    touching points) gives each period the bytes Markers.message makes of it alone, the one the test above
    reads back: A1's drop and landing (all four feet touch down within one period)."""
    from robodyn_ros.recording.markers import MarkerInputs, Markers
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        scene = load_scene('a1_stand')
    s = scene.system
    sim = Simulator(s, scene.y0, integrator='rosenbrock2', dt=1e-3)
    Y = []
    for k in range(60):   # 0.3 s at 200 Hz
        for port, values in scene.script(sim.t, sim.y).items():
            sim.set_command(port, values)
        Y.append(sim.advance((k + 1) / 200.0).copy())
    Y = np.array(Y)
    t_ns = np.arange(1, 61, dtype=np.int64) * 5_000_000 + 2_000_000_000   # a second boundary crossed: sec > 0
    P = s.contact_point_outputs(Y)
    counts = (P[:, :, 9] > 0).sum(axis=1)     # kernels.contact.PACTIVE
    assert P.shape == (60, s.contact.n_points, 10) and set(counts.tolist()) == {0, 4}   # in the air, on four feet
    m = Markers.of(s)
    one_by_one = [m.message(int(t), MarkerInputs.of_state(s, y)) for t, y in zip(t_ns, Y)]
    assert Markers.of(s).state_messages(t_ns, P) == one_by_one
    assert m.state_messages(t_ns[::-1], P[::-1]) == one_by_one[::-1]   # any order of periods


def test_the_recorded_description_is_joined_once_from_pieces_that_share_each_file():
    """embed_meshes_parts (what the recorder writes): joined, the URDF with each reference replaced by its file
    as a data URI (built here with re.sub), a file named by several references is one object among the pieces
    (the A1: 13 references to 5 COLLADA files), and the String CDR the recorder makes of the pieces is the
    generic encoder's of that text."""
    from robodyn_ros.assets import embed_meshes_parts, glb_of_collada
    from robodyn_ros.recording import cdr
    urdf = load_scene('a1_stand').system.urdf()
    parts, notes = embed_meshes_parts(urdf)
    expected = re.sub(r'(<mesh\b[^>]*?\bfilename=")([^"]*)(")',
                      lambda m: m.group(1) + 'data:model/gltf-binary;base64,'
                      + base64.b64encode(glb_of_collada(asset_file(m.group(2)).read_bytes())).decode('ascii')
                      + m.group(3), urdf)
    assert notes == () and b''.join(parts) == expected.encode('utf-8')
    big = [p for p in parts if len(p) > 100_000]
    assert len(big) == 13 and len({id(p) for p in big}) == 5
    enc = cdr._Encoder()
    enc.message('std_msgs/msg/String', {'data': expected})
    assert cdr.string_message_bytes(parts) == bytes(enc.buf)
    assert embed_meshes(urdf) == (expected, ())
