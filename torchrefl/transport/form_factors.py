"""Form factors between patches by Monte Carlo hemisphere rays through Embree (dissertation 4.2).

Convention (eq. 4.6): B_u = E_u + rho_u sum_v F_uv B_v, with F_uv the fraction of the energy
leaving patch u that arrives at patch v, so sum_v F_uv <= 1 and A_u F_uv = A_v F_vu (eq. 4.5).

Estimator: eq. 4.2 is the area average over u of the point form factor (eq. 4.4), and the point
form factor is the probability that a ray leaving dA_u with the cosine-weighted density
cos(theta)/pi first reaches A_v (Nusselt's analogue). So, per patch u, `samples_per_patch` rays
start at points drawn from u's candidate origins with probability proportional to their area
weights, leave in cosine-weighted directions about the local normal, and

    F_uv ~= (rays from u whose first hit is on the front of patch v) / (rays from u).

The rays are randomised QMC (torchrefl.core.rqmc: a scrambled Sobol set moved by a uniform shift per
patch, its first coordinate choosing the origin, the other two the direction): each ray is uniform like
an independent one, so the estimate is unbiased, but the origins and directions are stratified. With
independent rays an entry would have the binomial standard error sqrt(F (1 - F) / N) (`sampling_error`);
the stratified rays stay below it (on a closed box: 0.47 of it at 2 000 rays per patch, 0.27 at 32 000,
the error falling like N^-0.7 instead of N^-0.5). On Object E at full size they cut the fitter's own
per-texel Pd noise on the lower plate from 0.45-0.55 % to 0.14-0.27 % (docs/results/object_e_texel_by_texel.md).
The (deterministic) discretisation of u into its candidate origins comes on top. Rays that escape, hit a face that
belongs to no patch (a blocker), or reach the back side of a patch count nowhere: energy arriving at the back of a
range-image surface does not feed the radiosity B of its observed front side (`count_back_hits=True` counts them).
Embree's tnear is 0, so rays start `offset` along the normal.

The patches (square blocks of texels split at folds, and the patch of each mesh face) are in
torchrefl.transport.patches.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import torch

from torchrefl.core.lobe_sampling import tangent_frame
from torchrefl.core.rays import RayTracer
from torchrefl.core.rqmc import sobol_base, toroidal_shift
from torchrefl.core.surface import Surface
from torchrefl.core.texel_hits import TexelHits
from torchrefl.core.threads import thread_map
from torchrefl.errors import ConfigError, GeometryError
from torchrefl.transport.fold_hits import facing_corner, mixed_faces
from torchrefl.transport.patches import Patches, face_corners, face_patches, texel_patches

#: hemisphere_form_factors returns a dense (Q, Q) tensor when Q * Q <= DENSE_MAX_ENTRIES
#: (Q <= 2048: at most 32 MiB in float64), a sparse COO tensor otherwise.
DENSE_MAX_ENTRIES = 2048 * 2048
#: rays per work unit of hemisphere_form_factors (whole patches; one thread samples, traces and tallies a unit)
UNIT_RAYS = 1 << 16


def _as_array(name: str, x, shape_text: str) -> np.ndarray:
    a = x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)
    if not np.issubdtype(a.dtype, np.number):
        raise GeometryError(f"{name} must be numeric {shape_text}, got dtype {a.dtype}")
    return a


@dataclass
class HitPatches:
    """The patch a ray reaches where the mesh's faces hold several texels (an atlas): hits (core/texel_hits.py) maps
    each hit point to its texel, texel_patch (T,) int64 the texel to its patch (-1: none)."""

    hits: TexelHits
    texel_patch: np.ndarray

    def patches(self, tri: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N,) int64 patch of each hit on faces tri (N,) (-1 on a miss) at Embree's barycentrics u, v (N,)."""
        dst = np.full(len(tri), -1, dtype=np.int64)
        hit = np.flatnonzero(tri >= 0)
        if hit.size:
            uh, vh = u[hit], v[hit]
            texel, _ = self.hits.texels(tri[hit], np.stack([1 - uh - vh, uh, vh]))
            texel = np.asarray(texel, dtype=np.int64)
            dst[hit] = np.where(texel >= 0, self.texel_patch[np.maximum(texel, 0)], -1)
        return dst


