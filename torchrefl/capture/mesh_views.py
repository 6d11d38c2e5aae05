"""Loader of the `mesh_views` capture kind: a triangle mesh and photographs from calibrated cameras under lights.

Folder (the contract: docs/capture-formats.md, `mesh_views`):
    mesh.obj | mesh.ply | mesh.glb   the object, in scene.yaml's `units` (mm when it names none)
    scene.yaml                       optional: units
    cameras.json, lights.json, images.json, images/*   (capture.views_folder reads them)
    truth.npz                        optional (synthetic scenes): pd, ps, sigma on the atlas

The texels are the mesh's atlas at capture.texture_size (geometry.atlas_surface; made by xatlas when the mesh has
no UVs, and then written into the run folder). Each image is one light configuration p of the Observations: its
camera's view of the texels (capture.views_sampling: projection with distortion, Embree visibility, footprint
sampling, silhouettes and depth steps left out), its light's direction, falloff and cast shadow
(core.point_light), the pixel value divided by the image's exposure. P = images, so view_dir is (P, T, 3).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import Capture, CaptureLoader, Log
from torchrefl.capture.checks import image_content_checks, implied_albedo_check, light_indices, observations_left
from torchrefl.capture.images import read_image, read_images
from torchrefl.capture.truth import TRUTH, load_truth
from torchrefl.capture.views_folder import ViewsFolder, read_views_folder
from torchrefl.capture.views_sampling import OUTSIDE, REASON_KEYS, CameraView, camera_view, footprint_values
from torchrefl.config import Config
from torchrefl.core.observations import Observations
from torchrefl.core.point_light import PointLight, point_light
from torchrefl.core.rays import RayTracer
from torchrefl.errors import CaptureError, GeometryError
from torchrefl.geometry.atlas import uv_to_texel_xy
from torchrefl.geometry.atlas_neighbours import face_jacobians
from torchrefl.geometry.atlas_surface import AtlasGeometry, atlas_geometry
from torchrefl.geometry.mesh_file import MESH_SUFFIXES, read_mesh

#: rays cast from a point light to tell whether it sits inside the object (every one meets a back face)
INSIDE_RAYS = 26


def mesh_path(folder: Path) -> Path:
    """The folder's one mesh file (mesh.obj, mesh.ply or mesh.glb); CaptureError when there is none or several."""
    found = [folder / f"mesh{s}" for s in MESH_SUFFIXES if (folder / f"mesh{s}").is_file()]
    if len(found) != 1:
        raise CaptureError(
            f"{folder}: expected one mesh file (mesh.obj, mesh.ply or mesh.glb), found "
            f"{', '.join(p.name for p in found) or 'none'}"
        )
    return found[0]


def texel_steps(geom: AtlasGeometry) -> np.ndarray:
    """(T, 3, 2) 3-D displacement of one texel column and one texel row at each texel (its face's Jacobian)."""
    S = geom.surface.grid_shape[0]
    jac = face_jacobians(geom.mesh.vertices, geom.mesh.faces, uv_to_texel_xy(geom.mesh.uvs, S))
    return jac[geom.texels.face]


