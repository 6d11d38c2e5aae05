"""The atlas's hit map: a point of the real mesh goes to the texel under its uv, or the nearest texel of its own
chart; rays inside a closed atlas mesh all land on a texel of the face they hit (no crack along the seams)."""

import numpy as np
import pytest
from conftest import atlas_room

from torchrefl.core.rays import RayTracer
from torchrefl.core.texel_hits import TexelHits


def random_points(F: int, per_face: int, seed: int = 0):
    """(face (N,), bary (3, N)): uniform points on each of F faces, and points a hair inside each edge and corner."""
    rng = np.random.default_rng(seed)
    r1, r2 = rng.random((2, F * per_face))
    s1 = np.sqrt(r1)
    bary = [np.stack([1 - s1, s1 * (1 - r2), s1 * r2])]
    eps = 1e-7
    near = np.array([[eps, 0.5, 0.5 - eps], [0.5, eps, 0.5 - eps], [0.5, 0.5 - eps, eps], [1 - 2 * eps, eps, eps]]).T
    bary.append(np.tile(near, F))
    face = np.concatenate([np.repeat(np.arange(F), per_face), np.repeat(np.arange(F), near.shape[1])])
    return face, np.concatenate(bary, axis=1)


@pytest.mark.parametrize("gap", [1, 0])
def test_each_point_goes_to_the_texel_under_its_uv_or_the_nearest_of_its_chart(gap):
    S = 32
    geom = atlas_room(texture_size=S, gap=gap)
    hits = geom.surface.hits
    assert isinstance(hits, TexelHits)
    face, bary = random_points(len(geom.mesh.faces), 40)
    texel, collects = hits.texels(face, bary)
    assert collects.all()
    # the reference, by hand: the point's uv, its grid cell, and every texel of the face's chart (cube face f // 2)
    uv = np.einsum("kn,nkc->nc", bary, geom.mesh.uvs[face])
    cell = np.stack([np.floor((1 - uv[:, 1]) * S), np.floor(uv[:, 0] * S)], 1)
    texel_cell = np.stack(np.divmod(geom.texels.texel_index, S), 1)
    texel_chart = geom.texels.face // 2
    for k in range(len(face)):
        mine = np.flatnonzero(texel_chart == face[k] // 2)
        d = np.linalg.norm(texel_cell[mine] - cell[k], axis=1)
        assert texel_chart[texel[k]] == face[k] // 2
        assert np.linalg.norm(texel_cell[texel[k]] - cell[k]) == pytest.approx(d.min(), abs=1e-12)
    # the moved UVs leave cells partly covered by a chart whose centre is not: those points took a neighbour
    inside = [(texel_cell[t] == c).all() for t, c in zip(texel, cell)]
    assert 0 < inside.count(False) < len(face)


def test_rays_inside_a_closed_atlas_mesh_all_land_on_a_texel_of_the_face_they_hit():
    geom = atlas_room()
    hits = geom.surface.hits
    tracer = RayTracer(geom.mesh.vertices, geom.mesh.faces)
    rng = np.random.default_rng(1)
    n = 4000
    origins = rng.uniform(0.2, 7.8, (n, 3))
    d = rng.normal(size=(n, 3))
    h = tracer.closest_hit(origins, d)
    assert h.hit.all()  # nothing leaks out along the seams
    texel, _ = hits.texels(h.triangle, np.stack([1 - h.barycentric.sum(1), h.barycentric[:, 0], h.barycentric[:, 1]]))
    assert (geom.texels.face[texel] // 2 == h.triangle // 2).all()
    point = origins + h.distance[:, None] * d / np.linalg.norm(d, axis=1, keepdims=True)
    gap = np.linalg.norm(geom.surface.positions.numpy()[texel] - point, axis=1)
    assert gap.max() < 1.5  # mm: within about a texel (1 mm) of where the ray landed


def test_face_normals_face_the_texels_that_lie_on_them():
    geom = atlas_room()
    fn = geom.surface.hits.face_normals
    n = geom.surface.normals.numpy()
    assert np.allclose(np.linalg.norm(fn, axis=1), 1)
    assert (np.einsum("ti,ti->t", fn[geom.texels.face], n) > 0.99).all()  # the room's walls face in