def hemisphere_form_factors(
    tracer: RayTracer,
    face_patch,
    origins,
    normals,
    weights,
    *,
    samples_per_patch: int,
    seed: int,
    offset: float,
    count_back_hits: bool = False,
    layout: str = "auto",
    progress: Optional[Callable[[int, int], None]] = None,
    corners: Optional[tuple[np.ndarray, np.ndarray]] = None,
) -> torch.Tensor:
    """Form factors F (Q, Q) float64 between Q patches by cosine-weighted hemisphere rays.

    tracer: RayTracer over the scene mesh (F faces). face_patch: (F,) int, patch of each face, -1 for
    faces of no patch (blockers); or a HitPatches, where a face holds several patches (an atlas): a ray's hit point
    then goes to its texel's patch, and the front of a face is the side its hit map's face normal points to.
    origins, normals: (Q, K, 3) candidate ray start points on each
    patch and their normals (unit where the weight is > 0); weights: (Q, K) >= 0 area weights,
    0 = padding, positive row sums.
    Per patch, samples_per_patch rays: an origin drawn with probability weight / row sum, a
    direction with pdf cos(theta)/pi about that origin's normal, start moved `offset` along the
    normal. F_uv = (rays from u whose first hit is on the front of a face of patch v) / N; the front
    is the side the patch normal (weighted mean of its normals) points to, tested per face.
    layout: 'dense', 'sparse' (coalesced COO) or 'auto': dense when Q * Q <= DENSE_MAX_ENTRIES,
    else sparse. Both support .to_dense(). Deterministic in seed (independent of the thread count: each
    work unit of about UNIT_RAYS rays draws from its own stream keyed by seed and unit).
    progress(done_rays, total_rays) is called after each work unit.
    corners: (face_corners) the patches (F, 3) and normals (F, 3, 3) of each face's corners. A hit then goes
    to the patch of the face's first corner only if that corner's normal faces the ray (n . d < 0), else to
    the corner that faces it most (fold_hits.facing_corner). A face that bridges a crease (a range mesh cuts a
    fold's corner with a strip of faces from one side's last texel row to the other's first) is thus seen from each side
    as the other side's surface, which is what a ray crossing that strip reaches on the real object; from its own
    side's texels such a face would otherwise be the texels' own patch, lit like them (Object E at full size:
    the lower plate's row nearest the fold gathered 3 % too little light). Faces with all corners alike are
    unaffected, and so are faces whose corners' normals agree within about 25 degrees (fold_hits.MIXED_COS).
    """
    N = _check_form_factor_options(samples_per_patch, offset, layout)
    o, nm, w, row, used = _check_candidate_origins(origins, normals, weights)
    Q, K = o.shape[:2]
    cdf = torch.from_numpy(np.cumsum(w, axis=1) / row[:, None])
    slot, frames, cstart = _ray_starts(o, nm, used, offset)
    if isinstance(face_patch, HitPatches):
        point = _check_hit_patches(face_patch, tracer, Q)
        front = None if count_back_hits else np.asarray(point.hits.face_normals, dtype=np.float32)
        sampler = _PatchRays(tracer, None, cdf, slot, frames, cstart, front, None, N, int(seed), point)
    else:
        fp = _check_face_patch(face_patch, tracer, Q)
        corner_rule = None if corners is None else _CornerRule.of(corners, len(fp))
        front = None if count_back_hits else _front_faces(tracer, fp, w, nm, Q).astype(np.float32)
        sampler = _PatchRays(tracer, fp, cdf, slot, frames, cstart, front, corner_rule, N, int(seed))

    # work units of whole patches (about UNIT_RAYS rays each), each sampled, traced and tallied by one thread
    # with its own random stream keyed by (seed, unit): the result does not depend on the thread count
    per_unit = max(1, UNIT_RAYS // N)
    units = [(a, min(a + per_unit, Q)) for a in range(0, Q, per_unit)]
    total = Q * N
    done = [0]
    lock = threading.Lock()

    def work(i: int) -> np.ndarray:
        a, b = units[i]
        uniq, counts, rays = sampler.unit(i, a, b)
        with lock:
            done[0] += rays
            if progress is not None:
                progress(done[0], total)
        return uniq, counts

    parts = thread_map(work, range(len(units)), tracer.threads)
    return _assemble(parts, Q, N, layout)


def _check_form_factor_options(samples_per_patch, offset, layout: str) -> int:
    """hemisphere_form_factors' scalar options checked (ConfigError); returns samples_per_patch as int."""
    if (
        isinstance(samples_per_patch, bool)
        or not isinstance(samples_per_patch, (int, np.integer))
        or samples_per_patch < 1
    ):
        raise ConfigError(f"samples_per_patch must be an integer >= 1, got {samples_per_patch!r}")
    if not (isinstance(offset, (int, float, np.floating)) and math.isfinite(offset) and offset >= 0):
        raise ConfigError(f"offset must be a finite number >= 0 (ray start distance along the normal), got {offset!r}")
    if layout not in ("auto", "dense", "sparse"):
        raise ConfigError(f"layout must be 'auto', 'dense' or 'sparse', got {layout!r}")
    return int(samples_per_patch)


def _check_candidate_origins(origins, normals, weights):
    """hemisphere_form_factors' origins (Q, K, 3), normals (Q, K, 3) and weights (Q, K) checked (GeometryError).

    Returns (origins, normals, float64 weights, weight row sums (Q,), (Q, K) bool mask of positive weights)."""
    o = _as_array("origins", origins, "(Q, K, 3)")
    nm = _as_array("normals", normals, "(Q, K, 3)")
    w = _as_array("weights", weights, "(Q, K)")
    if o.ndim != 3 or o.shape[2] != 3 or o.shape[0] == 0 or o.shape[1] == 0:
        raise GeometryError(f"origins has shape {o.shape}, expected (Q, K, 3) with Q, K >= 1")
    Q, K = o.shape[:2]
    if nm.shape != o.shape:
        raise GeometryError(f"normals has shape {nm.shape}, expected {o.shape} like origins")
    if w.shape != (Q, K):
        raise GeometryError(f"weights has shape {w.shape}, expected {(Q, K)}")
    w = w.astype(np.float64)
    if not np.isfinite(w).all() or (w < 0).any():
        raise GeometryError("weights must be finite and >= 0 (0 marks padding)")
    row = w.sum(1)
    if (row <= 0).any():
        raise GeometryError(
            f"weights of patch {int(np.flatnonzero(row <= 0)[0])} sum to 0: every patch needs "
            "at least one origin with positive weight"
        )
    used = w > 0
    if not (np.isfinite(o[used]).all() and np.isfinite(nm[used]).all()):
        raise GeometryError("origins/normals contain NaN or inf values at entries with positive weight")
    nlen = np.linalg.norm(nm, axis=2)
    bad = used & (np.abs(nlen - 1) > 1e-3)
    if bad.any():
        q, k = np.argwhere(bad)[0]
        raise GeometryError(f"normals must be unit where weights > 0; normals[{q}, {k}] has length {nlen[q, k]:.4g}")
    return o, nm, w, row, used


def _check_face_patch(face_patch, tracer: RayTracer, Q: int) -> np.ndarray:
    """(F,) int64 patch of each mesh face, checked against the tracer's faces and Q patches (GeometryError)."""
    fp = _as_array("face_patch", face_patch, "(F,)")
    if fp.shape != (tracer.num_triangles,):
        raise GeometryError(
            f"face_patch has shape {fp.shape}, expected ({tracer.num_triangles},): one patch per mesh face"
        )
    if not np.issubdtype(fp.dtype, np.integer):
        raise GeometryError(f"face_patch must be integer patch indices, got dtype {fp.dtype}")
    fp = fp.astype(np.int64)
    if len(fp) and (fp.min() < -1 or fp.max() >= Q):
        raise GeometryError(f"face_patch values must lie in -1..{Q - 1} (Q = {Q} patches from origins)")
    return fp


def _check_hit_patches(point: HitPatches, tracer: RayTracer, Q: int) -> HitPatches:
    """hemisphere_form_factors' HitPatches checked against the tracer's faces and Q patches (GeometryError)."""
    tp = np.asarray(point.texel_patch, dtype=np.int64)
    if point.hits.num_faces != tracer.num_triangles or tp.shape != (point.hits.num_texels,):
        raise GeometryError(
            f"face_patch: the hit map covers {point.hits.num_faces} faces and {point.hits.num_texels} texels, "
            f"texel_patch has shape {tp.shape}; expected the tracer's {tracer.num_triangles} faces and one patch per "
            "texel"
        )
    if len(tp) and (tp.min() < -1 or tp.max() >= Q):
        raise GeometryError(f"face_patch: texel_patch values must lie in -1..{Q - 1} (Q = {Q} patches from origins)")
    return HitPatches(point.hits, tp)


@dataclass
class _CornerRule:
    """hemisphere_form_factors' corner rule: the patch (F, 3) int64 and normal (F, 3, 3) float32 of each face's
    corners, and mixed (F + 1,) bool, the faces the rule applies to (False at index F, read by misses)."""

    patch: np.ndarray
    normal: np.ndarray
    mixed: np.ndarray

    @classmethod
    def of(cls, corners, num_faces: int) -> Optional["_CornerRule"]:
        """The rule for corners (patches, normals) of num_faces faces, or None when no face is mixed."""
        c_patch, c_normal = (np.asarray(x) for x in corners)
        if c_patch.shape != (num_faces, 3) or c_normal.shape != (num_faces, 3, 3):
            raise GeometryError(
                f"corners have shapes {c_patch.shape} and {c_normal.shape}, expected ({num_faces}, 3) "
                f"and ({num_faces}, 3, 3): the patch and normal of each face's three corners"
            )
        c_patch = c_patch.astype(np.int64)
        c_normal = c_normal.astype(np.float32)
        # the rule matters on mixed faces whose corners lie in different patches, and only those pay for it
        mixed = mixed_faces(c_normal) & ((c_patch[:, 0] != c_patch[:, 1]) | (c_patch[:, 0] != c_patch[:, 2]))
        mixed = np.append(mixed, False)  # index -1 (a miss) reads False: one pass over the rays
        if not mixed.any():
            return None
        return cls(c_patch, c_normal, mixed)

    def apply(self, dst: np.ndarray, tri: np.ndarray, d: np.ndarray) -> None:
        """Moves dst (N,), the patch of each ray's hit triangle tri (N,) along d (N, 3), to the corner that
        faces the ray, in place."""
        hit = np.flatnonzero(np.take(self.mixed, tri))
        if hit.size:
            th, cn = tri[hit], self.normal[tri[hit]]
            k = facing_corner(
                np.zeros(hit.size, dtype=np.int64),
                cn,
                d[hit],
                -np.einsum("ni,nci->nc", d[hit], cn),
                usable=self.patch[th] >= 0,
            )
            dst[hit] = np.where(k > 0, self.patch[th, k], dst[hit])


def _ray_starts(o: np.ndarray, nm: np.ndarray, used: np.ndarray, offset: float):
    """Frames and start points once per candidate origin (Q * K), then gathered per ray (float32, like Embree).

    Returns (slot (Q * K,) int64: the candidate of each origin, -1 for padding; frames (C, 3, 3) float32, rows
    t, b, n; start points (C, 3) float32, moved `offset` along the normal)."""
    Q, K = used.shape
    cand = np.flatnonzero(used.ravel())
    slot = np.full(Q * K, -1, dtype=np.int64)
    slot[cand] = np.arange(len(cand))
    cn = nm.reshape(-1, 3)[cand].astype(np.float64)
    cn /= np.linalg.norm(cn, axis=1, keepdims=True)
    ct, cb = tangent_frame(cn)
    frames = np.stack([ct, cb, cn], 1).astype(np.float32)  # (C, 3, 3): rows t, b, n
    cstart = (o.reshape(-1, 3)[cand].astype(np.float64) + offset * cn).astype(np.float32)
    return slot, frames, cstart


@dataclass
class _PatchRays:
    """What one work unit of hemisphere_form_factors needs to sample, trace and tally its patches' rays."""

    tracer: RayTracer
    fp: Optional[np.ndarray]
    cdf: torch.Tensor
    slot: np.ndarray
    frames: np.ndarray
    cstart: np.ndarray
    front: Optional[np.ndarray]
    corner_rule: Optional[_CornerRule]
    N: int
    seed: int
    point: Optional[HitPatches] = None  # set: a hit goes to the patch of its point's texel (fp is None)

    def unit(self, i: int, a: int, b: int) -> tuple[np.ndarray, np.ndarray, int]:
        """Rays of patches a..b-1 (work unit i): (sorted keys src * Q + dst, their counts, rays traced)."""
        Q = len(self.cdf)
        rng = np.random.default_rng([self.seed, 0xF0, i])
        src, j, d = self._directions(rng, a, b)
        if self.point is None:
            tri = self.tracer.first_hit_triangles(self.cstart[j], np.ascontiguousarray(d))
            dst = np.where(tri >= 0, self.fp[np.maximum(tri, 0)], -1)
        else:
            tri, u, v, _ = self.tracer.first_hits(self.cstart[j], np.ascontiguousarray(d))
            tri = tri.astype(np.int64)
            dst = self.point.patches(tri, u, v)
        if self.corner_rule is not None:
            self.corner_rule.apply(dst, tri, d)
        if self.front is not None:
            hit = np.flatnonzero(dst >= 0)
            back = np.einsum("ni,ni->n", d[hit], self.front[tri[hit]]) >= 0
            dst[hit[back]] = -1
        ok = dst >= 0
        # tally per unit, on the unit's thread: units own disjoint source patches, so their (key, count)
        # pairs never overlap and concatenate in key order
        uniq, counts = np.unique(src[ok] * Q + dst[ok], return_counts=True)
        return uniq, counts, len(j)

    def _directions(self, rng: np.random.Generator, a: int, b: int):
        """(source patch (n,), candidate origin (n,), direction (n, 3) float32) of the n = (b - a) N rays."""
        N = self.N
        K = self.cdf.shape[1]
        # randomised QMC: one scrambled Sobol set per unit, moved by a uniform shift per patch; its first
        # coordinate picks the origin, the other two the direction, so both are stratified
        uq = toroidal_shift(sobol_base(N, 3, rng), rng.random((b - a, 3)))
        # origin choice by inverse CDF of the weights; a zero-weight slot has the same cdf as the slot
        # before it, so right=True never picks padding
        u = torch.from_numpy(np.ascontiguousarray(uq[:, 0].reshape(b - a, N)))
        k = np.minimum(torch.searchsorted(self.cdf[a:b], u, right=True).numpy(), K - 1)
        src = np.repeat(np.arange(a, b), N)
        j = self.slot[src * K + k.ravel()]
        u1 = uq[:, 1].astype(np.float32)
        phi = uq[:, 2].astype(np.float32) * np.float32(2.0 * np.pi)
        r = np.sqrt(u1)
        local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(np.float32(1.0) - u1, 0))], 1)
        d = np.einsum("ni,nij->nj", local, self.frames[j])
        return src, j, d


