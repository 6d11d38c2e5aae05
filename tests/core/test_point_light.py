"""point_light against a slow per-point reference: the geometry in float64 and the shadow rule of RayTracer.visible's
docstring, traced by Moller-Trumbore against every triangle. Rays that pass within EPS of a triangle's edge
or end within EPS of it are left out of the comparison (Embree works in float32)."""

import numpy as np
import pytest

from torchrefl.core.point_light import PointLight, light_geometry, point_light
from torchrefl.core.rays import RayTracer
from torchrefl.errors import GeometryError

EPS = 1e-4
OFFSET = 0.01


def quad(x0, x1, y0, y1, z):
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.fixture(scope="module")
def scene():
    """A ground plane z = 0 (points on it, normal +z) and a square occluder at z = 1 over |x|, |y| < 0.5."""
    g, gf = quad(-20, 20, -20, 20, 0.0)
    o, of = quad(-0.5, 0.5, -0.5, 0.5, 1.0)
    v = np.concatenate([g, o])
    f = np.concatenate([gf, of + 4])
    return v, f, RayTracer(v, f)


def segment_blocked(v, f, origin, end):
    """(blocked, clear_margin): some triangle crosses origin -> end (0 <= t < |end - origin|), and whether the
    answer is robust (no triangle within EPS of deciding otherwise)."""
    d = end - origin
    far = np.linalg.norm(d)
    d = d / far
    blocked, robust = False, True
    for tri in f:
        a, b, c = v[tri]
        e1, e2 = b - a, c - a
        p = np.cross(d, e2)
        det = p @ e1
        if abs(det) < 1e-12:
            continue
        s = origin - a
        u = (s @ p) / det
        q = np.cross(s, e1)
        w = (d @ q) / det
        t = (e2 @ q) / det
        margin = min(u, w, 1 - u - w)
        blocked |= margin > 0 and 0 <= t < far
        must = margin > EPS and EPS < t < far - EPS
        may = margin > -EPS and -EPS < t < far + EPS
        robust &= must == may
    return blocked, robust


def reference(v, f, x, n, L, offset, min_cos=0.0):
    """Per-point loop: direction, distance, cosine, lit, shadowed, robust."""
    N = len(x)
    out = {k: np.zeros(N) for k in ("distance", "cosine")}
    out["direction"] = np.zeros((N, 3))
    out["lit"], out["shadowed"], out["robust"] = (np.zeros(N, bool), np.zeros(N, bool), np.ones(N, bool))
    for i in range(N):
        to = L[i] - x[i]
        d = float(np.sqrt(to @ to))
        u = to / d if d > 0 else np.zeros(3)
        c = float(u @ n[i])
        out["distance"][i], out["direction"][i], out["cosine"][i] = d, u, c
        out["lit"][i] = c > min_cos
        if not out["lit"][i]:
            continue
        side = 1.0 if n[i] @ to >= 0 else -1.0
        origin = x[i] + side * offset * n[i]
        seg = L[i] - origin
        length = float(np.sqrt(seg @ seg))
        if length - offset <= 0:
            continue  # within the offset: nothing traced, unshadowed
        end = origin + seg / length * (length - offset)
        out["shadowed"][i], out["robust"][i] = segment_blocked(v, f, origin, end)
    return out


def cases():
    """(name, point, light): the named cases of the task, on the ground plane (normal +z)."""
    return [
        ("occluder between point and light", [0.0, 0.0, 0.0], [0.1, -0.2, 2.0]),
        ("open sky", [3.0, 0.0, 0.0], [3.0, 1.0, 2.0]),
        ("grazing light, lit", [3.0, 1.0, 0.0], [13.0, 1.0, 0.01]),
        ("grazing light behind the occluder", [-15.0, 0.0, 0.0], [15.0, 0.0, 2.0]),
        ("light behind the surface", [2.0, 2.0, 0.0], [2.5, 2.0, -3.0]),
        ("light in the surface's plane", [2.0, -2.0, 0.0], [6.0, -2.0, 0.0]),
        ("light very near the point", [4.0, 4.0, 0.0], [4.0, 4.0, 0.005]),
        ("light near the point, past the offset", [4.0, -4.0, 0.0], [4.0, -4.0, 0.05]),
        ("light on the point", [-4.0, 4.0, 0.0], [-4.0, 4.0, 0.0]),
        ("light just under the occluder", [0.0, 0.3, 0.0], [0.0, 0.3, 0.995]),
        ("light on the occluder's top", [0.2, 0.2, 0.0], [0.2, 0.2, 1.0 + 1e-3]),
    ]


def expected():
    return {
        "occluder between point and light": (True, True),
        "open sky": (True, False),
        "grazing light, lit": (True, False),
        "grazing light behind the occluder": (True, True),
        "light behind the surface": (False, False),
        "light in the surface's plane": (False, False),
        "light very near the point": (True, False),
        "light near the point, past the offset": (True, False),
        "light on the point": (False, False),
        "light just under the occluder": (True, False),
        "light on the occluder's top": (True, False),
    }


