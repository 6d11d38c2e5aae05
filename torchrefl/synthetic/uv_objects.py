"""Mesh objects with a texture atlas, for synthetic mesh_views scenes (a mesh + photographs from cameras).

Each is a ViewsObject: a synthetic.objects.MeshObject (the triangle mesh Embree traces, the exact normal and
the material at any surface point) with per-vertex atlas coordinates (seam and pole vertices duplicated, one
uv per vertex, as mesh.obj stores them) and exact per-vertex normals. Atlas convention (the capture format's):
u to the right, v up, texel (row, col) of an S x S atlas centred at uv = ((col + 0.5) / S, 1 - (row + 0.5) / S).

Materials are synthetic.materials.AtlasMaterials evaluated at the atlas coordinates of the surface point,
computed analytically from its position (not interpolated in the hit triangle), so the same function serves
the mesh with UVs, the same mesh written without UVs (atlas made by the loader) and the path tracer's
vertices. Region borders lie on the 1/16 grid of the atlas and on ring / segment boundaries of the mesh
(rings and segments are multiples of the grid), so a texel of a 16 x 2^k atlas never straddles two papers.

- ellipsoid: a UV ellipsoid (convex) about the origin, y up; u = azimuth / 2 pi from +z towards +x,
  v = 1 - polar angle / pi (the top pole on the atlas's top edge); non-uniform glossy papers everywhere.
- bowl: a hemispherical shell (inner radius 45 mm, 4 mm wall) with its opening up (+y), a deep concavity;
  the inside (non-uniform glossy papers) on atlas rows v in [5/16, 1] (its bottom on the top edge, its rim at
  v = 5/16), the outside (uniform matte paint) on v in [1/16, 4/16], the rim's annulus on a strip between.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from torchrefl.errors import GeometryError
from torchrefl.synthetic.materials import _PALETTE, AtlasMaterials, uniform_material
from torchrefl.synthetic.objects import MeshObject

GRID = 16  # material borders lie on multiples of 1/GRID of the atlas


@dataclass
class ViewsObject:
    """A mesh object of a mesh_views scene.

    mesh: the MeshObject (vertices (V, 3) mm, faces (F, 3), exact normal and material functions);
    uv: (V, 2) atlas coordinates in [0, 1] per vertex, or None (the mesh is written without UVs);
    vertex_normals: (V, 3) unit outward normals of the exact surface at the vertices;
    concave: the object sees itself (the renderer path-traces interreflection)."""

    mesh: MeshObject
    uv: np.ndarray | None
    vertex_normals: np.ndarray
    concave: bool


def _orient(vertices: np.ndarray, faces: np.ndarray, normal) -> np.ndarray:
    """faces with every triangle wound so that its geometric normal agrees with the exact normal."""
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    exact = normal(tri.mean(1), np.arange(len(faces)))
    flip = np.einsum("ni,ni->n", fn, exact) < 0
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out


def _sphere_chart(rings: int, segments: int, cap: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A (polar angle, azimuth) chart: parameters s in [0, 1] along the rings (s = 0 a pole), t in [0, 1] around
    (seam duplicated at t = 1), faces (unoriented) and the vertex count. The pole s = 0 is one vertex per
    segment (t at the segment's middle), fanned; cap: the last ring s = 1 is also a pole."""
    last = rings - 1 if cap else rings
    s = np.repeat(np.arange(1, last + 1) / rings, segments + 1)
    t = np.tile(np.arange(segments + 1) / segments, last)
    body = lambda i, j: (i - 1) * (segments + 1) + j  # noqa: E731 (ring i in 1..last, column j)
    n_body = last * (segments + 1)
    j = np.arange(segments)
    faces = [np.stack([n_body + j, body(1, j), body(1, j + 1)], -1)]
    s = np.concatenate([s, np.zeros(segments)])
    t = np.concatenate([t, (j + 0.5) / segments])
    for i in range(1, last):
        a, b, c, d = body(i, j), body(i, j + 1), body(i + 1, j), body(i + 1, j + 1)
        faces += [np.stack([a, c, d], -1), np.stack([a, d, b], -1)]
    if cap:
        pole = n_body + segments + j
        faces.append(np.stack([body(last, j), pole, body(last, j + 1)], -1))
        s = np.concatenate([s, np.ones(segments)])
        t = np.concatenate([t, (j + 0.5) / segments])
    return s, t, np.concatenate(faces)