def _directions(n: int) -> np.ndarray:
    """(n, 3) unit directions spread over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    y = 1 - 2 * k / n
    r = np.sqrt(1 - y * y)
    phi = k * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], -1)


def check_lights_outside(meta: ViewsFolder, tracer: RayTracer, used: set) -> None:
    """CaptureError naming a point light that sits inside the object: every ray from it meets a back face."""
    v = tracer.vertices.astype(np.float64)[tracer.faces.astype(np.int64)]
    face_n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    dirs = _directions(INSIDE_RAYS)
    for light in meta.lights:
        if light.kind != "point" or light.name not in used:
            continue
        hits = tracer.closest_hit(np.broadcast_to(light.vector, dirs.shape), dirs)
        if hits.hit.all() and (np.einsum("ni,ni->n", face_n[hits.triangle], dirs) > 0).all():
            raise CaptureError(
                f"{meta.folder / 'lights.json'}: light '{light.name}' at {light.vector.tolist()} is inside the "
                "object (every ray from it meets the mesh from inside): the light positions and the mesh are not "
                "in one frame, or not in the same units"
            )


def _light_geometry(light, x, n, tracer, offset, min_cos, trace) -> PointLight:
    """PointLight of one light at the texels (a directional light: its direction, distance 1, no falloff)."""
    if light.kind == "point":
        return point_light(
            x, n, np.broadcast_to(light.vector, x.shape), tracer, offset=offset, min_cos=min_cos, trace=trace
        )
    reach = 10.0 * float(np.ptp(tracer.vertices, axis=0).max()) + 1.0
    pl = point_light(x, n, x + reach * light.vector[None], tracer, offset=offset, min_cos=min_cos, trace=trace)
    return PointLight(
        np.broadcast_to(light.vector, x.shape).astype(x.dtype), np.ones(len(x), x.dtype), pl.cosine, pl.lit, pl.shadowed
    )


def _decode(images: np.ndarray, encoding: str) -> np.ndarray:
    """Linear fractions of full range: the sRGB curve undone for encoding 'srgb'."""
    if encoding != "srgb":
        return images
    return np.where(images <= 0.04045, images / 12.92, ((images + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _camera_images(meta: ViewsFolder, chosen: list, cam: int, threads: int) -> tuple[list, np.ndarray, int]:
    """The chosen images of camera `cam`: their indices among `chosen`, the decoded images (n, H, W, 3) and the bit
    depth; CaptureError when an image's size is not its camera's."""
    name = meta.cameras.names[cam]
    mine = [k for k, i in enumerate(chosen) if meta.images[i].camera == name]
    paths = [meta.folder / meta.images[chosen[k]].file for k in mine]
    images, bits = read_images(paths, threads=threads)
    W, H = int(meta.cameras.width[cam]), int(meta.cameras.height[cam])
    if images.shape[1:3] != (H, W):
        raise CaptureError(
            f"{paths[0]}: image is {images.shape[2]}x{images.shape[1]}, but its camera '{name}' in "
            f"{meta.cameras.source} is {W}x{H} (width x height)"
        )
    return mine, _decode(images, meta.encoding), bits


def _mask(meta: ViewsFolder, image, shape) -> np.ndarray:
    """(H, W, 1) float32: 1 where the image's mask file excludes the pixel (mask value 0), else 0."""
    if image.mask is None:
        return np.zeros(shape[:2] + (1,), dtype=np.float32)
    m, _ = read_image(meta.folder / image.mask)
    if m.shape[:2] != shape[:2]:
        raise CaptureError(
            f"{meta.folder / image.mask}: mask is {m.shape[1]}x{m.shape[0]}, expected {shape[1]}x{shape[0]} like "
            f"its image {image.file}"
        )
    return (m[..., :1] <= 0).astype(np.float32)


