"""Loader of the `mesh_views` capture kind: a triangle mesh and photographs from calibrated cameras under lights.

Folder (the contract: docs/capture-formats.md, `mesh_views`):
    mesh.obj | mesh.ply | mesh.glb   the object, in scene.yaml's `units` (mm when it names none)
    scene.yaml                       optional: units (mm, cm, m, in) of the mesh, cameras and lights
    images.json, cameras.json (or a COLMAP model), lights.json, images/*   (capture.view_folder reads them)
    truth.npz                        optional (synthetic scenes): pd, ps, sigma on the atlas

The texels are the mesh's atlas at capture.texture_size (geometry.atlas_surface; made by xatlas when the mesh has
no UVs, and then written into the run folder). Each image is one light configuration p of the Observations: its
camera's view of the texels (capture.views_sampling: projection with distortion, Embree visibility, footprint
sampling, silhouettes and depth steps left out), its light's direction, falloff and cast shadow
(core.point_light), the pixel value divided by the image's exposure. P = images, so view_dir is (P, T, 3).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import Capture, CaptureLoader, Log
from torchrefl.capture.checks import image_content_checks, implied_albedo_check, light_indices, observations_left
from torchrefl.capture.truth import TRUTH, load_truth
from torchrefl.capture.view_folder import ViewFolder, read_view_folder
from torchrefl.capture.views_sampling import OUTSIDE, REASON_KEYS, CameraView, camera_view, footprint_values
from torchrefl.config import Config, read_yaml_mapping
from torchrefl.core.observations import Observations
from torchrefl.core.point_light import light_geometry
from torchrefl.core.rays import RayTracer
from torchrefl.errors import CaptureError
from torchrefl.geometry.atlas import uv_to_texel_xy
from torchrefl.geometry.atlas_neighbours import face_jacobians
from torchrefl.geometry.atlas_surface import AtlasGeometry, atlas_geometry
from torchrefl.geometry.mesh_file import MESH_SUFFIXES, UNIT_SCALE_MM, read_mesh

#: rays cast from a point light to tell whether it sits inside the object (every one meets a back face)
INSIDE_RAYS = 26
SCENE_YAML = "scene.yaml"


def read_units(folder: Path) -> str:
    """scene.yaml's `units` (mm without the file or the key); CaptureError naming the file and key otherwise."""
    path = folder / SCENE_YAML
    if not path.is_file():
        return "mm"
    doc = read_yaml_mapping(path, CaptureError, "scene file")
    unknown = sorted(set(doc) - {"units"})
    if unknown:
        raise CaptureError(f"{path}: unknown key(s) {', '.join(map(repr, unknown))} (scene.yaml holds 'units')")
    units = doc.get("units", "mm")
    if units not in UNIT_SCALE_MM:
        raise CaptureError(f"{path}: key 'units' is {units!r}, expected one of {', '.join(UNIT_SCALE_MM)}")
    return units


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


def check_lights_outside(lights, tracer: RayTracer, used) -> None:
    """CaptureError naming a point light (of capture.lights_json.Lights, indices `used`) that sits inside the
    object: every ray from it meets a back face."""
    v = tracer.vertices.astype(np.float64)[tracer.faces.astype(np.int64)]
    face_n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    dirs = _directions(INSIDE_RAYS)
    for k in sorted(set(used)):
        if not lights.point[k]:
            continue
        hits = tracer.closest_hit(np.broadcast_to(lights.position[k], dirs.shape), dirs)
        if hits.hit.all() and (np.einsum("ni,ni->n", face_n[hits.triangle], dirs) > 0).all():
            raise CaptureError(
                f"{lights.source}: light '{lights.names[k]}' at {lights.position[k].tolist()} mm is inside the "
                "object (every ray from it meets the mesh from inside): the light positions and the mesh are not "
                "in one frame, or not in the same units"
            )


def _camera_images(meta: ViewFolder, chosen: list, cam: int) -> tuple[list, list]:
    """The positions among `chosen` of camera `cam`'s images and those images (H, W, 3), decoded (ViewFolder)."""
    mine = [k for k, i in enumerate(chosen) if meta.camera_index[i] == cam]
    return mine, [meta.read_image(chosen[k]) for k in mine]


def _masked_out(meta: ViewFolder, i: int, shape) -> np.ndarray:
    """(H, W, 1) float32: 1 where image i's mask leaves the pixel out, else 0."""
    mask = meta.read_mask(i)
    if mask is None:
        return np.zeros(shape[:2] + (1,), dtype=np.float32)
    return (~mask)[..., None].astype(np.float32)


