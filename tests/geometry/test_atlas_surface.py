"""The Surface of an atlas: texel areas, positions and normals against the meshes' known geometry."""

import numpy as np
import pytest
import torch
import trimesh
from atlas_meshes import cube_atlas, open_cylinder, uv_sphere

from torchrefl.geometry.atlas_surface import atlas_geometry, load_atlas_geometry
from torchrefl.geometry.mesh_file import write_obj


def on_mesh_distance(mesh, surface):
    """Distance of each texel's position from the mesh face it names (trimesh's point-triangle distance)."""
    triangles = mesh.vertices[mesh.faces[surface.extras["face"]]]
    points = surface.positions.numpy()
    return np.linalg.norm(trimesh.triangles.closest_point(triangles, points) - points, axis=1)


def test_cube_texels_tile_each_face_exactly():
    geom = atlas_geometry(cube_atlas(side_texels=16, texel_mm=0.5), texture_size=64)
    s = geom.surface
    assert s.grid_shape == (64, 64)
    assert s.num_texels == 6 * 16 * 16
    assert torch.allclose(s.areas, torch.full_like(s.areas, 0.25))
    # Texel centres sit half a texel in from the face edges: coordinates are odd multiples of 0.25 mm or the
    # face planes 0 and 8 mm.
    p = s.positions.numpy()
    on_plane = np.isclose(p, 0) | np.isclose(p, 8)
    assert (on_plane.sum(1) == 1).all()
    inner = p[~on_plane].reshape(-1) / 0.25
    assert np.allclose(inner, np.round(inner)) and (np.round(inner) % 2 == 1).all()
    # Flat faces keep their face normals (creases at the cube's edges): the axis towards the face's plane.
    n = s.normals.numpy()
    expected = np.where(np.isclose(p, 8), 1.0, np.where(np.isclose(p, 0), -1.0, 0.0))
    assert np.allclose(n, expected)
    assert set(s.extras) >= {"face", "barycentric", "chart"}
    assert geom.parametrised is False


def test_uv_sphere_area_positions_and_normals():
    r = 20.0
    mesh = uv_sphere(r, 48, 96)
    s = atlas_geometry(mesh, texture_size=256).surface
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert float(s.areas.sum()) == pytest.approx(tm.area, rel=0.01)
    assert float(s.areas.sum()) == pytest.approx(4 * np.pi * r * r, rel=0.02)
    assert on_mesh_distance(mesh, s).max() < 1e-6
    # Inside the sphere by at most the sagitta of the widest facet.
    radius = np.linalg.norm(s.positions.numpy(), axis=1)
    assert radius.max() <= r + 1e-9 and radius.min() > r * np.cos(np.pi / 48)
    radial = s.positions.numpy() / np.linalg.norm(s.positions.numpy(), axis=1, keepdims=True)
    cos = np.einsum("ti,ti->t", s.normals.numpy(), radial)
    assert np.percentile(cos, 1) > np.cos(np.radians(2.0))
    assert cos.min() > np.cos(np.radians(6.0))


def test_cylinder_normals_are_horizontal_and_radial():
    mesh = open_cylinder(10.0, 30.0, 8, 96)
    s = atlas_geometry(mesh, texture_size=128).surface
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert float(s.areas.sum()) == pytest.approx(tm.area, rel=0.01)
    p, n = s.positions.numpy(), s.normals.numpy()
    assert on_mesh_distance(mesh, s).max() < 1e-6
    radial = p[:, :2] / np.linalg.norm(p[:, :2], axis=1, keepdims=True)
    assert np.abs(n[:, 2]).max() < 1e-9
    assert np.einsum("ti,ti->t", n[:, :2], radial).min() > np.cos(np.radians(1.0))


def test_face_normals_on_request():
    mesh = uv_sphere(5.0, 12, 24)
    s = atlas_geometry(mesh, texture_size=64, face_normals=True).surface
    f = s.extras["face"]
    v = mesh.vertices[mesh.faces[f]]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    ok = np.linalg.norm(fn, axis=1) > 1e-9
    fn = fn[ok] / np.linalg.norm(fn[ok], axis=1, keepdims=True)
    assert np.allclose(s.normals.numpy()[ok], fn)


def test_hand_written_obj_rasterises_to_hand_computed_texels(tmp_path):
    # A 4 x 2 cm rectangle (units cm) whose UVs fill the left half of a 4 x 4 atlas (u in [0, 0.5]).
    (tmp_path / "mesh.obj").write_text(
        "v 0 0 0\nv 4 0 0\nv 4 2 0\nv 0 2 0\nvt 0 0\nvt 0.5 0\nvt 0.5 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    geom = load_atlas_geometry(tmp_path / "mesh.obj", texture_size=4, units="cm")
    s = geom.surface
    # Texels (row, col) with col in {0, 1}: centre uv ((col + 0.5) / 4, 1 - (row + 0.5) / 4); x = 40 mm * u / 0.5,
    # y = 20 mm * v; each texel covers 20 mm x 5 mm.
    rows, cols = np.meshgrid(np.arange(4), np.arange(2), indexing="ij")
    expected_index = np.sort((rows * 4 + cols).ravel())
    assert s.texel_index.tolist() == expected_index.tolist()
    r, c = s.texel_index.numpy() // 4, s.texel_index.numpy() % 4
    expected = np.stack([80.0 * (c + 0.5) / 4, 20.0 * (1 - (r + 0.5) / 4), np.zeros(len(r))], axis=1)
    assert np.allclose(s.positions.numpy(), expected)
    assert np.allclose(s.areas.numpy(), 100.0)
    assert np.allclose(s.normals.numpy(), [0, 0, 1])


def test_mesh_without_uvs_gets_an_atlas_written_back_with_it(tmp_path):
    tm = trimesh.creation.icosphere(2, radius=10.0)
    path = tmp_path / "mesh.ply"
    tm.export(path)
    geom = load_atlas_geometry(path, texture_size=128)
    assert geom.parametrised and geom.mesh.uvs is not None
    assert np.unique(geom.surface.extras["face"]).size == len(tm.faces)
    assert float(geom.surface.areas.sum()) == pytest.approx(tm.area, rel=0.03)
    write_obj(tmp_path / "atlas.obj", geom.mesh)
    again = load_atlas_geometry(tmp_path / "atlas.obj", texture_size=128)
    assert not again.parametrised
    assert again.surface.texel_index.tolist() == geom.surface.texel_index.tolist()
    assert torch.allclose(again.surface.positions, geom.surface.positions, atol=1e-5)
