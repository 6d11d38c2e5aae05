"""Relighting a fitted object: its image from any camera under any point or directional light, with cast shadows.

Per pixel (supersample^2 stratified rays; report.relight_camera): Embree's closest hit on the run's mesh
(report.hit_texels: the scan grid's triangulation, or the mesh_views mesh) -> the texels the hit reads (bilinear
over estimated texels, on an atlas only those of the hit's chart, or the nearest texel) -> the estimate there,
with the normal blended from the hit face's corner normals (the loader's texel normals at its points) -> a shadow
ray from the hit to the light (core.point_light.light_geometry, as the capture loader traces it: origin offset
geometry.shadow_offset_mm along that normal) -> the fitter's own observation model,
transport.local.render_reference (i = kappa Y falloff g(n, l, v), core.brdf), with the run's BRDF, diffuse part
and kappa. The pixel is the mean over its samples (a miss, a back-facing sample or one without an estimate
counts 0). Values are sensor fractions of full range at exposure 1, like the capture's.

Interreflection (`interreflection`, default: the run's level): a radiosity or photon run adds the indirect light
its level computes for the new light from the fitted parameters (report.relight_indirect: each texel's indirect
sensor value, sampled at the hit with the weights of its parameters and added to the direct light, cast shadows
included); a local run, or interreflection=False, gives direct light and cast shadows only.

Photometric stereo has no depth: it is relit on its own grid through the camera of its photographs
(`photographs_camera`, orthographic), without cast shadows; another camera is refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.lights_json import Lights
from torchrefl.capture.mesh_views import check_lights_outside, read_units
from torchrefl.core.observations import Observations
from torchrefl.core.point_light import light_geometry
from torchrefl.core.progress import bar
from torchrefl.core.rays import RayTracer
from torchrefl.errors import CaptureError, RunFolderError
from torchrefl.geometry.mesh_file import read_mesh
from torchrefl.report.hit_texels import (
    TexelImage,
    TexelMesh,
    atlas_texel_mesh,
    geometry_mask,
    grid_texel_mesh,
    sample_table,
    sample_texels,
    texel_image,
    value_table,
)
from torchrefl.report.relight_camera import OrthographicCamera, camera_rays, image_size
from torchrefl.report.relight_indirect import (
    INTERREFLECTION_LEVELS,
    IndirectModel,
    indirect_grid,
    indirect_model,
    run_level,
)
from torchrefl.transport.local import render_reference

#: rays per block (one progress-bar step)
BLOCK_RAYS = 1 << 16
#: default shadow-ray origin offset (geometry.shadow_offset_mm's default) when the run's config has none
SHADOW_OFFSET = 0.05
#: the shading's dtype (the fit's default; float64 changes a frame by < 1e-4 DN and takes twice as long)
SHADE_DTYPE = torch.float32
#: a default light makes a white Lambertian texel facing it at the object's centre read this fraction of full range
DEFAULT_LEVEL = 0.8


@dataclass(frozen=True)
class Light:
    """One light: a point light at `position` (3,) (world frame, the run's units) or a directional light towards
    `direction` (3,) (unit); intensity (3,) RGB radiant intensity Y > 0 (point: full range x units^2,
    directional: full range; the capture's light units, docs/capture-formats.md)."""

    intensity: np.ndarray
    position: np.ndarray | None = None
    direction: np.ndarray | None = None

    def __post_init__(self) -> None:
        if (self.position is None) == (self.direction is None):
            raise CaptureError("render light: give exactly one of position=(x, y, z) and direction=(x, y, z)")
        for name in ("position", "direction"):
            value = getattr(self, name)
            if value is not None:
                a = np.asarray(value, dtype=np.float64)
                if a.shape != (3,) or not np.isfinite(a).all():
                    raise CaptureError(f"render light: {name}={value!r}, expected 3 finite numbers")
                if name == "direction":
                    if not np.linalg.norm(a) > 0:
                        raise CaptureError(f"render light: direction={value!r} is the zero vector")
                    a = a / np.linalg.norm(a)
                object.__setattr__(self, name, a)
        y = np.asarray(self.intensity, dtype=np.float64)
        y = np.full(3, float(y.ravel()[0])) if y.size == 1 else y  # one number (also --intensity Y): grey
        if y.shape != (3,) or not (np.isfinite(y) & (y > 0)).all():
            raise CaptureError(f"render light: intensity={self.intensity!r}, expected one or three finite values > 0")
        object.__setattr__(self, "intensity", y)


@dataclass
class RelitImage:
    """image (H, W, 3) float64: predicted sensor values (fractions of full range, exposure 1); covered (H, W) bool:
    some ray of the pixel meets the object; estimated (H, W) bool: every ray of the pixel that meets the object
    lands on estimated texels (the image is complete there); filled (H, W) bool: every ray of the pixel meets the
    object (no silhouette pixel)."""

    image: np.ndarray
    covered: np.ndarray
    estimated: np.ndarray
    filled: np.ndarray


@dataclass
class RelightScene:
    """What a run is relit on: its texel mesh and Embree scene (None for photometric stereo: no depth), the
    estimate's centre and radius (the bounding sphere of its texels, for presets and default lights), the
    estimate as a TexelImage (in SHADE_DTYPE) for sampling, and what the interreflection of a radiosity or photon
    run is computed from (report.relight_indirect.IndirectModel, built on the first frame that needs it)."""

    mesh: TexelMesh | None
    tracer: RayTracer | None
    centre: np.ndarray
    radius: float
    texels: TexelImage | None = None
    indirect: IndirectModel | None = None


def run_mesh(run) -> TexelMesh | None:
    """The TexelMesh of a RunResult: the atlas mesh params.npz's `mesh` names (mesh_views), the scan grid's
    triangulation (a cylindrical scan), None for photometric stereo (units px). RunFolderError naming params.npz's
    `mesh` for a mesh file that is missing, unreadable or has no UVs."""
    if run.units == "px":
        return None
    if run.mesh is None:
        return grid_texel_mesh(run.positions, run.normals)
    path = Path(run.mesh)
    path = path if path.is_absolute() else run.folder / path
    where = f"{run.folder / 'params.npz'}: key 'mesh' names {path}"
    if not path.is_file():
        raise RunFolderError(f"{where}, which is missing (expected the mesh whose atlas the maps are)")
    # torchrefl writes its own mesh.obj in mm; a capture's mesh is in its scene.yaml's units
    units = "mm" if path.parent == run.folder else read_units(path.parent)
    try:
        mesh = read_mesh(path, units)
    except Exception as exc:  # GeometryError and trimesh's own: name the key
        raise RunFolderError(f"{where}, which cannot be read ({exc})") from None
    if mesh.uvs is None:
        raise RunFolderError(f"{where}, which has no UVs (expected the mesh with the atlas the maps lie on)")
    return atlas_texel_mesh(mesh, run.grid_shape)


def relight_scene(run, threads: int = 2) -> RelightScene:
    """The RelightScene of a RunResult (run_mesh and its Embree scene)."""
    mesh = run_mesh(run)
    x = run.positions[geometry_mask(run.normals)].astype(np.float64)
    lo, hi = x.min(0), x.max(0)
    centre = (lo + hi) / 2.0
    radius = float(np.linalg.norm(x - centre, axis=1).max())
    if mesh is None:
        return RelightScene(None, None, centre, radius)
    tracer = RayTracer(mesh.vertices, mesh.faces, threads=threads)
    texels = texel_image(run.pd, run.ps, run.sigma, run.mask, dtype=SHADE_DTYPE)
    return RelightScene(mesh, tracer, centre, radius, texels)


def photographs_camera(run) -> OrthographicCamera:
    """The orthographic camera of a photometric-stereo run's photographs: pixel (u, v) = texel (col, row) of its
    grid (positions x = col - W/2, y = H/2 - row, z = 0), looking along -z."""
    H, W = run.grid_shape
    R = np.diag([1.0, -1.0, -1.0])
    return OrthographicCamera(R, np.array([0.0, 0.0, float(max(H, W))]), W, H, 1.0, W / 2.0, H / 2.0)


def default_intensity(run, scene: RelightScene, position=None) -> np.ndarray:
    """(3,) an intensity under which a white Lambertian texel facing the light at the object's centre reads
    DEFAULT_LEVEL of full range: DEFAULT_LEVEL pi d^2 / kappa for a point light at distance d, without d^2 for a
    directional light (position None)."""
    d2 = 1.0 if position is None else float(np.sum((np.asarray(position, np.float64) - scene.centre) ** 2))
    return DEFAULT_LEVEL * np.pi * d2 / np.asarray(run.kappa, dtype=np.float64)


def shade(run, n, l, falloff, v, intensity, pd, ps, sigma) -> torch.Tensor:
    """(T, 3) i = kappa Y falloff g(n, l, v) of T points under one light, through the fitter's observation model
    (transport.local.render_reference) with the run's BRDF, kappa and diffuse exponent; float64 tensors
    n, l, v (T, 3), falloff (T,), intensity (3,), pd (T, 3), ps (T, C), sigma (T,)."""
    T, dt = len(n), n.dtype
    obs = Observations(
        intensity=torch.zeros(1, T, 3, dtype=dt),
        valid=torch.ones(1, T, dtype=torch.bool),
        saturated=torch.zeros(1, T, dtype=torch.bool),
        shadowed=torch.zeros(1, T, dtype=torch.bool),
        light_dir=l[None],
        falloff=falloff[None],
        light_intensity=torch.as_tensor(intensity, dtype=dt)[None],
        view_dir=v,
        kappa=torch.as_tensor(np.asarray(run.kappa, dtype=np.float64), dtype=dt),
        source=str(run.folder),
    )
    with torch.no_grad():
        return render_reference(run.brdf, n, obs, pd, ps, sigma, run.minnaert_k)[0]


def check_light_outside(scene: RelightScene, light: Light) -> None:
    """CaptureError when a point light sits inside the object (capture.mesh_views.check_lights_outside: every ray
    from it meets the mesh from inside)."""
    if scene.tracer is None or light.position is None:
        return
    lights = Lights(
        names=("render light",),
        point=np.array([True]),
        position=light.position[None],
        direction=np.full((1, 3), np.nan),
        intensity=light.intensity[None],
        source="render light",
    )
    check_lights_outside(lights, scene.tracer, [0])


def relight(
    run,
    camera,
    light: Light,
    *,
    index: int = 0,
    supersample: int = 1,
    shadows: bool = True,
    interpolation: str = "bilinear",
    scene: RelightScene | None = None,
    progress: bool = False,
    interreflection: bool | None = None,
) -> RelitImage:
    """The RelitImage of a RunResult seen by camera (Cameras: camera `index`; OrthographicCamera) under light
    (module doc). scene: the run's RelightScene (built when None; pass it to render many frames);
    interreflection: add the indirect light of the run's radiosity or photon level (None: when the run's level has
    it; True for a local run is a CaptureError)."""
    if int(supersample) < 1:
        raise CaptureError(f"render supersample={supersample!r}, expected an integer >= 1")
    scene = relight_scene(run) if scene is None else scene
    with_indirect = _uses_interreflection(run, scene, interreflection)
    if scene.mesh is None:
        return _relight_grid(run, camera, light)
    check_light_outside(scene, light)
    H, W = image_size(camera, index)
    offset = _shadow_offset(run)
    indirect = None
    if with_indirect:
        if scene.indirect is None:
            scene.indirect = indirect_model(run, scene.mesh)
        values = indirect_grid(scene.indirect, light, camera, index, scene.tracer, offset)
        indirect = value_table(values.reshape(run.grid_shape + (3,)), run.mask, dtype=SHADE_DTYPE)
    origins, dirs, pixel = camera_rays(camera, index, supersample)
    total = np.zeros((H * W, 3))
    hit_count = np.zeros(H * W)
    done_count = np.zeros(H * W)
    with bar(len(origins), "render", enabled=progress, unit="ray") as pbar:
        for start in range(0, len(origins), BLOCK_RAYS):
            sl = slice(start, min(start + BLOCK_RAYS, len(origins)))
            values, hit, done = _trace_block(
                run, scene, light, origins[sl], dirs[sl], offset, shadows, interpolation, indirect
            )
            px = pixel[sl]
            for c in range(3):
                total[:, c] += np.bincount(px, weights=values[:, c], minlength=H * W)
            hit_count += np.bincount(px, weights=hit, minlength=H * W)
            done_count += np.bincount(px, weights=done, minlength=H * W)
            pbar.update(sl.stop - sl.start)
    k2 = int(supersample) ** 2
    covered = hit_count > 0
    return RelitImage(
        (total / k2).reshape(H, W, 3),
        covered.reshape(H, W),
        (covered & (done_count == hit_count)).reshape(H, W),
        (hit_count == k2).reshape(H, W),
    )


def _uses_interreflection(run, scene: RelightScene, interreflection: bool | None) -> bool:
    """Whether a frame adds the run's interreflection (relight's `interreflection`)."""
    level = run_level(run)
    if interreflection is None:
        return level in INTERREFLECTION_LEVELS and scene.mesh is not None
    if interreflection and level not in INTERREFLECTION_LEVELS:
        raise CaptureError(
            f"render interreflection=True: the run {run.folder} was fitted at the {level} level (metrics.json "
            f"'model'), which models no interreflection (expected one of {', '.join(INTERREFLECTION_LEVELS)})"
        )
    return bool(interreflection)


def _shadow_offset(run) -> float:
    section = run.config.get("geometry") if isinstance(run.config, dict) else None
    value = section.get("shadow_offset_mm") if isinstance(section, dict) else None
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else SHADOW_OFFSET


def _trace_block(run, scene: RelightScene, light: Light, o, d, offset, shadows, interpolation, indirect=None):
    """(values (N, 3), hit (N,) float, estimated (N,) float) of one block of rays; indirect: a value_table of the
    texels' indirect sensor values (H * W, 4) added at every front-facing hit, or None."""
    values = np.zeros((len(o), 3))
    hits = scene.tracer.closest_hit(o, d)
    idx = np.flatnonzero(hits.hit)
    hit = hits.hit.astype(np.float64)
    done = np.zeros(len(o))
    if not idx.size:
        return values, hit, done
    x = o[idx] + hits.distance[idx, None] * d[idx]
    tri, bary = hits.triangle[idx], hits.barycentric[idx]
    weights = scene.mesh.texel_weights(tri, bary, interpolation)
    s = sample_texels(scene.texels, weights)
    done[idx] = s.estimated.numpy()
    n = scene.mesh.normals(tri, bary)
    front = s.estimated.numpy() & (np.einsum("ni,ni->n", n, d[idx]) < 0)
    lit = light_geometry(
        x,
        n,
        scene.tracer if shadows else None,
        position=light.position,
        direction=light.direction,
        offset=offset,
        trace=front,
    )
    keep = front & lit.visible
    if keep.any():
        k = torch.from_numpy(keep)
        t = lambda a: torch.from_numpy(np.ascontiguousarray(a[keep])).to(scene.texels.table.dtype)
        out = shade(
            run, t(n), t(lit.direction), t(lit.falloff), t(-d[idx]), light.intensity, s.pd[k], s.ps[k], s.sigma[k]
        )
        values[idx[keep]] = out.numpy()
    if indirect is not None:
        values[idx[front]] += sample_table(indirect, weights)[0].numpy()[front]
    return values, hit, done


def _relight_grid(run, camera, light: Light) -> RelitImage:
    """Photometric stereo: the grid seen by its photographs' camera (no depth, no cast shadows)."""
    own = photographs_camera(run)
    fields = ("R", "t", "width", "height", "pixel_size", "cx", "cy")
    same = isinstance(camera, OrthographicCamera) and all(
        np.allclose(getattr(camera, f), getattr(own, f)) for f in fields
    )
    if not same:
        raise CaptureError(
            f"render camera: the run {run.folder} is photometric stereo (no depth): it can be relit only through the "
            "orthographic camera of its photographs (torchrefl.report.relight.photographs_camera, --camera photographs)"
        )
    m = run.mask
    x, n = (np.asarray(a, dtype=np.float64)[m] for a in (run.positions, run.normals))
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    lit = light_geometry(x, n, None, position=light.position, direction=light.direction, offset=0.0)
    keep = lit.lit & (n[:, 2] > 0)  # facing the light and the camera (v = +z)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(np.asarray(a, dtype=np.float64)[keep]))
    v = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(int(keep.sum()), 3)
    maps = (t(a[m]) for a in (run.pd, run.ps, run.sigma))
    values = np.zeros((len(x), 3))
    values[keep] = shade(run, t(n), t(lit.direction), t(lit.falloff), v, light.intensity, *maps).numpy()
    image = np.zeros(run.grid_shape + (3,))
    image[m] = values
    return RelitImage(image, m.copy(), m.copy(), m.copy())