def _check_grid(rings: int, segments: int, where: str) -> None:
    if rings % GRID or segments % GRID or rings < GRID:
        raise GeometryError(
            f"{where}: rings {rings} and segments {segments} must be positive multiples of {GRID} "
            "(material borders lie on ring and segment boundaries)"
        )


def ellipsoid(
    axes=(40.0, 52.0, 34.0), *, rings: int = 64, segments: int = 128, seed: int = 0, uv: bool = True
) -> ViewsObject:
    """The UV ellipsoid of semi-axes `axes` (x, y, z) mm about the origin (module doc); uv=False: the same
    surface as a closed mesh without seam or pole duplicates, written without UVs."""
    _check_grid(rings, segments, "ellipsoid")
    a = np.asarray(axes, dtype=np.float64)
    s, t, faces = _sphere_chart(rings, segments, cap=True)
    theta, phi = np.pi * s, 2 * np.pi * t
    unit = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), np.sin(theta) * np.cos(phi)], -1)
    verts = a * unit
    papers = AtlasMaterials(seed)

    def normal(points, tri):
        n = np.asarray(points) / a**2
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def material(points, tri):
        q = np.asarray(points) / a
        polar = np.arctan2(np.hypot(q[:, 0], q[:, 2]), q[:, 1])
        return papers(np.arctan2(q[:, 0], q[:, 2]) / (2 * np.pi), 1.0 - polar / np.pi)

    faces = _orient(verts, faces, normal)
    uvs = np.stack([t, 1.0 - s], -1)
    if not uv:
        merged = trimesh.Trimesh(verts, faces, process=True)  # joins the seam and the poles; keeps the face order
        verts, faces, uvs = np.asarray(merged.vertices), np.asarray(merged.faces), None
    info = {"axes": a, "rings": rings, "segments": segments}
    mesh = MeshObject("ellipsoid", verts, faces, normal, material, (-a[1], a[1]), info)
    return ViewsObject(mesh, uvs, normal(verts, None), concave=False)