def load_views_observations(
    meta: ViewsFolder, geom: AtlasGeometry, tracer: RayTracer, cfg: Config, log: Log
) -> tuple[Observations, dict, list[str]]:
    """The Observations of the chosen images (capture.light_subset indexes images.json's images), the statistics
    and the warnings."""
    where = str(meta.folder / "images.json")
    chosen = light_indices(cfg.capture.light_subset, len(meta.images), where)
    images = [meta.images[i] for i in chosen]
    s = geom.surface
    x = s.positions.double().numpy()
    n = s.normals.double().numpy()
    areas = s.areas.double().numpy()
    steps = texel_steps(geom)
    T, P = s.num_texels, len(images)
    offset = cfg.geometry.shadow_offset_mm
    saturation = meta.saturation_level if meta.saturation_level is not None else cfg.capture.saturation_level
    kappa = np.asarray(meta.kappa if meta.kappa is not None else cfg.capture.kappa, dtype=np.float64)
    check_lights_outside(meta, tracer, {im.light for im in images})
    lights = {light.name: light for light in meta.lights}
    # the dense (P, T) tensors are what the rest of the code takes: float32 (a sparse form is a later issue)
    intensity = np.zeros((P, T, 3), dtype=np.float32)
    view_dir = np.zeros((P, T, 3), dtype=np.float32)
    light_dir = np.zeros((P, T, 3), dtype=np.float32)
    dist = np.ones((P, T), dtype=np.float32)
    cos_l = np.zeros((P, T), dtype=np.float32)
    seen = np.zeros((P, T), dtype=bool)
    lit = np.zeros((P, T), dtype=bool)
    shadowed = np.zeros((P, T), dtype=bool)
    saturated = np.zeros((P, T), dtype=bool)
    masked = np.zeros((P, T), dtype=bool)
    unseen_by: dict[str, np.ndarray] = {}  # reason -> (P, T) bool observations a camera view leaves out
    projects = False  # some texel lies in front of some camera and inside its image
    bits = None
    x32, n32 = x.astype(np.float32), n.astype(np.float32)
    for cam in sorted({meta.cameras.index(im.camera) for im in images}):
        view: CameraView = camera_view(
            meta.cameras, cam, x, n, areas, steps, tracer, offset=offset, min_cos_view=cfg.reflectance.min_cos_view
        )
        projects = projects or bool((~view.reasons[OUTSIDE]).any())
        mine, pixels, depth = _camera_images(meta, chosen, cam, cfg.threads)
        bits = depth if bits is None else bits
        for j, p in enumerate(mine):
            im = images[p]
            for reason, mask in view.reasons.items():
                unseen_by.setdefault(reason, np.zeros((P, T), dtype=bool))[p] = mask
            values = footprint_values(pixels[j], view, T)
            sat = footprint_values((pixels[j] >= saturation).any(-1, keepdims=True).astype(np.float32), view, T)
            out = footprint_values(_mask(meta, im, pixels[j].shape), view, T)
            seen[p] = view.seen
            intensity[p] = np.where(view.seen[:, None], values / np.float32(im.exposure), 0.0)
            saturated[p] = view.seen & (sat[:, 0] > 0)
            masked[p] = view.seen & (out[:, 0] > 0)
            view_dir[p] = view.view_dir
            pl = _light_geometry(lights[im.light], x32, n32, tracer, offset, cfg.reflectance.min_cos_light, view.seen)
            light_dir[p], dist[p], cos_l[p], lit[p], shadowed[p] = (
                pl.direction,
                pl.distance,
                pl.cosine,
                pl.lit,
                pl.shadowed,
            )
    finite = np.isfinite(intensity).all(-1)
    removed = {
        **{f"not seen: {reason}": mask for reason, mask in unseen_by.items()},
        "not lit (n.l at or below reflectance.min_cos_light)": ~lit,
        "in cast shadow": shadowed,
        f"saturated (>= {saturation:g})": saturated,
        "masked out by the image's mask": masked,
        "not finite": ~finite,
    }
    valid = ~np.logical_or.reduce(list(removed.values()))
    if not projects:
        raise CaptureError(
            f"{meta.folder}: nothing projects onto the object: no texel of the mesh {geom.mesh.source} lies in front "
            f"of a camera of {meta.cameras.source} inside its image and facing it; the mesh and the cameras are not "
            "in the same frame (or not in the same units: scene.yaml's units)"
        )
    observations_left(valid, removed, where)
    paths = [meta.folder / im.file for im in images]
    filled = np.where(seen[..., None], intensity, intensity[np.arange(P), seen.argmax(1)][:, None])
    warnings = image_content_checks(filled, paths)
    Y = np.stack([lights[im.light].intensity for im in images])
    point = [lights[im.light].kind == "point" for im in images]
    falloff = np.where(np.asarray(point)[:, None], 1.0 / np.maximum(dist, 1e-9) ** 2, 1.0).astype(np.float32)
    implied_albedo_check(
        intensity, valid, cos_l, Y[:, None, :] * falloff[..., None], kappa, f"{meta.folder / 'lights.json'} (intensity)"
    )
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(cfg.torch_dtype)  # noqa: E731
    obs = Observations(
        intensity=t(intensity),
        valid=torch.from_numpy(valid),
        saturated=torch.from_numpy(saturated),
        shadowed=torch.from_numpy(shadowed),
        light_dir=t(light_dir),
        falloff=t(falloff),
        light_intensity=t(Y),
        view_dir=t(view_dir),
        kappa=t(kappa),
        light_positions=t(np.stack([lights[im.light].vector for im in images])) if all(point) else None,
        light_names=[Path(im.file).name for im in images],
        source=where,
    )
    by_image = seen.any(0)
    stats = {
        "bit_depth": bits,
        "images": P,
        "cameras": len({im.camera for im in images}),
        "texels": T,
        "texels_seen_by_no_image": int((~by_image).sum()),
        "valid_observations": int(valid.sum()),
        "saturation_level": float(saturation),
        "saturated_observations": int((saturated & lit).sum()),
        "shadowed_observations": int(shadowed.sum()),
        "masked_observations": int(masked.sum()),
        **{f"not_seen_{REASON_KEYS[reason]}_observations": int(mask.sum()) for reason, mask in unseen_by.items()},
    }
    return obs, stats, warnings


