"""The geometry physics reads of a mesh file (``meshes.mesh_vertices``: a ground part's contact spheres, the
mass and inertia of a link without ``<inertial>``), for COLLADA files against coal's reader (assimp, which
Pinocchio loads collision meshes with), and on a hand-written file against its closed form.

coal, as RViz, builds a mesh from the nodes below the assimp scene's root and leaves the root's own transform
out: the COLLADA file's ``<unit meter>`` and up axis, which assimp puts there. So the oracle is coal's vertices
times the file's unit (RViz applies the unit itself), and the up axis applies to neither."""
from __future__ import annotations

import glob
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import coal
import numpy as np
import pytest
from scipy.spatial import cKDTree

from robodyn_ros.meshes import MeshError, mesh_sphere, mesh_vertices
from robodyn_ros.urdf import example_robot_data_dir


def _unit(path) -> float:
    unit = next((u for u in ET.parse(path).getroot().iter() if isinstance(u.tag, str) and u.tag.endswith('unit')), None)
    return float(unit.get('meter', 1.0)) if unit is not None else 1.0


def test_every_collada_file_of_example_robot_data_is_read_as_coal_reads_it():
    """All 262 COLLADA files: the vertices physics reads are coal's (times the unit), nearest neighbour both
    ways to 1e-6 of the mesh's size (assimp reads and transforms in single precision: 1.9e-7 at worst). 98 of
    them place their geometry by node transforms (scale, rotation: HyQ's trunk, Romeo's links, Tiago's torso),
    which the earlier reader left out."""
    files = sorted(glob.glob(str(example_robot_data_dir() / '**' / '*.dae'), recursive=True))
    assert len(files) >= 262
    loader = coal.MeshLoader()
    worst, moved = 0.0, 0
    for f in files:
        with warnings.catch_warnings():
            warnings.simplefilter('error')
            ours = mesh_vertices(f)
        bvh = loader.load(f, np.ones(3))
        ref = np.asarray(bvh.vertices()) * _unit(f)
        size = np.abs(ref).max()
        d = max(cKDTree(ref).query(ours)[0].max(), cKDTree(ours).query(ref)[0].max()) / size
        worst = max(worst, d)
        raw = np.vstack([np.array(fa.text.split(), dtype=float).reshape(-1, 3)
                         for src in ET.parse(f).getroot().iter() if isinstance(src.tag, str) and src.tag.endswith('source')
                         and 'position' in (src.get('id') or '').lower()
                         for fa in src if isinstance(fa.tag, str) and fa.tag.endswith('float_array') and fa.text]) * _unit(f)
        moved += not np.allclose(np.sort(raw.min(0)), np.sort(ours.min(0)), rtol=1e-6, atol=1e-9 * size)
    assert worst < 1e-6, worst
    assert moved >= 40, moved   # (the node transforms matter: without them these would differ)


DAE = """<?xml version="1.0"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit meter="0.01"/><up_axis>{up}</up_axis></asset>
  <library_geometries><geometry id="g"><mesh>
    <source id="g-positions"><float_array id="a" count="24">-1 -1 -1 1 -1 -1 1 1 -1 -1 1 -1 -1 -1 1 1 -1 1 1 1 1 -1 1 1</float_array>
      <technique_common><accessor source="#a" count="8" stride="3"><param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/></accessor></technique_common></source>
    <vertices id="v"><input semantic="POSITION" source="#g-positions"/></vertices>
    <triangles count="2"><input semantic="VERTEX" source="#v" offset="0"/><p>0 1 2 4 5 6 2 3 0 7 6 5</p></triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="s"><node id="n"><translate>10 5 0</translate><scale>2 2 2</scale>
    <instance_geometry url="#g"/></node></visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>
"""


@pytest.mark.parametrize('up', ['Z_UP', 'Y_UP'])
def test_a_scaled_and_moved_cube_gives_its_closed_form_sphere(tmp_path, up):
    """A cube of half-size 1 placed by ``translate 10 5 0`` then ``scale 2``, in centimetres: its enclosing sphere
    is centred at (0.1, 0.05, 0) m with radius 0.02 √3 m, on either up axis (not applied, as RViz and coal)."""
    f = tmp_path / 'cube.dae'
    f.write_text(DAE.format(up=up))
    c, r = mesh_sphere(str(f))
    assert np.allclose(c, [0.1, 0.05, 0.0], atol=1e-15) and r == pytest.approx(0.02 * np.sqrt(3.0), rel=1e-14)
    c2, r2 = mesh_sphere(str(f), scale=(1.0, 1.0, 3.0))   # a URDF scale multiplies the placed vertices
    assert np.allclose(c2, [0.1, 0.05, 0.0]) and r2 == pytest.approx(0.02 * np.sqrt(11.0), rel=1e-14)


def test_a_file_the_scene_reader_refuses_is_read_raw_with_a_warning(tmp_path):
    """An X-up file (which the viewer's reader refuses): its raw positions times the unit, and a warning that says
    the node transforms are left out; a file with no positions at all is refused."""
    f = tmp_path / 'x.dae'
    f.write_text(DAE.format(up='X_UP'))
    with pytest.warns(UserWarning, match='without the scene.s node transforms'):
        v = mesh_vertices(str(f))
    assert np.allclose(np.abs(v).max(axis=0), 0.01)
    g = tmp_path / 'empty.dae'
    g.write_text('<COLLADA><asset><unit meter="1"/></asset></COLLADA>')
    with pytest.raises(MeshError), warnings.catch_warnings():
        warnings.simplefilter('ignore')
        mesh_vertices(str(g))
