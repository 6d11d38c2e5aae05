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
(core.point_light; texels at a cast shadow's edge left out: capture.shadow_edges), the pixel value divided by the
image's exposure. P = images, so view_dir is (P, T, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import Capture, CaptureLoader, Log
from torchrefl.capture.checks import image_content_checks, implied_albedo_check, light_indices, observations_left
from torchrefl.capture.footprint_spread import half_angle_spread, normal_steps
from torchrefl.capture.shadow_edges import face_neighbours, shadow_edge_observations
from torchrefl.capture.truth import TRUTH, load_truth
from torchrefl.capture.view_folder import ViewFolder, read_view_folder
from torchrefl.capture.views_sampling import (
    OUTSIDE,
    REASON_KEYS,
    SMALL,
    CameraView,
    camera_view,
    footprint_values,
    narrow_warning,
)
from torchrefl.config import Config, read_yaml_mapping
from torchrefl.core.observations import Observations
from torchrefl.core.point_light import PointLight, light_geometry
from torchrefl.core.rays import RayTracer
from torchrefl.core.texel_neighbours import TexelNeighbours
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


@dataclass
class TexelFrame:
    """The atlas's texels as the cameras sample them (float64, mm): points (T, 3), unit normals (T, 3), areas (T,),
    steps (T, 3, 2) (texel_steps), dnormal (T, 3, 2), the normal's change per step (footprint_spread), adjacent
    (T, 4) int64, each texel's neighbours on its face (capture.shadow_edges.face_neighbours), and neighbours, the
    surface's (Surface.neighbours)."""

    points: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    steps: np.ndarray
    dnormal: np.ndarray
    adjacent: np.ndarray
    neighbours: TexelNeighbours


def texel_frame(geom: AtlasGeometry) -> TexelFrame:
    """The TexelFrame of an atlas geometry."""
    s, m, t = geom.surface, geom.mesh, geom.texels
    dnormal = normal_steps(m.vertices, m.faces, m.uvs, s.grid_shape[0], t.face, t.barycentric)
    return TexelFrame(
        s.positions.double().numpy(),
        s.normals.double().numpy(),
        s.areas.double().numpy(),
        texel_steps(geom),
        dnormal,
        face_neighbours(s.neighbours, s.normals.double().numpy()),
        s.neighbours,
    )


def frame_view(meta: ViewFolder, cam: int, frame: TexelFrame, tracer: RayTracer, cfg: Config) -> CameraView:
    """What camera index `cam` of meta's cameras sees of the texels (capture.views_sampling.camera_view, with the
    config's shadow offset and minimum n.v)."""
    f, off, min_cos = frame, cfg.geometry.shadow_offset_mm, cfg.reflectance.min_cos_view
    return camera_view(
        meta.cameras,
        cam,
        f.points,
        f.normals,
        f.areas,
        f.steps,
        tracer,
        offset=off,
        min_cos_view=min_cos,
        neighbours=f.neighbours,
    )


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


@dataclass
class ImageRows:
    """What the images record, one row p per image and one column per texel (float32 / bool; P images, T texels).

    intensity (P, T, 3): the footprint's pixel value / the image's exposure, 0 where not seen; view_dir,
    light_dir (P, T, 3) unit vectors; dist (P, T) texel-light distance (1 for a directional light); cos_l (P, T)
    n . l; seen, lit, shadowed, saturated, masked (P, T); shadow_edge (P, T): lit texels beside a cast shadow
    (capture.shadow_edges); unseen (P, T) uint8: 0 where seen, else 1 + the index in
    UNSEEN of why the camera does not see the texel; spread (P, T, 3) the half-angle offset's variance over the
    footprint along and across it (radians^2) and its shift (radians) (capture.footprint_spread), 0 where not
    seen."""

    intensity: np.ndarray
    view_dir: np.ndarray
    light_dir: np.ndarray
    dist: np.ndarray
    cos_l: np.ndarray
    seen: np.ndarray
    lit: np.ndarray
    shadowed: np.ndarray
    saturated: np.ndarray
    masked: np.ndarray
    unseen: np.ndarray
    spread: np.ndarray
    shadow_edge: np.ndarray

    @classmethod
    def empty(cls, P: int, T: int) -> "ImageRows":
        f3 = lambda: np.zeros((P, T, 3), dtype=np.float32)  # noqa: E731
        b = lambda: np.zeros((P, T), dtype=bool)  # noqa: E731
        return cls(
            f3(), f3(), f3(), np.ones((P, T), np.float32), np.zeros((P, T), np.float32),
            b(), b(), b(), b(), b(), np.zeros((P, T), np.uint8), np.zeros((P, T, 3), np.float32), b(),
        )  # fmt: skip

    def not_seen(self, k: int) -> np.ndarray:
        """(P, T) bool: observations left out for the reason UNSEEN[k]."""
        return self.unseen == k + 1


#: the reasons a camera does not see a texel (views_sampling.CameraView.reasons), in ImageRows.unseen's order
UNSEEN = list(REASON_KEYS)


def _footprint_flag(flags: np.ndarray, view: CameraView, T: int) -> np.ndarray:
    """(T,) bool: a pixel of the (H, W) bool image `flags` contributes to the seen texel's footprint value."""
    return footprint_values(flags[..., None].astype(np.float32), view, T)[:, 0] > 0


def _image_row(rows: ImageRows, p: int, view: CameraView, image: np.ndarray, mask, exposure: float, saturation):
    """Row p of rows from one image (H, W, 3) float32 of view's camera: the footprint values divided by the
    exposure, the saturated texels (a pixel at or above `saturation` in the footprint), the texels its mask
    (H, W) bool or None leaves out, the view and why texels are not seen."""
    T = rows.intensity.shape[1]
    for k, reason in enumerate(UNSEEN):
        if reason in view.reasons:  # a reason no texel reached may be missing
            rows.unseen[p][view.reasons[reason]] = k + 1
    seen = view.seen
    rows.seen[p] = seen
    values = footprint_values(image, view, T)
    rows.intensity[p] = np.where(seen[:, None], values / np.float32(exposure), 0.0)
    rows.saturated[p] = seen & _footprint_flag((image >= saturation).any(-1), view, T)
    if mask is not None:
        rows.masked[p] = seen & _footprint_flag(~mask, view, T)
    rows.view_dir[p] = view.view_dir


def _light_row(rows: ImageRows, p: int, pl: PointLight, adjacent: np.ndarray) -> None:
    """Row p's light geometry, and the texels at its cast shadows' edges (adjacent: TexelFrame.adjacent)."""
    rows.light_dir[p], rows.dist[p], rows.cos_l[p] = pl.direction, pl.distance, pl.cosine
    rows.lit[p], rows.shadowed[p] = pl.lit, pl.shadowed
    rows.shadow_edge[p] = rows.seen[p] & pl.lit & shadow_edge_observations(pl.shadowed, adjacent)


def _read_rows(
    meta: ViewFolder, chosen: list, frame: TexelFrame, tracer: RayTracer, cfg: Config, saturation: float
) -> ImageRows:
    """ImageRows of the chosen images: camera by camera, one camera view and then its images one at a time (one
    image in memory); a pixel at or above `saturation` saturates the texels it contributes to."""
    T, P = len(frame.points), len(chosen)
    rows = ImageRows.empty(P, T)
    x32, n32 = frame.points.astype(np.float32), frame.normals.astype(np.float32)
    offset = cfg.geometry.shadow_offset_mm
    for cam in sorted({int(meta.camera_index[i]) for i in chosen}):
        view = frame_view(meta, cam, frame, tracer, cfg)
        centre = meta.cameras.centres()[cam].numpy()
        for p in [k for k, i in enumerate(chosen) if meta.camera_index[i] == cam]:
            i = chosen[p]
            image = meta.read_image(i)
            _image_row(rows, p, view, image, meta.read_mask(i), meta.views.images[i].exposure, saturation)
            del image
            k = int(meta.light_index[i])
            lights = meta.lights
            pl = light_geometry(
                x32,
                n32,
                tracer,
                position=lights.position[k] if lights.point[k] else None,
                direction=None if lights.point[k] else lights.direction[k],
                offset=offset,
                min_cos=cfg.reflectance.min_cos_light,
            )
            _light_row(rows, p, pl, frame.adjacent)
            _spread_row(rows, p, view, frame, centre, lights.point[k], cfg.reflectance.brdf)
    return rows


def view_spread(
    view: CameraView, frame: TexelFrame, centre: np.ndarray, light_dir: np.ndarray, light_dist: np.ndarray, brdf: str
) -> np.ndarray:
    """(T, 3) float32: the footprint spread of the half-angle offset (capture.footprint_spread) of one image, camera
    `view` (centre (3,) mm) under a light at unit directions light_dir (T, 3) and distances light_dist (T,) (inf for a
    directional light), at the texels the camera sees; 0 elsewhere."""
    out = np.zeros((len(frame.points), 3), dtype=np.float32)
    idx = np.flatnonzero(view.seen)
    X = frame.points[idx]
    out[idx] = half_angle_spread(
        frame.normals[idx],
        frame.steps[idx],
        frame.dnormal[idx],
        view.spread[idx],
        np.asarray(light_dir[idx], dtype=np.float64),
        np.asarray(light_dist[idx], dtype=np.float64),
        view.view_dir[idx].astype(np.float64),
        np.linalg.norm(centre[None] - X, axis=1),
        brdf,
    )
    return out


def _spread_row(
    rows: ImageRows, p: int, view: CameraView, frame: TexelFrame, centre: np.ndarray, point: bool, brdf: str
) -> None:
    """Row p's footprint spread of the half-angle offset (view_spread) at the seen texels."""
    dist = rows.dist[p] if point else np.full(len(frame.points), np.inf)
    rows.spread[p] = view_spread(view, frame, centre, rows.light_dir[p], dist, brdf)


def _removed(rows: ImageRows, saturation: float) -> dict[str, np.ndarray]:
    """Filter description -> (P, T) bool observations it removes (capture.checks.observations_left)."""
    return {
        **{f"not seen: {reason}": rows.not_seen(k) for k, reason in enumerate(UNSEEN)},
        "not lit (n.l at or below reflectance.min_cos_light)": ~rows.lit,
        "in cast shadow": rows.shadowed,
        "at a cast shadow's edge (the footprint partly in shadow)": rows.shadow_edge,
        f"saturated (>= {saturation:g})": rows.saturated,
        "masked out by the image's mask": rows.masked,
        "not finite": ~np.isfinite(rows.intensity).all(-1),
    }


def _valid(rows: ImageRows) -> np.ndarray:
    """(P, T) bool: seen, lit, not shadowed nor at a shadow's edge, saturated nor masked, finite (what _removed
    removes, in place)."""
    valid = rows.seen & rows.lit
    valid &= ~rows.shadowed
    valid &= ~rows.shadow_edge
    valid &= ~rows.saturated
    valid &= ~rows.masked
    valid &= np.isfinite(rows.intensity).all(-1)
    return valid


def _content_warnings(rows: ImageRows, paths: list) -> list[str]:
    """capture.checks.image_content_checks on each image's seen texels (an image's row padded with its first seen
    value to the longest row), and a warning naming the images that show no texel."""
    P = len(paths)
    shows = np.flatnonzero(rows.seen.any(1))  # images in which some texel is seen
    counts = rows.seen[shows].sum(1)
    compact = np.empty((len(shows), int(counts.max(initial=0)), 3), dtype=np.float32)
    for j, p in enumerate(shows):
        values = rows.intensity[p][rows.seen[p]]
        compact[j] = values[0]
        compact[j, : len(values)] = values
    warnings = image_content_checks(compact, [paths[i] for i in shows])
    if len(shows) < P:
        blind = [str(paths[i]) for i in sorted(set(range(P)) - set(shows.tolist()))]
        warnings.append(
            f"{len(blind)} image(s) show no texel of the object usably (outside the image, occluded, too small or "
            f"at silhouettes), e.g. {', '.join(blind[:3])}: is its camera pointed at the object?"
        )
    return warnings


def _albedo_check(rows: ImageRows, valid: np.ndarray, lights, light_of: list, kappa: np.ndarray) -> np.ndarray:
    """capture.checks.implied_albedo_check of the rows; returns the (P, T) float32 falloff (1 / dist^2 for a point
    light, 1 for a directional one)."""
    point = np.asarray(lights.point[light_of])
    falloff = np.where(point[:, None], 1.0 / np.maximum(rows.dist, np.float32(1e-9)) ** 2, np.float32(1.0))
    falloff = falloff.astype(np.float32, copy=False)
    scale = lights.intensity[light_of].astype(np.float32)[:, None, :] * falloff[..., None]
    implied_albedo_check(rows.intensity, valid, rows.cos_l, scale, kappa, f"{lights.source} (intensity)")
    return falloff


def _stats(meta: ViewFolder, rows: ImageRows, valid: np.ndarray, images: list, saturation: float) -> dict:
    """The loader's statistics (metrics.json's capture section)."""
    P, T = rows.seen.shape
    return {
        "bit_depth": meta.bits,
        "images": P,
        "cameras": len({im.camera for im in images}),
        "texels": T,
        "texels_seen_by_no_image": int((~rows.seen.any(0)).sum()),
        "valid_observations": int(valid.sum()),
        "saturation_level": float(saturation),
        "saturated_observations": int((rows.saturated & rows.lit).sum()),
        "shadowed_observations": int((rows.shadowed & rows.seen).sum()),
        "shadow_edge_observations": int(rows.shadow_edge.sum()),
        "masked_observations": int(rows.masked.sum()),
        **{
            f"not_seen_{REASON_KEYS[reason]}_observations": int(rows.not_seen(k).sum())
            for k, reason in enumerate(UNSEEN)
        },
    }


def _check_projects(rows: ImageRows, meta: ViewFolder, geom: AtlasGeometry) -> None:
    """CaptureError when no texel lies in front of any camera and inside its image (the frames differ)."""
    if (rows.unseen != UNSEEN.index(OUTSIDE) + 1).any():
        return
    raise CaptureError(
        f"{meta.folder}: nothing projects onto the object: no texel of the mesh {geom.mesh.source} lies in front "
        f"of a camera of {meta.cameras.source} inside its image and facing it; the mesh and the cameras are not "
        "in the same frame (or not in the same units: scene.yaml's units)"
    )


def load_views_observations(
    meta: ViewFolder, geom: AtlasGeometry, tracer: RayTracer, cfg: Config, log: Log
) -> tuple[Observations, dict, list[str]]:
    """The Observations of the chosen images (capture.light_subset indexes images.json's images), the statistics
    and the warnings. meta's cameras and lights are in mm, like the mesh. The (P, T) arrays are float32, each
    image read, sampled and dropped in turn."""
    where = meta.views.source
    chosen = light_indices(cfg.capture.light_subset, len(meta.views.images), where)
    images = [meta.views.images[i] for i in chosen]
    light_of = [int(meta.light_index[i]) for i in chosen]
    v, lights = meta.views, meta.lights
    saturation = v.saturation_level if v.saturation_level is not None else cfg.capture.saturation_level
    kappa = np.asarray(v.kappa if v.kappa is not None else cfg.capture.kappa, dtype=np.float64)
    check_lights_outside(lights, tracer, light_of)
    rows = _read_rows(meta, chosen, texel_frame(geom), tracer, cfg, saturation)
    valid = _valid(rows)
    _check_projects(rows, meta, geom)
    if not valid.any():
        observations_left(valid, _removed(rows, saturation), where)
    warnings = narrow_warning(rows.seen, rows.not_seen(UNSEEN.index(SMALL)))
    warnings += _content_warnings(rows, [meta.paths[i] for i in chosen])
    falloff = _albedo_check(rows, valid, lights, light_of, kappa)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(cfg.torch_dtype)  # noqa: E731
    point = lights.point[light_of]
    obs = Observations(
        intensity=t(rows.intensity),
        valid=torch.from_numpy(valid),
        saturated=torch.from_numpy(rows.saturated),
        shadowed=torch.from_numpy(rows.shadowed),
        light_dir=t(rows.light_dir),
        falloff=t(falloff),
        light_intensity=t(lights.intensity[light_of]),
        view_dir=t(rows.view_dir),
        kappa=t(kappa),
        light_positions=t(lights.position[light_of]) if point.all() else None,
        lobe_spread=t(rows.spread),
        light_names=[Path(im.file).name for im in images],
        source=where,
    )
    return obs, _stats(meta, rows, valid, images, saturation), warnings


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