def test_named_cases_match_the_reference_and_the_rule(scene):
    v, f, tr = scene
    names = [c[0] for c in cases()]
    x = np.array([c[1] for c in cases()])
    L = np.array([c[2] for c in cases()])
    n = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    got = point_light(x, n, L, tr, offset=OFFSET)
    ref = reference(v, f, x, n, L, OFFSET)
    assert ref["robust"].all()
    np.testing.assert_allclose(got.distance, ref["distance"], rtol=1e-14)
    np.testing.assert_allclose(got.direction, ref["direction"], rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(got.cosine, ref["cosine"], rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(got.lit, ref["lit"])
    np.testing.assert_array_equal(got.shadowed, ref["shadowed"])
    for i, name in enumerate(names):
        assert (bool(got.lit[i]), bool(got.shadowed[i])) == expected()[name], name
    assert got.visible.tolist() == [lit and not sh for lit, sh in expected().values()]
    assert got.cosine[names.index("grazing light behind the occluder")] < 0.07
    # "light on the occluder's top": the occluder's top face is within the offset of the light, so it does not
    # block; the light's own surface never shadows it (segment shortened at the light)


def test_random_points_lights_and_normals_match_the_reference(scene):
    """Points on the ground, normals tilted either way, one light per point (co-rotating rigs), above and below
    the plane and the occluder."""
    v, f, tr = scene
    rng = np.random.default_rng(1)
    N = 400
    x = np.c_[rng.uniform(-2, 2, (N, 2)), np.zeros(N)]
    n = np.c_[rng.normal(scale=0.3, size=(N, 2)), np.where(rng.random(N) < 0.8, 1.0, -1.0)]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    L = np.c_[rng.uniform(-3, 3, (N, 2)), rng.uniform(-1.5, 3.0, N)]
    for min_cos in (0.0, 0.3):
        got = point_light(x, n, L, tr, offset=OFFSET, min_cos=min_cos)
        ref = reference(v, f, x, n, L, OFFSET, min_cos)
        ok = ref["robust"]
        assert ok.mean() > 0.95
        np.testing.assert_allclose(got.cosine, ref["cosine"], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(got.distance, ref["distance"], rtol=1e-14)
        np.testing.assert_array_equal(got.lit, ref["lit"])
        np.testing.assert_array_equal(got.shadowed[ok], ref["shadowed"][ok])
        assert ref["shadowed"][ok].sum() > 10 and (ref["lit"] & ~ref["shadowed"]).sum() > 10
        E = got.irradiance(np.array([1.0, 2.0, 3.0]))
        vis = ref["lit"] & ~ref["shadowed"]
        ref_E = np.where(vis, np.maximum(ref["cosine"], 0) / ref["distance"] ** 2, 0.0)[:, None] * [1.0, 2.0, 3.0]
        np.testing.assert_allclose(E[ok], ref_E[ok], rtol=1e-12)


def test_trace_mask_no_tracer_float32_and_falloff(scene):
    v, f, tr = scene
    x = np.zeros((3, 3))
    n = np.tile([0.0, 0.0, 1.0], (3, 1))
    L = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [0.0, 0.0, -2.0]])
    got = point_light(x, n, L, tr, offset=OFFSET, trace=[True, False, True])
    assert got.shadowed.tolist() == [True, False, False] and got.visible.tolist() == [False, True, False]
    assert not point_light(x, n, L, None, offset=OFFSET).shadowed.any()
    np.testing.assert_allclose(got.falloff, [0.25, 0.25, 0.25])
    assert got.irradiance(2.0).tolist() == [0.0, 0.5, 0.0]
    g32 = point_light(x.astype(np.float32), n.astype(np.float32), L.astype(np.float32), tr, offset=OFFSET)
    assert g32.direction.dtype == g32.distance.dtype == g32.cosine.dtype == np.float32
    assert g32.shadowed.tolist() == [True, True, False]
    assert isinstance(got, PointLight)


def test_shape_errors(scene):
    _, _, tr = scene
    with pytest.raises(GeometryError, match=r"lights has shape \(2, 3\), expected \(3, 3\)"):
        point_light(np.zeros((3, 3)), np.ones((3, 3)), np.ones((2, 3)), tr, offset=OFFSET)
    with pytest.raises(GeometryError, match="offset"):
        point_light(np.zeros((1, 3)), np.array([[0.0, 0, 1]]), np.array([[0.0, 0, 3]]), tr, offset=-1.0)


def test_light_geometry_of_a_point_and_a_directional_light(scene):
    """A point light is point_light's; a directional light has its direction everywhere, distance 1, and its shadow
    ray reaches past the scene (the occluder at z = 1 shadows the point under it, not the open ground)."""
    _, _, tr = scene
    x = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    n = np.tile([0.0, 0.0, 1.0], (3, 1))
    L = np.array([0.1, -0.2, 2.0])
    point = light_geometry(x, n, tr, position=L, offset=OFFSET)
    ref = point_light(x, n, np.broadcast_to(L, x.shape), tr, offset=OFFSET)
    np.testing.assert_array_equal(point.direction, ref.direction)
    np.testing.assert_array_equal(point.shadowed, ref.shadowed)
    towards = np.array([0.0, 0.28, 0.96])  # meets z = 1 at y = 0.29, over the occluder
    sun = light_geometry(x, n, tr, direction=towards, offset=OFFSET, trace=[True, True, False])
    np.testing.assert_allclose(sun.direction, np.tile(towards, (3, 1)))
    np.testing.assert_allclose(sun.falloff, 1.0)
    np.testing.assert_allclose(sun.cosine, 0.96)
    assert sun.shadowed.tolist() == [True, False, False]  # under the occluder; open ground; not traced
    with pytest.raises(GeometryError, match="exactly one of position"):
        light_geometry(x, n, tr, offset=OFFSET)