def load_views_observations(
    meta: ViewFolder, geom: AtlasGeometry, tracer: RayTracer, cfg: Config, log: Log
) -> tuple[Observations, dict, list[str]]:
    """The Observations of the chosen images (capture.light_subset indexes images.json's images), the statistics
    and the warnings. meta's cameras and lights are in mm, like the mesh."""
    where = meta.views.source
    chosen = light_indices(cfg.capture.light_subset, len(meta.views.images), where)
    images = [meta.views.images[i] for i in chosen]
    light_of = [int(meta.light_index[i]) for i in chosen]
    s = geom.surface
    x = s.positions.double().numpy()
    n = s.normals.double().numpy()
    areas = s.areas.double().numpy()
    steps = texel_steps(geom)
    T, P = s.num_texels, len(images)
    offset = cfg.geometry.shadow_offset_mm
    v = meta.views
    saturation = v.saturation_level if v.saturation_level is not None else cfg.capture.saturation_level
    kappa = np.asarray(v.kappa if v.kappa is not None else cfg.capture.kappa, dtype=np.float64)
    lights = meta.lights
    check_lights_outside(lights, tracer, light_of)
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
    x32, n32 = x.astype(np.float32), n.astype(np.float32)
    for cam in sorted({int(meta.camera_index[i]) for i in chosen}):
        view: CameraView = camera_view(
            meta.cameras, cam, x, n, areas, steps, tracer, offset=offset, min_cos_view=cfg.reflectance.min_cos_view
        )
        projects = projects or bool((~view.reasons[OUTSIDE]).any())
        mine, pixels = _camera_images(meta, chosen, cam)
        for j, p in enumerate(mine):
            im = images[p]
            for reason, mask in view.reasons.items():
                unseen_by.setdefault(reason, np.zeros((P, T), dtype=bool))[p] = mask
            values = footprint_values(pixels[j], view, T)
            sat = footprint_values((pixels[j] >= saturation).any(-1, keepdims=True).astype(np.float32), view, T)
            out = footprint_values(_masked_out(meta, chosen[p], pixels[j].shape), view, T)
            seen[p] = view.seen
            intensity[p] = np.where(view.seen[:, None], values / np.float32(im.exposure), 0.0)
            saturated[p] = view.seen & (sat[:, 0] > 0)
            masked[p] = view.seen & (out[:, 0] > 0)
            view_dir[p] = view.view_dir
            k = light_of[p]
            pl = light_geometry(
                x32,
                n32,
                tracer,
                position=lights.position[k] if lights.point[k] else None,
                direction=None if lights.point[k] else lights.direction[k],
                offset=offset,
                min_cos=cfg.reflectance.min_cos_light,
                trace=view.seen,
            )
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
    paths = [meta.paths[i] for i in chosen]
    shows = np.flatnonzero(seen.any(1))  # images in which some texel is seen (the content checks' images)
    filled = np.where(seen[..., None], intensity, intensity[np.arange(P), seen.argmax(1)][:, None])[shows]
    warnings = image_content_checks(filled, [paths[i] for i in shows])
    if len(shows) < P:
        blind = [str(paths[i]) for i in sorted(set(range(P)) - set(shows.tolist()))]
        warnings.append(
            f"{len(blind)} image(s) show no texel of the object usably (outside the image, occluded, too small or "
            f"at silhouettes), e.g. {', '.join(blind[:3])}: is its camera pointed at the object?"
        )
    Y = lights.intensity[light_of]
    point = lights.point[light_of]
    falloff = np.where(np.asarray(point)[:, None], 1.0 / np.maximum(dist, 1e-9) ** 2, 1.0).astype(np.float32)
    implied_albedo_check(
        intensity, valid, cos_l, Y[:, None, :] * falloff[..., None], kappa, f"{lights.source} (intensity)"
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
        light_positions=t(lights.position[light_of]) if point.all() else None,
        light_names=[Path(im.file).name for im in images],
        source=where,
    )
    by_image = seen.any(0)
    stats = {
        "bit_depth": meta.bits,
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

    def load_geometry(self, folder: Path, cfg: Config) -> tuple[ViewFolder, AtlasGeometry]:
        """The folder's metadata (cameras and lights scaled to mm with the mesh) and the mesh's atlas at
        capture.texture_size."""
        folder = Path(folder)
        units = read_units(folder)
        meta = read_view_folder(folder)
        scale = UNIT_SCALE_MM[units]
        meta = replace(meta, cameras=meta.cameras.scaled(scale), lights=meta.lights.scaled(scale))
        geom = atlas_geometry(read_mesh(mesh_path(folder), units), cfg.capture.texture_size, dtype=cfg.torch_dtype)
        return meta, geom

    def load(self, folder: Path, cfg: Config, log: Log) -> Capture:
        folder = Path(folder)
        meta, geom = self.load_geometry(folder, cfg)
        s = geom.surface
        how = "made by xatlas (the mesh has no UVs)" if geom.parametrised else "the mesh's own"
        log(
            f"surface: {s.num_texels} texels on a {s.grid_shape[0]}x{s.grid_shape[1]} atlas ({how}), "
            f"{len(geom.mesh.faces)} triangles; {len(meta.views.images)} images from {len(meta.cameras)} cameras"
        )
        tracer = RayTracer(geom.mesh.vertices, geom.mesh.faces, threads=cfg.threads)
        obs, stats, warnings = load_views_observations(meta, geom, tracer, cfg, log)
        warnings = list(meta.warnings) + warnings
        if stats["texels_seen_by_no_image"]:
            log(f"capture: {stats['texels_seen_by_no_image']} of {s.num_texels} texels are seen by no image")
        stats["mesh"] = Path(geom.mesh.source).name
        truth = load_views_truth(folder, geom, cfg.capture.texture_size)
        # the interreflection levels trace the mesh itself; its hits (geometry.atlas_hits) map a hit's uv to a texel
        return Capture(s, obs, stats, truth, folder, warnings, mesh=geom.mesh, mesh_parametrised=geom.parametrised)