def _assemble(parts, Q: int, N: int, layout: str) -> torch.Tensor:
    """The (Q, Q) form factors from the work units' (keys, counts): dense or sparse by `layout`."""
    uniq = np.concatenate([p[0] for p in parts])
    counts = np.concatenate([p[1] for p in parts])
    values = torch.from_numpy(counts.astype(np.float64) / N)
    idx = torch.from_numpy(np.stack([uniq // Q, uniq % Q]))
    dense = layout == "dense" or (layout == "auto" and Q * Q <= DENSE_MAX_ENTRIES)
    if dense:
        F = torch.zeros(Q, Q, dtype=torch.float64)
        F[idx[0], idx[1]] = values
        return F
    # the keys are unique and sorted (row-major), which is the coalesced layout already
    return torch.sparse_coo_tensor(idx, values, (Q, Q), dtype=torch.float64, check_invariants=False, is_coalesced=True)


def _front_faces(tracer: RayTracer, fp: np.ndarray, w: np.ndarray, nm: np.ndarray, Q: int) -> np.ndarray:
    """(F, 3) geometric face normals oriented to the front of their patch (the side its weighted
    mean normal points to); zero for faces of no patch."""
    v = tracer.vertices.astype(np.float64)
    f = tracer.faces
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    mean = np.einsum("qk,qki->qi", w, np.nan_to_num(nm.astype(np.float64)))
    sign = np.where(fp >= 0, np.sign(np.einsum("fi,fi->f", fn, mean[np.maximum(fp, 0)])), 0.0)
    sign[(fp >= 0) & (sign == 0)] = 1.0
    return fn * sign[:, None]


def form_factors_for_surface(
    surface: Surface,
    tracer: Optional[RayTracer] = None,
    patch_size: int = 1,
    samples_per_patch: int = 256,
    seed: int = 0,
    offset: Optional[float] = None,
    split_angle_deg: float = 180.0,
    **kwargs,
) -> tuple[Patches, torch.Tensor]:
    """Patches of the surface (texel_patches with split_angle_deg) and their form factors
    (hemisphere_form_factors).

    Candidate origins of a patch are its texel positions with their normals, weighted by texel
    area. A ray's hit goes to a patch by the surface's hits (core/texel_hits.py; None, the range mesh: the patch
    of the face's first vertex, patches.face_patches, with the corner rule of face_corners). tracer: a RayTracer
    over the surface mesh (built from surface.mesh_* when None).
    offset: ray start distance along the normal; None = 1e-3 x the median texel side
    (sqrt of the median texel area). kwargs go to hemisphere_form_factors (layout, progress,
    count_back_hits).
    """
    if not surface.has_mesh:
        raise GeometryError(
            f"surface from {surface.source}: mesh_vertices/mesh_faces are None; form factors need the triangle mesh"
        )
    patches = texel_patches(surface, patch_size, split_angle_deg)
    if surface.hits is None:  # the range mesh: a face is the patch of the texel at its first vertex
        fpatch, corners = face_patches(surface, patches), face_corners(surface, patches)
    else:  # a face holds several texels: each hit point goes to its texel's patch
        fpatch, corners = HitPatches(surface.hits, patches.texel_patch.cpu().numpy()), None
    if tracer is None:
        tracer = RayTracer(surface.mesh_vertices, surface.mesh_faces)
    if offset is None:
        offset = 1e-3 * math.sqrt(float(surface.areas.detach().double().median()))
    pos, nrm, area, mask = patches.padded(
        surface.positions.detach().cpu().double(),
        surface.normals.detach().cpu().double(),
        surface.areas.detach().cpu().double(),
    )
    F = hemisphere_form_factors(
        tracer,
        fpatch,
        pos,
        nrm,
        area * mask,
        samples_per_patch=samples_per_patch,
        seed=seed,
        offset=float(offset),
        corners=corners,
        **kwargs,
    )
    return patches, F


def sampling_error(F: torch.Tensor, samples_per_patch: int) -> torch.Tensor:
    """Binomial standard error sqrt(F (1 - F) / N) of each entry (same layout as F; 0 where F is 0): the error
    of independent rays, which hemisphere_form_factors' stratified rays stay below (module docstring)."""
    if (
        isinstance(samples_per_patch, bool)
        or not isinstance(samples_per_patch, (int, np.integer))
        or samples_per_patch < 1
    ):
        raise ConfigError(f"samples_per_patch must be an integer >= 1, got {samples_per_patch!r}")
    if F.is_sparse:
        F = F.coalesce()
        v = F.values()
        return torch.sparse_coo_tensor(
            F.indices(), torch.sqrt(v * (1 - v) / samples_per_patch), F.shape, check_invariants=False
        ).coalesce()
    return torch.sqrt(F * (1 - F) / samples_per_patch)
