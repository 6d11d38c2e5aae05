"""Reading and writing a mesh_views mesh: units, UVs per face corner, glb scenes, bad files."""

import numpy as np
import pytest
import trimesh

from torchrefl.errors import GeometryError
from torchrefl.geometry.mesh_file import MeshData, read_mesh, write_obj

# Two triangles sharing the edge 1-3 in 3-D, but with different UVs on that edge (a UV seam): vertices 1 and 3
# carry two UVs each.
SEAM_OBJ = """v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0.1 0.1
vt 0.4 0.1
vt 0.4 0.4
vt 0.6 0.6
vt 0.9 0.9
vt 0.6 0.9
f 1/1 2/2 3/3
f 1/4 3/5 4/6
"""


def write(tmp_path, text, name="mesh.obj"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_obj_uvs_are_kept_per_face_corner_across_a_seam(tmp_path):
    mesh = read_mesh(write(tmp_path, SEAM_OBJ))
    corners = mesh.vertices[mesh.faces]
    assert np.allclose(corners[0], [[0, 0, 0], [1, 0, 0], [1, 1, 0]])
    assert np.allclose(corners[1], [[0, 0, 0], [1, 1, 0], [0, 1, 0]])
    assert np.allclose(mesh.uvs[0], [[0.1, 0.1], [0.4, 0.1], [0.4, 0.4]])
    assert np.allclose(mesh.uvs[1], [[0.6, 0.6], [0.9, 0.9], [0.6, 0.9]])


@pytest.mark.parametrize("units, scale", [("mm", 1.0), ("cm", 10.0), ("m", 1000.0), ("in", 25.4)])
def test_units_scale_to_millimetres(tmp_path, units, scale):
    mesh = read_mesh(write(tmp_path, SEAM_OBJ), units=units)
    assert np.allclose(np.ptp(mesh.vertices, axis=0), [scale, scale, 0])


def test_glb_scene_is_one_mesh_with_its_transforms(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box((1, 1, 1))
    scene.add_geometry(box, node_name="a", transform=np.eye(4))
    scene.add_geometry(box.copy(), node_name="b", transform=trimesh.transformations.translation_matrix([0, 5, 0]))
    path = tmp_path / "mesh.glb"
    scene.export(path)
    mesh = read_mesh(path, units="m")
    assert len(mesh.faces) == 2 * len(box.faces)
    assert np.allclose(mesh.vertices.min(axis=0), [-500, -500, -500])
    assert np.allclose(mesh.vertices.max(axis=0), [500, 5500, 500])
    assert mesh.uvs is None


def test_ply_without_uvs(tmp_path):
    tm = trimesh.creation.icosphere(1)
    tm.export(tmp_path / "mesh.ply")
    mesh = read_mesh(tmp_path / "mesh.ply")
    assert not mesh.has_uvs and len(mesh.faces) == len(tm.faces)


def test_write_obj_reads_back_with_the_same_uvs(tmp_path):
    mesh = read_mesh(write(tmp_path, SEAM_OBJ))
    mesh.vertices = mesh.vertices * 12.5
    write_obj(tmp_path / "out.obj", mesh)
    back = trimesh.load(tmp_path / "out.obj", process=False, force="mesh")
    assert np.allclose(np.asarray(back.vertices)[back.faces], mesh.vertices[mesh.faces])
    assert np.allclose(np.asarray(back.visual.uv)[back.faces], mesh.uvs)
    plain = MeshData(mesh.vertices, mesh.faces)
    write_obj(tmp_path / "plain.obj", plain)
    assert not read_mesh(tmp_path / "plain.obj").has_uvs


@pytest.mark.parametrize(
    "text, message",
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
        ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or inf"),
        ("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n", "degenerate"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1.5 0\nvt 0 1\nf 1/1 2/2 3/3\n", "outside"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt -0.2 0\nvt 0 1\nf 1/1 2/2 3/3\n", "outside"),
    ],
)
def test_bad_meshes_name_the_file(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(GeometryError, match=message) as err:
        read_mesh(path)
    assert str(path) in str(err.value)


def test_uvs_just_outside_the_unit_square_are_clipped(tmp_path):
    path = write(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 -0.00001\nvt 1.00001 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    mesh = read_mesh(path)
    assert mesh.uvs.min() == 0.0 and mesh.uvs.max() == 1.0


def test_bad_arguments_name_the_file(tmp_path):
    with pytest.raises(GeometryError, match="units"):
        read_mesh(write(tmp_path, SEAM_OBJ), units="furlong")
    with pytest.raises(GeometryError, match=r"\.stl"):
        read_mesh(write(tmp_path, SEAM_OBJ, "mesh.stl"))
    with pytest.raises(GeometryError, match="not found"):
        read_mesh(tmp_path / "missing.obj")
