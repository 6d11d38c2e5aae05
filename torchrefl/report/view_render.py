"""A mesh_views run's estimate rendered into one photograph of its capture: the photograph, the re-render and their
difference in the camera's own pixels (a held-out image as a picture; the notebook tour's mesh_views section).

    from torchrefl.report.run_result import load_run
    from torchrefl.report.view_render import render_view
    view = render_view(load_run("outputs/mesh_views"), image=5)   # images.json's image 5
    view.photograph, view.rendered, view.shown, view.difference()

The re-render: rays through supersample x supersample points of every pixel (the camera's distortion undone by
kornia's undistort_points), Embree's first hit on the run's mesh (params.npz `mesh`), the estimate of the texel
under the hit's uv, the normal interpolated from the mesh's corner normals (as the loader's texel normals), the
image's light with a cast-shadow ray, and the fitted BRDF through RunResult.shade: exposure x kappa x L_o, local
transport (no interreflection). A pixel is shown when every sub-sample hits an estimated texel facing the camera
(silhouettes and texels without an estimate are left out).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.cameras import Cameras
from torchrefl.capture.images_json import IMAGES_JSON
from torchrefl.capture.mesh_views import read_units
from torchrefl.capture.view_folder import ViewFolder, read_view_folder
from torchrefl.config import GeometryConfig
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.errors import RunFolderError
from torchrefl.geometry.atlas import uv_to_texel_xy
from torchrefl.geometry.mesh_file import UNIT_SCALE_MM, MeshData, read_mesh
from torchrefl.geometry.mesh_normals import corner_normals
from torchrefl.report.metrics import image_difference
from torchrefl.report.run_result import RunResult

#: fixed-point steps of kornia's undistort_points (its default 5 leaves ~1e-2 px at k1 = -0.2 in the corners)
UNDISTORT_ITERATIONS = 20


@dataclass
class ViewRender:
    """Image `image` of the capture (images.json's index; `file`, its path): photograph (H, W, 3) as stored
    (fractions of full range, exposure included), rendered (H, W, 3) the estimate's re-render (0 where not
    shown), shown (H, W) bool the pixels compared."""

    image: int
    file: Path
    photograph: np.ndarray
    rendered: np.ndarray
    shown: np.ndarray

    def difference(self) -> dict:
        """rendered - photograph over the shown pixels on the 8-bit scale (metrics.image_difference's keys)."""
        t = lambda a: torch.from_numpy(np.asarray(a, dtype=np.float64))[None]
        return image_difference(t(self.rendered), t(self.photograph), torch.from_numpy(self.shown)[None])


def run_mesh(run: RunResult, capture: Path) -> MeshData:
    """The mesh whose atlas the run's maps lie on, in mm: params.npz's `mesh` (in the capture folder: in its
    scene.yaml's unit; one torchrefl wrote into the run folder: mm)."""
    if run.mesh is None:
        raise RunFolderError(f"{run.folder}/params.npz: no 'mesh' key (expected a mesh_views run)")
    path = Path(run.mesh) if Path(run.mesh).is_absolute() else run.folder / run.mesh
    in_capture = path.resolve().parent == capture.resolve()
    return read_mesh(path, read_units(capture) if in_capture else "mm")


def capture_folder(run: RunResult, capture=None) -> Path:
    """`capture` when given, else the folder of the run's mesh when it holds images.json (a mesh with its own UVs),
    else the run's own capture/ (a synthetic run's); RunFolderError asking for it otherwise."""
    if capture is not None:
        return Path(capture)
    beside = [(run.folder / run.mesh).parent] if run.mesh is not None else []
    for folder in [*beside, run.folder / "capture"]:
        if (folder / IMAGES_JSON).is_file():
            return folder
    raise RunFolderError(
        f"{run.folder}: the capture folder is not beside the run's mesh ({run.mesh}); give it: capture=PATH"
    )


def pixel_rays(c: Cameras, cam: int, supersample: int) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), unit directions (H, W, s*s, 3)) of camera `cam`'s rays through s x s points of every pixel
    (pixel centres at integer (u, v), the sub-points at their centres)."""
    from kornia.geometry.calibration import undistort_points

    H, W, s = int(c.height[cam]), int(c.width[cam]), int(supersample)
    sub = (np.arange(s) + 0.5) / s - 0.5
    v, u, dv, du = np.meshgrid(np.arange(H), np.arange(W), sub, sub, indexing="ij")
    uv = torch.from_numpy(np.stack([u + du, v + dv], -1).reshape(1, -1, 2)).double()
    K, dist = c.K[cam].double()[None], c.distortion[cam].double()[None]
    if dist.any():
        eye = torch.eye(3, dtype=torch.float64)[None]
        xy = undistort_points(uv, K, dist, new_K=eye, num_iters=UNDISTORT_ITERATIONS)
    else:  # no distortion: skip kornia's iteration (seconds on a megapixel)
        xy = (uv - K[:, :2, 2]) / K[:, [0, 1], [0, 1]]
    xy = xy.reshape(-1, 2, 1)  # normalised (x', y'), z = 1
    dirs_cam = torch.cat([xy, torch.ones_like(xy[:, :1])], 1)[..., 0]
    dirs = (dirs_cam @ c.R[cam].double()).numpy()  # R^T d, row-wise
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return c.centres()[cam].double().numpy(), dirs.reshape(H, W, s * s, 3)


def _light(meta: ViewFolder, k: int, p: np.ndarray, n: np.ndarray, tracer: RayTracer, offset: float, reach: float):
    """(direction (N, 3), falloff (N,), lit and unshadowed (N,)) of light k at points p with normals n."""
    lights = meta.lights
    target = lights.position[k] if lights.point[k] else p + reach * lights.direction[k]
    pl = point_light(p, n, np.broadcast_to(target, p.shape), tracer, offset=offset)
    falloff = pl.falloff if lights.point[k] else np.ones(len(p))
    return pl.direction, falloff, pl.visible


def render_view(run: RunResult, image: int, capture=None, supersample: int = 2, threads: int = 2) -> ViewRender:
    """Photograph `image` (images.json's index) of the run's capture and the estimate re-rendered in its camera
    (module doc). capture: the capture folder (default: capture_folder)."""
    folder = capture_folder(run, capture)
    meta = read_view_folder(folder)
    if not 0 <= image < len(meta.paths):
        raise RunFolderError(f"{meta.views.source}: no image {image} (it lists {len(meta.paths)})")
    scale = UNIT_SCALE_MM[read_units(folder)]
    meta = replace(meta, cameras=meta.cameras.scaled(scale), lights=meta.lights.scaled(scale))
    mesh = run_mesh(run, folder)
    if mesh.uvs is None:
        raise RunFolderError(f"{mesh.source}: the run's mesh has no UVs (expected the mesh the maps lie on)")
    tracer = RayTracer(mesh.vertices, mesh.faces, threads=threads)
    cam = int(meta.camera_index[image])
    centre, dirs = pixel_rays(meta.cameras, cam, supersample)
    H, W, S2 = dirs.shape[:3]
    hits = tracer.closest_hit(np.broadcast_to(centre, (H * W * S2, 3)), dirs.reshape(-1, 3))
    idx = np.flatnonzero(hits.hit)
    tri, b = hits.triangle[idx], hits.barycentric[idx]
    w = np.column_stack([1.0 - b.sum(1), b])  # Embree's (u, v): hit = (1-u-v) v0 + u v1 + v v2
    p = centre + hits.distance[idx, None] * dirs.reshape(-1, 3)[idx]
    n = np.einsum("nk,nki->ni", w, corner_normals(mesh.vertices, mesh.faces)[tri])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rows, cols = run.grid_shape
    xy = np.floor(uv_to_texel_xy(np.einsum("nk,nki->ni", w, mesh.uvs[tri]), rows)).astype(np.int64)
    xy = np.clip(xy, 0, [cols - 1, rows - 1])
    texel = xy[:, 1] * cols + xy[:, 0]
    v = centre - p
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    good = np.zeros(H * W * S2, dtype=bool)
    good[idx] = run.mask.reshape(-1)[texel] & (np.einsum("ni,ni->n", n, v) > 0)
    shown = good.reshape(H, W, S2).all(-1)
    keep = shown.reshape(-1).repeat(S2)[idx]  # the sub-samples of shown pixels
    p, n, v, texel = p[keep], n[keep], v[keep], texel[keep]
    offset = float(run.config.get("geometry", {}).get("shadow_offset_mm", GeometryConfig.shadow_offset_mm))
    reach = 10.0 * float(np.ptp(mesh.vertices, axis=0).max()) + 1.0
    k = int(meta.light_index[image])
    l, falloff, lit = _light(meta, k, p, n, tracer, offset, reach)
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a, dtype=np.float64))
    values = run.shade(texel, t(n), t(l), t(v), t(falloff * lit), t(meta.lights.intensity[k])).numpy()
    sums = np.zeros((H * W * S2, 3))
    sums[idx[keep]] = values * meta.views.images[image].exposure
    rendered = sums.reshape(H, W, S2, 3).mean(2)
    return ViewRender(image, meta.paths[image], meta.read_image(image), rendered, shown)