def bowl(
    *,
    radius: float = 45.0,
    wall: float = 4.0,
    centre_y: float = 22.0,
    rings: int = 44,
    outer_rings: int = 24,
    segments: int = 128,
    seed: int = 0,
) -> ViewsObject:
    """The bowl (module doc): sphere centre at (0, centre_y, 0), opening up; parts inside, outside, rim (faces in
    that order)."""
    if rings % 11 or segments % GRID:
        raise GeometryError(
            f"bowl: rings {rings} must be a multiple of 11 and segments {segments} of {GRID} (the inside spans "
            "11/16 of the atlas; material borders lie on ring and segment boundaries)"
        )
    centre = np.array([0.0, centre_y, 0.0])
    axis = np.array([0.0, 1.0, 0.0])
    e1, e2 = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])  # azimuth 0 towards +z, increasing towards +x

    def unit(alpha, phi):
        return (
            (np.sin(alpha) * np.cos(phi))[:, None] * e1
            + (np.sin(alpha) * np.sin(phi))[:, None] * e2
            - (np.cos(alpha)[:, None] * axis)
        )

    s_in, t_in, f_in = _sphere_chart(rings, segments, cap=False)
    s_out, t_out, f_out = _sphere_chart(outer_rings, segments, cap=False)
    inner = centre + radius * unit(s_in * np.pi / 2, 2 * np.pi * t_in)
    outer = centre + (radius + wall) * unit(s_out * np.pi / 2, 2 * np.pi * t_out)
    n_in, n_out = len(inner), len(outer)
    rim, f_rim, t_rim = _rim_annulus(unit, centre, radius, wall, segments, n_in + n_out)
    verts = np.concatenate([inner, outer, rim])
    faces = np.concatenate([f_in, f_out + n_in, f_rim])
    uvs = np.concatenate(
        [
            np.stack([t_in, 1.0 - 11 / 16 * s_in], -1),
            np.stack([t_out, 1 / 16 + 3 / 16 * s_out], -1),
            np.stack([np.tile(t_rim, 2), np.repeat([4.75 / 16, 4.25 / 16], segments + 1)], -1),
        ]
    )
    fi, fo = len(f_in), len(f_in) + len(f_out)
    papers = AtlasMaterials(seed, v_range=(5 / 16, 1.0))

    def part_of(tri):
        tri = np.asarray(tri)
        return np.where(tri < fi, 0, np.where(tri < fo, 1, 2))

    def normal(points, tri):
        part = part_of(tri)
        dd = np.asarray(points) - centre
        dd = dd / np.maximum(np.linalg.norm(dd, axis=-1, keepdims=True), 1e-12)
        n = np.where((part == 0)[:, None], -dd, dd)
        return np.where((part == 2)[:, None], axis[None, :], n)

    def material(points, tri):
        dd = np.asarray(points) - centre
        alpha = np.arctan2(np.linalg.norm(dd - np.outer(dd @ axis, axis), axis=-1), -dd @ axis)
        u = np.arctan2(dd @ e2, dd @ e1) / (2 * np.pi)
        m = papers(u, 1.0 - 11 / 16 * np.clip(alpha, 0.0, np.pi / 2) / (np.pi / 2))
        inside = part_of(tri) == 0
        paint = uniform_material(len(inside), _PALETTE[0], region=np.full(len(inside), 5))
        return {k: np.where(inside if m[k].ndim == 1 else inside[:, None], m[k], paint[k]) for k in m}

    faces = _orient(verts, faces, normal)
    part_v = np.concatenate([np.zeros(n_in), np.ones(n_out), np.full(len(rim), 2)])
    vn = np.where(
        (part_v == 2)[:, None], axis, (verts - centre) / np.linalg.norm(verts - centre, axis=-1, keepdims=True)
    )
    vn = np.where((part_v == 0)[:, None], -vn, vn)
    info = {"centre": centre, "axis": axis, "radius": radius, "wall": wall, "inner_faces": fi, "outer_faces": fo - fi}
    y = verts[:, 1]
    mesh = MeshObject("bowl", verts, faces, normal, material, (float(y.min()), float(y.max())), info)
    return ViewsObject(mesh, uvs, vn, concave=True)


def _rim_annulus(unit, centre, radius: float, wall: float, segments: int, first: int) -> tuple:
    """The bowl's rim, the flat annulus between the inner and the outer sphere at the opening: (vertices (2 (S + 1),
    3), the inner edge's then the outer's; faces (2 S, 3) numbered from vertex `first`; the edges' azimuth
    coordinate t (S + 1,)) for S = segments. unit(alpha, phi): the unit vector from the centre at polar angle alpha
    from the bottom and azimuth phi."""
    t_rim = np.arange(segments + 1) / segments
    rim_unit = unit(np.full(segments + 1, np.pi / 2), 2 * np.pi * t_rim)
    rim = np.concatenate([centre + radius * rim_unit, centre + (radius + wall) * rim_unit])
    j = np.arange(segments)
    a, b = first + j, first + j + 1  # inner edge of the rim
    c, d = a + segments + 1, b + segments + 1  # outer edge
    f_rim = np.concatenate([np.stack([a, c, d], -1), np.stack([a, d, b], -1)])
    return rim, f_rim, t_rim


VIEWS_OBJECTS = ("ellipsoid", "ellipsoid_no_uv", "bowl")


def make_views_object(name: str, seed: int = 0) -> ViewsObject:
    """The mesh_views object `name`: ellipsoid (convex, with UVs), ellipsoid_no_uv (the same, without UVs), bowl."""
    if name == "ellipsoid":
        return ellipsoid(seed=seed)
    if name == "ellipsoid_no_uv":
        return ellipsoid(seed=seed, uv=False)
    if name == "bowl":
        return bowl(seed=seed)
    raise GeometryError(f"mesh_views object: unknown object '{name}', expected one of {', '.join(VIEWS_OBJECTS)}")
