"""Corner normals: smooth across UV seams and round the sphere, sharp at a cube's edges."""

import numpy as np
import trimesh
from atlas_meshes import cube_atlas, uv_sphere

from torchrefl.geometry.mesh_normals import corner_normals, row_ids, welded_vertices


def test_cube_corners_keep_their_face_normals():
    mesh = cube_atlas()
    n = corner_normals(mesh.vertices, mesh.faces)
    v = mesh.vertices[mesh.faces]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    assert np.allclose(n, fn[:, None, :])
    # With a crease angle above 90 degrees the corners blend the three faces at the cube's corners.
    blended = corner_normals(mesh.vertices, mesh.faces, crease_angle_deg=100.0)
    assert np.allclose(np.abs(blended), 1 / np.sqrt(3))


def test_sphere_corners_are_radial_also_at_the_seam_and_poles():
    mesh = uv_sphere(3.0, 24, 48)
    n = corner_normals(mesh.vertices, mesh.faces)
    radial = mesh.vertices[mesh.faces] / 3.0
    assert np.einsum("fki,fki->fk", n, radial).min() > np.cos(np.radians(1.0))


def test_welding_and_row_ids():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 1e-12], [1, 0, 0.5]], dtype=np.float64)
    w = welded_vertices(v)
    assert w[0] == w[2] and w[1] == w[3] and len(set(w.tolist())) == 3
    assert row_ids(np.array([1, 2, 1, 1]), np.array([5, 5, 5, 6])).tolist() == [0, 2, 0, 1]
    ico = trimesh.creation.icosphere(1)
    assert len(np.unique(welded_vertices(np.concatenate([ico.vertices, ico.vertices])))) == len(ico.vertices)