def load_views_truth(folder: Path, geom: AtlasGeometry, texture_size: int) -> dict | None:
    """truth.npz on the atlas (capture.truth), or None without one; CaptureError when its maps are not
    texture_size x texture_size."""
    path = folder / TRUTH
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            shape = npz["pd"].shape[:2] if "pd" in npz.files else None
    except Exception:
        shape = None  # load_truth names what is wrong with the file
    if shape is not None and shape != (texture_size, texture_size):
        raise CaptureError(
            f"{path}: 'pd' is on a {shape[1]}x{shape[0]} atlas, but capture.texture_size is {texture_size}: the truth "
            f"must lie on the atlas the loader makes (set capture.texture_size: {shape[0]})"
        )
    return load_truth(path, geom.surface)


class MeshViewsLoader(CaptureLoader):
    """capture.kind mesh_views: a mesh, calibrated cameras, lights and their photographs (module doc)."""

    kind = "mesh_views"

    def load_geometry(self, folder: Path, cfg: Config) -> tuple[ViewsFolder, AtlasGeometry]:
        """The folder's metadata and the mesh's atlas at capture.texture_size."""
        meta = read_views_folder(folder)
        path = mesh_path(Path(folder))
        try:
            mesh = read_mesh(path, meta.units)
        except GeometryError as exc:
            raise GeometryError(f"{exc} (units '{meta.units}' from {Path(folder) / 'scene.yaml'})") from None
        geom = atlas_geometry(mesh, cfg.capture.texture_size, dtype=cfg.torch_dtype)
        return meta, geom

    def load(self, folder: Path, cfg: Config, log: Log) -> Capture:
        folder = Path(folder)
        meta, geom = self.load_geometry(folder, cfg)
        s = geom.surface
        how = "made by xatlas (the mesh has no UVs)" if geom.parametrised else "the mesh's own"
        log(
            f"surface: {s.num_texels} texels on a {s.grid_shape[0]}x{s.grid_shape[1]} atlas ({how}), "
            f"{len(geom.mesh.faces)} triangles; {len(meta.images)} images from {len(meta.cameras)} cameras"
        )
        tracer = RayTracer(geom.mesh.vertices, geom.mesh.faces, threads=cfg.threads)
        obs, stats, warnings = load_views_observations(meta, geom, tracer, cfg, log)
        if stats["texels_seen_by_no_image"]:
            log(f"capture: {stats['texels_seen_by_no_image']} of {s.num_texels} texels are seen by no image")
        stats["mesh"] = Path(geom.mesh.source).name
        truth = load_views_truth(folder, geom, cfg.capture.texture_size)
        return Capture(s, obs, stats, truth, folder, warnings, mesh=geom.mesh, mesh_parametrised=geom.parametrised)
