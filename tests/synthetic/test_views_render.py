"""The mesh_views renderer's direct and interreflected light against tests/reference/path_tracer.py (which shares
no code with torchrefl) on a concave scene, at a handful of pixels whose surface points the test computes itself."""

import math

import numpy as np
import trimesh
from reference.path_tracer import ReferenceRenderer

from torchrefl.synthetic.materials import PAPER_GLOSSY
from torchrefl.synthetic.objects import object_e
from torchrefl.synthetic.uv_objects import ViewsObject
from torchrefl.synthetic.views_layout import ViewLight, look_at
from torchrefl.synthetic.views_render import ViewsRenderer


def _fold_scene():
    """Object E with glossy paper (flat faces, one material: what the reference renderer models exactly), a camera
    looking into the fold and a light in front of it."""
    mesh = object_e(glossy=True)
    info = mesh.info
    mid = info["fold_start"] + info["fold_dir"] * info["length"] / 2
    bis = info["plate_dirs"].sum(0)
    bis /= np.linalg.norm(bis)
    cam = look_at("cam00", mid + 250 * bis + 30 * info["fold_dir"], mid + 25 * bis, 48, 48, 110.0)
    ldir = bis + 0.5 * info["plate_dirs"][0] - 0.3 * info["fold_dir"]
    light = ViewLight("L00", mid + 280 * ldir / np.linalg.norm(ldir), np.array([60000.0, 50000.0, 40000.0]))
    vn = np.asarray(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals)
    return ViewsObject(mesh, None, vn, concave=True), cam, light


def _inside_hits(obj, cam, supersample):
    """Independent of the renderer: each sub-pixel ray met with the two inside rectangles of the fold (plane
    intersections from Object E's defining geometry). Returns points, normals (N, 3), plate (N,) -1 for rays
    that meet neither within 3 mm of its edges, and the pixel of each ray."""
    info = obj.mesh.info
    o, d, pixel = cam.rays(supersample)
    best = np.full(len(d), np.inf)
    plate = np.full(len(d), -1)
    for k in range(2):
        n = info["inside_normals"][k]
        s = ((info["fold_start"] - o) @ n) / (d @ n)
        q = o + s[:, None] * d - info["fold_start"]
        a, along = q @ info["plate_dirs"][k], q @ info["fold_dir"]
        ok = (s > 0) & (s < best) & (a > 3) & (a < info["width"] - 3) & (along > 3) & (along < info["length"] - 3)
        best = np.where(ok, s, best)
        plate = np.where(ok, k, plate)
    points = o + np.where(np.isfinite(best), best, 0)[:, None] * d
    normals = info["inside_normals"][np.maximum(plate, 0)]
    return points, normals, -d, plate, pixel


def test_direct_and_interreflected_light_match_the_reference_on_a_concave_scene():
    obj, cam, light = _fold_scene()
    ss = 2
    points, normals, views, plate, pixel = _inside_hits(obj, cam, ss)
    full = np.flatnonzero(np.bincount(pixel[plate >= 0], minlength=cam.width * cam.height) == ss * ss)
    dist = np.abs(np.einsum("ni,i->n", points - obj.mesh.info["fold_start"], obj.mesh.info["inside_normals"][1]))
    order = full[np.argsort(dist.reshape(-1, ss * ss)[full, 0])]  # by distance from plate 1's plane
    chosen = order[np.linspace(0, len(order) - 1, 8).astype(int)]
    sub = (chosen[:, None] * ss * ss + np.arange(ss * ss)).ravel()
    pd, ps, sigma = (np.asarray(x, dtype=np.float64) for x in PAPER_GLOSSY)
    V = len(obj.mesh.vertices)
    reference = ReferenceRenderer(
        obj.mesh.vertices,
        obj.mesh.faces,
        obj.vertex_normals,
        np.tile(pd, (V, 1)),
        np.tile(ps, (V, 1)),
        np.full(V, sigma),
        offset=0.01,
        seed=11,
    )
    kappa = np.array([math.pi, 2.5, 2.0])
    n = len(sub)
    args = (points[sub], normals[sub], views[sub], np.tile(pd, (n, 1)), np.tile(ps, (n, 1)), np.full(n, sigma))
    lights = np.broadcast_to(light.position, (1, n, 3))
    ref_direct, _ = reference.render(*args, lights, light.intensity[None], kappa, "direct")
    ref_full, ref_se = reference.render(*args, lights, light.intensity[None], kappa, "full", samples=512)
    per_pixel = lambda a: a[0].reshape(len(chosen), ss * ss, 3).mean(1)  # noqa: E731
    ref_direct, ref_full = per_pixel(ref_direct), per_pixel(ref_full)
    ref_se = np.sqrt((ref_se[0].reshape(len(chosen), ss * ss, 3) ** 2).sum(1)) / (ss * ss)

    direct = ViewsRenderer(obj, kappa=kappa, supersample=ss).radiance(cam, [light], pixels=chosen).values[0]
    np.testing.assert_allclose(direct, ref_direct, rtol=2e-4, atol=1e-7)
    runs = [
        ViewsRenderer(obj, kappa=kappa, supersample=ss, indirect_samples=256, seed=s)
        .radiance(cam, [light], pixels=chosen)
        .values[0]
        for s in (0, 1)
    ]
    mine = (runs[0] + runs[1]) / 2
    my_se = np.sqrt(np.mean((runs[0] - runs[1]) ** 2)) / 2  # pooled over pixels: half the spread of a difference
    indirect = ref_full - ref_direct
    assert (indirect > 0.1 * ref_direct).mean() > 0.5, indirect / ref_direct  # interreflection matters here
    tol = 4 * np.sqrt(ref_se**2 + my_se**2)
    assert (np.abs(mine - ref_full) < tol).all(), (mine - ref_full) / tol
    assert abs((mine - ref_direct).sum() / indirect.sum() - 1) < 0.03
