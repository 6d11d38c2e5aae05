"""The Embree boundary against a slow, obvious reference: Moller-Trumbore over every triangle in float64.

Embree works in float32, so the reference is two-sided where a ray grazes an edge or ends near a
surface: a hit the reference finds well inside a triangle (barycentric margin > EPS) and well within
the ray's range must be found; anything Embree reports must be a hit the reference allows with a
tolerance of EPS on the edges. Nearest hits must be the nearest, up to exact ties.
"""

import numpy as np
import pytest
import trimesh

from torchrefl.core.rays import RayTracer, aimed_rays, raw_embree_rate
from torchrefl.errors import ConfigError, GeometryError

EPS = 1e-4


def moller_trumbore(vertices, faces, origins, dirs):
    """Every ray against every triangle: t, u, v and the barycentric margin min(u, v, 1-u-v), each (N, F).
    dirs: unit. t is NaN where the ray is parallel to the triangle's plane."""
    v0, v1, v2 = (np.asarray(vertices, dtype=np.float64)[faces[:, k]] for k in range(3))
    e1, e2 = v1 - v0, v2 - v0  # (F, 3)
    p = np.cross(dirs[:, None, :], e2[None])  # (N, F, 3)
    det = np.einsum("nfi,fi->nf", p, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(np.abs(det) > 1e-15, 1.0 / det, np.nan)
        s = origins[:, None, :] - v0[None]
        u = np.einsum("nfi,nfi->nf", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("nfi,ni->nf", q, dirs) * inv
        t = np.einsum("nfi,fi->nf", q, e2) * inv
    margin = np.minimum(np.minimum(u, v), 1 - u - v)
    return t, u, v, margin


def hit_intervals(t, margin, far):
    """Triangles the ray must hit (strict) and may hit (loose) within [0, far); (N, F) bool each."""
    far = np.broadcast_to(np.asarray(far, dtype=np.float64), t.shape[:1])[:, None]
    strict = (margin > EPS) & (t > EPS) & (t < far - EPS)
    loose = (margin > -EPS) & (t > -EPS) & (t < far + EPS)
    return strict, loose  # comparisons with NaN t are False


@pytest.fixture(scope="module")
def scene():
    """Icosphere plus random triangles (some crossing the sphere), and rays from a box around it."""
    rng = np.random.default_rng(0)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    centres = rng.uniform(-2.0, 2.0, size=(120, 1, 3))
    loose_tris = centres + rng.normal(scale=0.4, size=(120, 3, 3))
    vertices = np.concatenate([sphere.vertices, loose_tris.reshape(-1, 3)])
    faces = np.concatenate([sphere.faces, len(sphere.vertices) + np.arange(360).reshape(120, 3)])
    n = 3000
    origins = rng.uniform(-3.0, 3.0, size=(n, 3))
    dirs = rng.uniform(-1.5, 1.5, size=(n, 3)) - origins
    dirs[: n // 10] = rng.normal(size=(n // 10, 3))  # some rays aimed anywhere (misses)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, u, v, margin = moller_trumbore(vertices, faces, origins, dirs)
    return vertices, faces, origins, dirs, t, u, v, margin


def check_closest(hits, t, u, v, margin, far=np.inf):
    strict, loose = hit_intervals(t, margin, far)
    must, may = strict.any(1), loose.any(1)
    assert (hits.hit[must]).all(), "reference hits a triangle well inside, Embree misses"
    assert (may[hits.hit]).all(), "Embree hits where the reference allows no hit"
    r = np.flatnonzero(hits.hit)
    k = hits.triangle[r]
    assert loose[r, k].all(), "the reported triangle is not hit by the reported ray"
    np.testing.assert_allclose(hits.distance[r], t[r, k], rtol=EPS, atol=1e-5)
    nearest = np.where(strict, t, np.inf).min(1)[r]
    assert (hits.distance[r] <= nearest * (1 + EPS) + 1e-5).all(), "a nearer hit exists"
    np.testing.assert_allclose(hits.barycentric[r], np.stack([u[r, k], v[r, k]], 1), atol=1e-4)
    miss = ~hits.hit
    assert np.isinf(hits.distance[miss]).all() and (hits.triangle[miss] == -1).all()
    assert np.isnan(hits.barycentric[miss]).all()
    return must, may


def test_closest_hit_matches_brute_force(scene):
    vertices, faces, o, d, t, u, v, margin = scene
    scale = np.random.default_rng(2).uniform(0.1, 10.0, size=(len(d), 1))
    hits = RayTracer(vertices, faces).closest_hit(o, d * scale)  # non-unit directions allowed
    must, may = check_closest(hits, t, u, v, margin)
    assert must.sum() > 2000 and (~may).sum() > 100  # the scene tests both hits and misses
    strict, loose = hit_intervals(t, margin, np.inf)
    best = np.where(strict, t, np.inf)
    nearest = best.min(1)
    two = np.sort(np.where(loose, t, np.inf), axis=1)[:, :2]
    clear = must & (two[:, 0] > nearest - 1e-3) & (two[:, 1] > nearest + 1e-3)  # no tie, no edge graze nearer
    assert clear.sum() > 1900
    np.testing.assert_array_equal(hits.triangle[clear], best[clear].argmin(1))


def test_first_hit_triangles_and_per_call_threads_agree_with_closest_hit(scene):
    """The raw fast paths (one Embree call: primitive ids; Embree's hit records) and a per-call thread count give
    closest_hit's triangles."""
    vertices, faces, o, d, t, u, v, margin = scene
    tracer = RayTracer(vertices, faces, threads=2)
    ref = tracer.closest_hit(o, d)
    tri = tracer.first_hit_triangles(
        np.ascontiguousarray(o, dtype=np.float32), np.ascontiguousarray(d, dtype=np.float32)
    )
    assert tri.dtype == np.int64
    np.testing.assert_array_equal(tri, ref.triangle)
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    prim, u, v, dist = tracer.first_hits(
        np.ascontiguousarray(o, dtype=np.float32), np.ascontiguousarray(unit, dtype=np.float32)
    )
    np.testing.assert_array_equal(prim.astype(np.int64), ref.triangle)
    hit = prim >= 0
    np.testing.assert_allclose(dist[hit], ref.distance[hit], rtol=1e-5)  # directions normalised in float64 here
    np.testing.assert_allclose(np.stack([u, v], -1)[hit], ref.barycentric[hit], atol=1e-5)
    one = tracer.closest_hit(o, d, threads=1)
    np.testing.assert_array_equal(one.triangle, ref.triangle)
    np.testing.assert_array_equal(one.distance, ref.distance)
    assert tracer.threads == 2  # the override is per call


def test_closest_hit_with_max_distance(scene):
    vertices, faces, o, d, t, u, v, margin = scene
    far = np.random.default_rng(3).uniform(0.5, 5.0, size=len(o))
    far_in = far.copy()
    hits = RayTracer(vertices, faces).closest_hit(o, d, max_distance=far_in)
    np.testing.assert_array_equal(far_in, far)  # Embree's in-place tfar never leaks
    must, _ = check_closest(hits, t, u, v, margin, far)
    assert must.sum() > 1000 and (hits.distance[hits.hit] <= far[hits.hit] * (1 + 1e-6)).all()


def test_occlusion_matches_segment_test(scene):
    vertices, faces, o, d, t, _, _, margin = scene
    far = np.random.default_rng(1).uniform(0.2, 5.0, size=len(o))
    occ = RayTracer(vertices, faces).occluded(o, d * 2.5, far)
    strict, loose = hit_intervals(t, margin, far)
    must, may = strict.any(1), loose.any(1)
    assert occ[must].all() and may[occ].all()
    assert must.sum() > 500 and (~may).sum() > 500


def test_float32_input_gives_the_same_answers(scene):
    vertices, faces, o, d, *_ = scene
    tr = RayTracer(vertices, faces)
    a = tr.closest_hit(o, d)
    b = RayTracer(vertices.astype(np.float32), faces.astype(np.int32)).closest_hit(
        o.astype(np.float32), d.astype(np.float32)
    )
    np.testing.assert_array_equal(a.distance, b.distance)
    np.testing.assert_array_equal(a.triangle, b.triangle)
    assert a.distance.dtype == np.float64 and a.triangle.dtype == np.int64 and a.barycentric.shape == (len(o), 2)


@pytest.mark.parametrize("threads,chunk", [(2, 1 << 20), (2, 97), (3, 13)])
def test_threads_and_chunks_give_identical_results(scene, threads, chunk):
    vertices, faces, o, d, *_ = scene
    base = RayTracer(vertices, faces, threads=1)
    tr = RayTracer(vertices, faces, threads=threads, chunk_size=chunk)
    a, b = base.closest_hit(o, d), tr.closest_hit(o, d)
    for field in ("distance", "triangle", "barycentric", "hit"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    far = np.linspace(0.1, 4.0, len(o))
    np.testing.assert_array_equal(base.occluded(o, d, far), tr.occluded(o, d, far))
    targets = o + 2.0 * d
    np.testing.assert_array_equal(base.visible(o, d, targets, offset=1e-3), tr.visible(o, d, targets, offset=1e-3))


def test_large_batch_is_split_over_threads(scene):
    """A batch above the split size goes through several chunks on two threads: same answers."""
    vertices, faces, o, d, *_ = scene
    o, d = np.tile(o, (50, 1)), np.tile(d, (50, 1))  # 150k rays: 3 chunks of 65536 or fewer
    a = RayTracer(vertices, faces, threads=1).closest_hit(o, d)
    b = RayTracer(vertices, faces, threads=2).closest_hit(o, d)
    np.testing.assert_array_equal(a.distance, b.distance)
    np.testing.assert_array_equal(a.distance[:3000], a.distance[3000:6000])


def test_visible_from_a_sphere_surface_either_normal_orientation():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    tr = RayTracer(sphere.vertices, sphere.faces)
    rng = np.random.default_rng(4)
    pts = sphere.vertices[:500]
    nrm = sphere.vertex_normals[:500]
    tangent = np.cross(nrm, rng.normal(size=nrm.shape))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    outside = pts + 3.0 * (nrm + rng.uniform(0, 1.0, size=(500, 1)) * tangent)  # within 45 deg of the normal
    for n in (nrm, -nrm, 7.0 * nrm):  # outward, inward, not unit
        assert tr.visible(pts, n, outside, offset=1e-3).all()  # no self-hit
    assert tr.visible(pts, None, outside, offset=1e-3).all()
    behind = -pts * 5.0  # through the sphere
    for n in (nrm, -nrm, None):
        assert not tr.visible(pts, n, behind, offset=1e-3).any()
    assert not tr.visible(pts, nrm, outside, offset=0.0).all()  # without the offset the point hits itself


def test_target_hidden_behind_a_second_object():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    wall = trimesh.creation.box(extents=(0.1, 20, 20))
    wall.apply_translation((3.0, 0, 0))
    m = trimesh.util.concatenate([sphere, wall])
    tr = RayTracer(m.vertices, m.faces)
    facing = np.flatnonzero(sphere.vertex_normals[:, 0] > 0.5)
    p, n = sphere.vertices[facing], sphere.vertex_normals[facing]
    beyond = p + (5.0 - p[:, :1]) / n[:, :1] * n  # x = 5, behind the wall
    before = p + (2.0 - p[:, :1]) / n[:, :1] * n  # x = 2, between sphere and wall
    assert not tr.visible(p, n, beyond, offset=1e-3).any()
    assert tr.visible(p, n, before, offset=1e-3).all()
    on_wall = p + (2.95 - p[:, :1]) / n[:, :1] * n  # target on the wall's surface
    assert tr.visible(p, n, on_wall, offset=1e-3).all()
    assert tr.visible(p, n, p + 1e-4 * n, offset=1e-3).all()  # target within the offset: visible


def test_empty_batches():
    m = trimesh.creation.icosphere(subdivisions=1)
    tr = RayTracer(m.vertices, m.faces)
    h = tr.closest_hit(np.zeros((0, 3)), np.zeros((0, 3)))
    assert h.distance.shape == (0,) and h.triangle.shape == (0,) and h.barycentric.shape == (0, 2)
    assert tr.occluded(np.zeros((0, 3)), np.zeros((0, 3)), 1.0).shape == (0,)
    assert tr.visible(np.zeros((0, 3)), None, np.zeros((0, 3)), offset=1e-3).shape == (0,)
    assert tr.num_triangles == len(m.faces)


_M = trimesh.creation.icosphere(subdivisions=1)
_Z = np.zeros((5, 3))
_ONE = np.tile([0.0, 0.0, 1.0], (5, 1))
_NAN = np.where(np.arange(15).reshape(5, 3) == 7, np.nan, 1.0)


@pytest.mark.parametrize(
    "call,pattern",
    [
        (lambda tr: tr.closest_hit(np.zeros((5, 2)), _ONE), r"origins has shape \(5, 2\), expected \(N, 3\)"),
        (lambda tr: tr.closest_hit(_Z, _ONE[:, :, None]), r"directions has shape \(5, 3, 1\), expected \(N, 3\)"),
        (lambda tr: tr.occluded(_Z, _ONE[:4], 1.0), "directions has 4 rows, expected 5"),
        (lambda tr: tr.closest_hit(_NAN, _ONE), "origins contains NaN or inf .*first at row 2"),
        (lambda tr: tr.occluded(_Z, np.full((5, 3), np.inf), 1.0), "directions contains NaN or inf"),
        (lambda tr: tr.closest_hit(_Z, np.full((5, 3), 1e300)), "directions contains NaN or inf .*float32 range"),
        (lambda tr: tr.closest_hit(_Z, np.zeros((5, 3))), "directions has zero-length vectors, first at row 0"),
        (lambda tr: tr.closest_hit(_Z, _ONE, max_distance=np.ones(4)), r"max_distance has shape \(4,\)"),
        (lambda tr: tr.occluded(_Z, _ONE, np.nan), "max_distance contains NaN"),
        (lambda tr: tr.occluded(_Z, _ONE, -1.0), "max_distance contains NaN or negative"),
        (lambda tr: tr.visible(_Z, _ONE[:3], _ONE, offset=1e-3), "normals has 3 rows, expected 5"),
        (lambda tr: tr.visible(_Z, np.zeros((5, 3)), _ONE, offset=1e-3), "normals has zero-length vectors"),
        (lambda tr: tr.visible(_Z, None, np.zeros((5, 2)), offset=1e-3), r"targets has shape \(5, 2\)"),
        (lambda tr: tr.visible(_NAN, None, _ONE, offset=1e-3), "points contains NaN"),
        (lambda tr: tr.visible(_Z, None, _ONE, offset=-1.0), "offset is -1.0, expected"),
        (lambda tr: RayTracer(np.zeros((0, 3)), np.zeros((0, 3), dtype=int)), "mesh is empty"),
        (lambda tr: RayTracer(_M.vertices[:, :2], _M.faces), r"vertices have shape \(42, 2\)"),
        (lambda tr: RayTracer(_M.vertices, _M.faces.T), r"faces have shape \(3, 80\)"),
        (lambda tr: RayTracer(_M.vertices, _M.faces + 40), "faces index vertices .* out of range 0..41"),
        (lambda tr: RayTracer(_M.vertices, _M.faces.astype(float)), "faces have dtype float64"),
        (lambda tr: RayTracer(np.full((3, 3), np.nan), np.array([[0, 1, 2]])), "vertices contain NaN"),
    ],
)
def test_bad_input_names_the_argument(call, pattern):
    tr = RayTracer(_M.vertices, _M.faces)
    with pytest.raises(GeometryError, match=pattern):
        call(tr)


def test_raw_rate_uses_the_aimed_rays():
    m = trimesh.creation.icosphere(subdivisions=3)
    o, d, far = aimed_rays(m.vertices, 2000)
    hits = RayTracer(m.vertices, m.faces).closest_hit(o, d, far)
    assert hits.hit.mean() > 0.5  # "aimed at the mesh"
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-6)
    assert raw_embree_rate(m.vertices, m.faces, 2000, "OCCLUDED") > 0
    with pytest.raises(ConfigError, match="query is 'CLOSEST'"):
        raw_embree_rate(m.vertices, m.faces, 10, "CLOSEST")


def test_bad_row_is_reported_by_its_index_in_the_whole_batch():
    tr = RayTracer(_M.vertices, _M.faces, chunk_size=3)
    o = np.zeros((10, 3))
    o[7, 1] = np.inf
    with pytest.raises(GeometryError, match="origins contains NaN or inf .*first at row 7"):
        tr.closest_hit(o, np.ones((10, 3)))


def test_occluded_unit_fast_path_matches_occluded():
    import trimesh as _tm

    m = _tm.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(5)
    o = rng.uniform(-2, 2, (500, 3)).astype(np.float32)
    d = rng.normal(size=(500, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    far = rng.uniform(0.1, 4.0, 500).astype(np.float32)
    tr = RayTracer(m.vertices, m.faces)
    np.testing.assert_array_equal(tr.occluded_unit(o, d, far), tr.occluded(o, d, far))
