"""The Embree boundary against a brute-force Moller-Trumbore reference."""

import numpy as np
import pytest
import trimesh

from torchrefl.errors import GeometryError
from torchrefl.rays import RayTracer, raw_embree_rate


def brute_force(vertices, faces, origins, dirs):
    """(N,) nearest t > 0 along unit dirs (inf on miss) and triangle index, by testing every triangle."""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    e1, e2 = v1 - v0, v2 - v0
    best_t = np.full(len(origins), np.inf)
    best_i = np.full(len(origins), -1)
    for r, (o, d) in enumerate(zip(origins, dirs)):
        p = np.cross(d, e2)
        det = (e1 * p).sum(1)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - v0
        u = (s * p).sum(1) * inv
        q = np.cross(s, e1)
        v = (q * d).sum(1) * inv
        t = (q * e2).sum(1) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
        if hit.any():
            k = np.flatnonzero(hit)[np.argmin(t[hit])]
            best_t[r], best_i[r] = t[k], k
    return best_t, best_i


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(0)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    box.apply_translation((2.0, 0.0, 0.0))
    mesh = trimesh.util.concatenate([sphere, box])
    n = 2000
    origins = rng.uniform(-3, 3, size=(n, 3))
    targets = rng.uniform(-1.2, 2.5, size=(n, 3))
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, i = brute_force(mesh.vertices, mesh.faces, origins, dirs)
    return mesh, origins, dirs, t, i


def test_closest_hit_matches_brute_force(scene):
    mesh, o, d, t, i = scene
    hits = RayTracer(mesh.vertices, mesh.faces).closest_hit(o, d * 3.0)   # non-unit directions allowed
    assert (hits.hit == np.isfinite(t)).mean() > 0.998                     # edge grazes may differ
    both = hits.hit & np.isfinite(t)
    np.testing.assert_allclose(hits.distance[both], t[both], rtol=1e-4, atol=1e-5)
    assert (hits.triangle[both] == i[both]).mean() > 0.99
    assert np.isnan(hits.barycentric[~hits.hit]).all()


def test_occlusion_matches_segment_test(scene):
    mesh, o, d, t, _ = scene
    rng = np.random.default_rng(1)
    far = rng.uniform(0.5, 5.0, size=len(o))
    occ = RayTracer(mesh.vertices, mesh.faces).occluded(o, d, far)
    ref = t < far
    assert (occ == ref).mean() > 0.998


@pytest.mark.parametrize("threads,chunk", [(1, 1 << 20), (2, 1 << 20), (2, 97), (3, 13)])
def test_threads_and_chunks_give_identical_results(scene, threads, chunk):
    mesh, o, d, _, _ = scene
    base = RayTracer(mesh.vertices, mesh.faces, threads=1)
    tr = RayTracer(mesh.vertices, mesh.faces, threads=threads, chunk_size=chunk)
    a, b = base.closest_hit(o, d), tr.closest_hit(o, d)
    np.testing.assert_array_equal(a.distance, b.distance)
    np.testing.assert_array_equal(a.triangle, b.triangle)
    np.testing.assert_array_equal(base.occluded(o, d, 2.0), tr.occluded(o, d, 2.0))


def test_visible_from_the_surface_with_offset():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    tr = RayTracer(sphere.vertices, sphere.faces)
    pts = sphere.vertices[:200]
    nrm = sphere.vertex_normals[:200]
    outside = pts + 5.0 * nrm                       # straight out: visible, no self-hit
    assert tr.visible(pts, nrm, outside, offset=1e-3).all()
    behind = -pts * 5.0                             # through the sphere: blocked
    assert not tr.visible(pts, nrm, behind, offset=1e-3).any()
    assert not tr.visible(pts, None, behind, offset=1e-3).any()


def test_target_hidden_behind_another_object():
    a = trimesh.creation.box(extents=(1, 1, 1))
    wall = trimesh.creation.box(extents=(0.1, 4, 4))
    wall.apply_translation((2.0, 0, 0))
    m = trimesh.util.concatenate([a, wall])
    tr = RayTracer(m.vertices, m.faces)
    p = np.array([[0.5, 0.0, 0.0]])
    n = np.array([[1.0, 0.0, 0.0]])
    assert not tr.visible(p, n, np.array([[4.0, 0.0, 0.0]]), offset=1e-3)[0]
    assert tr.visible(p, n, np.array([[1.5, 0.0, 0.0]]), offset=1e-3)[0]


def test_empty_batches_and_bad_input():
    m = trimesh.creation.icosphere(subdivisions=1)
    tr = RayTracer(m.vertices, m.faces)
    assert tr.closest_hit(np.zeros((0, 3)), np.zeros((0, 3))).distance.shape == (0,)
    with pytest.raises(GeometryError, match=r"origins has shape \(5, 2\), expected \(N, 3\)"):
        tr.closest_hit(np.zeros((5, 2)), np.zeros((5, 3)))
    with pytest.raises(GeometryError, match="directions has 4 rows, expected 5"):
        tr.occluded(np.zeros((5, 3)), np.ones((4, 3)), 1.0)
    with pytest.raises(GeometryError, match="NaN"):
        tr.closest_hit(np.full((2, 3), np.nan), np.ones((2, 3)))
    with pytest.raises(GeometryError, match="zero-length"):
        tr.closest_hit(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(GeometryError, match="empty"):
        RayTracer(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(GeometryError, match="out of range"):
        RayTracer(m.vertices, m.faces + 1000)
    with pytest.raises(GeometryError, match="NaN"):
        RayTracer(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))


def test_raw_rate_is_positive():
    m = trimesh.creation.icosphere(subdivisions=3)
    assert raw_embree_rate(m.vertices, m.faces, 10000, "OCCLUDED") > 0
