"""Point-light geometry at surface points: the one function every caller uses (the capture loader, the
radiosity level's emitter maps, the photon tracer's landing, the synthetic renderer's direct light and its
next-event estimation).

For N surface points x with normals n and one light position L per point (a rig's lights co-rotate with the
scan, so every point may see its light from another place):

    direction l = (L - x) / |L - x|,  distance d = |L - x|,  cosine = n . l,
    lit = cosine > min_cos,  visible = lit and the shadow ray is unblocked,

and a light of intensity Y gives the irradiance E = Y max(n . l, 0) visible / d^2 (PointLight.irradiance).

`light_geometry` is the same for one light that is either a point light or a directional light (the capture
loader of mesh_views, the relighting renderer): a directional light has its direction everywhere, distance 1 (no
falloff), and its shadow ray ends DIRECTIONAL_REACH scene extents beyond each point.

The shadow test is RayTracer.visible (torchrefl.core.rays), whose docstring states the one origin-offset rule
(`offset` in scene units, e.g. geometry.shadow_offset_mm); only lit points are traced.

Direction, distance and cosine are computed in numpy's promotion of the inputs' dtypes (float32 inputs give
float32 results, as Embree uses; float64 gives float64); the shadow test always runs in float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from torchrefl.errors import GeometryError

#: a directional light's shadow ray ends this many scene extents (the tracer's largest bounding-box side) + 1 away
DIRECTIONAL_REACH = 10.0


@dataclass
class PointLight:
    """Point-light geometry of N surface points.

    direction: (N, 3) unit vector from each point to its light (zero where the light sits on the point).
    distance: (N,) |L - x|.
    cosine: (N,) n . direction (normals as given).
    lit: (N,) bool, cosine > min_cos.
    shadowed: (N,) bool, lit, traced (see point_light's `trace`) and the shadow ray blocked.
    """

    direction: np.ndarray
    distance: np.ndarray
    cosine: np.ndarray
    lit: np.ndarray
    shadowed: np.ndarray

    @property
    def visible(self) -> np.ndarray:
        """(N,) bool: lit and not shadowed."""
        return self.lit & ~self.shadowed

    @property
    def falloff(self) -> np.ndarray:
        """(N,) 1 / d^2."""
        return 1.0 / self.distance**2

    def irradiance(self, intensity=1.0) -> np.ndarray:
        """E = Y max(n . l, 0) visible / d^2: (N,) for a scalar intensity Y, (N, C) for Y of shape (C,)
        (zero where not visible, also at d = 0)."""
        vis = self.visible
        e = np.zeros(len(vis), dtype=np.result_type(self.cosine.dtype, np.float32))
        e[vis] = np.maximum(self.cosine[vis], 0.0) / self.distance[vis] ** 2
        y = np.asarray(intensity)
        return e * y if y.ndim == 0 else e[:, None] * y[None, :]


def point_light(points, normals, lights, tracer, *, offset: float, min_cos: float = 0.0, trace=None) -> PointLight:
    """PointLight of points (N, 3) with normals (N, 3) (unit) lit by lights (N, 3) (one light position per
    point; broadcast a single light with np.broadcast_to(L, points.shape)).

    tracer: a RayTracer of the scene (None: no shadow test, nothing is shadowed); offset: the shadow ray's
    origin offset (RayTracer.visible); min_cos: a point is lit when n . l > min_cos; trace: optional (N,) bool,
    only these points get a shadow ray (the others are never shadowed: for points the caller discards)."""
    x = np.asarray(points)
    n = np.asarray(normals)
    L = np.asarray(lights)
    for name, a in (("points", x), ("normals", n), ("lights", L)):
        if a.ndim != 2 or a.shape[1] != 3 or len(a) != len(x):
            raise GeometryError(f"point_light {name} has shape {a.shape}, expected ({len(x)}, 3)")
    to = L - x
    distance = np.sqrt(np.einsum("ni,ni->n", to, to))
    direction = to / np.maximum(distance, 1e-12)[:, None]
    cosine = np.einsum("ni,ni->n", direction, n)
    lit = cosine > min_cos
    shadowed = np.zeros(len(x), dtype=bool)
    test = lit if trace is None else lit & np.asarray(trace, dtype=bool)
    idx = np.flatnonzero(test)
    if tracer is not None and idx.size:
        shadowed[idx] = ~tracer.visible(x[idx], n[idx], L[idx], offset=offset)
    return PointLight(direction, distance, cosine, lit, shadowed)


def light_geometry(
    points, normals, tracer, *, position=None, direction=None, offset: float, min_cos: float = 0.0, trace=None
) -> PointLight:
    """PointLight of points (N, 3) with normals (N, 3) under one light: a point light at position (3,) or a
    directional light towards direction (3,) (unit): l = direction at every point, distance 1 (falloff 1), the
    shadow ray to a target DIRECTIONAL_REACH scene extents beyond the point (module doc). tracer, offset, min_cos,
    trace: point_light's. GeometryError unless exactly one of position and direction is given."""
    if (position is None) == (direction is None):
        raise GeometryError("light_geometry: give exactly one of position (a point light) and direction")
    x = np.asarray(points)
    if position is not None:
        L = np.broadcast_to(np.asarray(position).astype(x.dtype), x.shape)
        return point_light(x, normals, L, tracer, offset=offset, min_cos=min_cos, trace=trace)
    towards = np.asarray(direction).astype(x.dtype)
    extent = float(np.ptp(tracer.vertices, axis=0).max()) if tracer is not None else 0.0
    targets = x + (DIRECTIONAL_REACH * extent + 1.0) * towards[None]
    pl = point_light(x, normals, targets, tracer, offset=offset, min_cos=min_cos, trace=trace)
    ones = np.ones(len(x), dtype=pl.distance.dtype)
    return PointLight(np.broadcast_to(towards, x.shape), ones, pl.cosine, pl.lit, pl.shadowed)
