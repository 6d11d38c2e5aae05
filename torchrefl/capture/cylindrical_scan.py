"""Loader of the `cylindrical_scan` capture kind (the seed's Cyberware-style rig).

Folder layout (written by the synthetic scanner and by the rig, the contract: docs/capture-formats.md):
    scan.yaml         grid, camera, light intensity, kappa, saturation level, lights
    range.npy         (H, W) float range r(s, t) in mm, NaN where nothing was measured
    textures/*.png    one texture image (H, W, 3) per light position
    manifest.jsonl    (optional) the rig's manifest; `lights: manifest.jsonl` in scan.yaml
    truth.npz         (optional, synthetic scenes) ground-truth pd, ps, sigma maps

The texel grid is the cylindrical image. Points and normals come from the range image
by the dissertation's preprocessing (median filter, Yokoya-Levine quadratic fit, eq. 2.1-2.4);
the triangle mesh for shadow rays is the range image's grid triangulation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import Capture, CaptureLoader, Log
from torchrefl.capture.checks import (
    distinct_image_files,
    image_content_checks,
    implied_albedo_check,
    light_indices,
    observations_left,
    unlisted_images,
)
from torchrefl.capture.cylindrical_rig import CylindricalRig
from torchrefl.capture.images import read_images
from torchrefl.capture.scan_scale import scan_scale_check
from torchrefl.capture.scan_yaml import read_manifest, read_scan_yaml  # noqa: F401  (the loader's readers)
from torchrefl.capture.shadow_edges import face_neighbours, shadow_edge_observations
from torchrefl.capture.truth import TRUTH
from torchrefl.capture.truth import load_truth as read_truth
from torchrefl.capture.untrusted_texels import mixed_footprint_grid, untrusted_counts, untrusted_geometry
from torchrefl.config import Config
from torchrefl.core.observations import Observations
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.core.surface import Surface
from torchrefl.core.texel_grid import TexelGrid
from torchrefl.core.threads import thread_map
from torchrefl.errors import CaptureError, GeometryError
from torchrefl.geometry.footprint import unfit_windows
from torchrefl.geometry.range_image import median_note, preprocess_range_image
from torchrefl.geometry.range_mesh import grid_triangulation, texel_areas

DEFAULT_SATURATION = 0.995


@dataclass
class ScanGeometry:
    """What the range image gives: the Surface, the rig geometry, the tracer and the scan metadata."""

    surface: Surface
    rig: CylindricalRig
    tracer: RayTracer
    meta: dict
    folder: Path
    mixed: np.ndarray | None = None  # (T,) bool: texels whose footprint is mixed (geometry.footprint); None: none
    unfit: np.ndarray | None = None  # (T,) bool: texels no range-fitting window describes (footprint.unfit_windows)
    median_size: int = 1  # the median window the preprocessing applied (1 = none)
    noise_mm: float = 0.0  # the range noise it estimated, mm
    scale_warnings: list[str] = field(default_factory=list)  # the scale check's (capture.scan_scale)

    def texel_angles(self) -> np.ndarray:
        """(T,) scan angle of each valid texel's column."""
        cols = self.surface.texel_index.numpy() % self.rig.columns
        return self.rig.angles()[cols]

    def view_dirs(self) -> np.ndarray:
        """(T, 3) unit vectors from each texel to the camera."""
        cam = self.rig.camera_positions(self.texel_angles())
        v = cam - self.surface.positions.numpy().astype(np.float64)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def light_world_positions(self, head_positions: np.ndarray) -> np.ndarray:
        """(P, T, 3) world position of each head-frame light (P, 3) for every texel."""
        s = self.texel_angles()
        return np.stack([self.rig.head_to_world(s, np.asarray(h, dtype=np.float64)) for h in head_positions])


def _range_in_mm(raw: np.ndarray, spec: dict, path: Path, where: str) -> np.ndarray:
    """The stored range values in mm: float32/float64 as they are; integers only with range.scale_mm."""
    if np.issubdtype(raw.dtype, np.integer) and "scale_mm" not in spec:
        raise CaptureError(
            f"{path}: range image is {raw.dtype}, integer counts are not millimetres; store float32 "
            f"mm (NaN where nothing was measured) or give range.scale_mm (mm per count) in {where}"
        )
    if not np.issubdtype(raw.dtype, np.integer) and raw.dtype not in (np.float32, np.float64):
        raise CaptureError(f"{path}: range image is {raw.dtype}, expected float32 or float64 millimetres")
    for key in ("scale_mm", "offset_mm"):
        if key in spec and (
            isinstance(spec[key], bool)
            or not isinstance(spec[key], (int, float))
            or not math.isfinite(spec[key])
            or (key == "scale_mm" and spec[key] <= 0)
        ):
            raise CaptureError(
                f"{where}: key 'range.{key}' = {spec[key]!r}, expected a finite number"
                + (" > 0" if key == "scale_mm" else "")
            )
    return raw.astype(np.float64) * float(spec.get("scale_mm", 1.0)) + float(spec.get("offset_mm", 0.0))


def read_range(folder: Path, doc: dict) -> np.ndarray:
    """(H, W) float64 range image in mm (NaN = no surface): distances from the rotation axis, inside the camera's."""
    spec = doc.get("range", {})
    path = folder / spec.get("file", "range.npy")
    where = str(folder / "scan.yaml")
    if not path.is_file():
        raise CaptureError(f"{path}: range image not found")
    try:
        raw = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises many kinds for corrupt files
        raise CaptureError(f"{path}: unreadable range image ({exc})") from None
    if raw.ndim != 2:
        raise CaptureError(f"{path}: range image has shape {raw.shape}, expected (H, W)")
    r = _range_in_mm(raw, spec, path, where)
    finite = np.isfinite(r)
    if finite.sum() == 0:
        raise CaptureError(f"{path}: range image has no valid (finite) pixel: the mask selects nothing")
    for key, n in (("rows", r.shape[0]), ("columns", r.shape[1])):
        if key in doc["grid"] and doc["grid"][key] != n:
            raise CaptureError(f"{where}: key 'grid.{key}' = {doc['grid'][key]!r} but {path} has {n} {key}")
    lo, hi, camera = float(r[finite].min()), float(r[finite].max()), float(doc["camera"]["distance_mm"])
    if lo < 0:
        raise CaptureError(
            f"{path}: {int((r[finite] < 0).sum())} negative ranges (down to {lo:.4g} mm); expected "
            "distances from the rotation axis in mm, >= 0"
        )
    if hi >= camera:
        raise CaptureError(
            f"{path}: ranges up to {hi:.4g} mm reach past the camera at camera.distance_mm = "
            f"{camera:g} in {where}: the ranges are not in mm (range.scale_mm?) or the camera "
            "distance is wrong"
        )
    return r


def rig_from_yaml(doc: dict, shape) -> CylindricalRig:
    g, c = doc["grid"], doc["camera"]
    return CylindricalRig(
        rows=shape[0],
        columns=shape[1],
        angle0=math.radians(g["angle0_deg"]),
        angle_step=math.radians(g["angle_step_deg"]),
        height0=float(g["height0_mm"]),
        height_step=float(g["height_step_mm"]),
        camera_distance=float(c["distance_mm"]),
        camera_height=float(c["height_mm"]),
    )


def load_scan_geometry(
    folder,
    *,
    median_size: int | None = None,
    fit_window: int = 5,
    noise_tolerance: float = 2.0,
    threads: int = 2,
    dtype=torch.float32,
    check_scale: bool = True,
) -> ScanGeometry:
    """Range image -> Surface (points, normals, areas, mesh) and the rig geometry (median_size None: auto); check_scale:
    the scale check (capture.scan_scale: errors raised, warnings kept), False where the caller made it."""
    folder = Path(folder)
    doc = read_scan_yaml(folder)
    r = read_range(folder, doc)
    scale_warnings = scan_scale_check(r, doc, folder).enforce() if check_scale else []
    rig = rig_from_yaml(doc, r.shape)
    valid = np.isfinite(r)
    r_t = torch.from_numpy(np.where(valid, r, 0.0))
    geo = preprocess_range_image(
        r_t,
        torch.from_numpy(valid),
        s0=rig.angle0,
        ds=rig.angle_step,
        t0=rig.height0,
        dt=rig.height_step,
        median_size=median_size,
        window=fit_window,
        wrap=rig.covers_full_turn(),
        noise_tolerance=noise_tolerance,
    )
    ok = geo.valid.numpy() & valid
    points_ok = np.isfinite(geo.points.numpy()).all(-1) & np.isfinite(geo.normals.numpy()).all(-1)
    ok &= points_ok
    if not ok.any():
        raise GeometryError(f"{folder / 'range.npy'}: no texel survives preprocessing (mask selects nothing)")
    points = geo.points.numpy()
    normals = geo.normals.numpy()
    idx = np.flatnonzero(ok.ravel())
    verts, faces = grid_triangulation(points, ok, wrap=rig.covers_full_turn())
    areas = texel_areas(points, ok)
    surface = Surface(
        grid_shape=r.shape,
        texel_index=torch.from_numpy(idx).long(),
        positions=torch.from_numpy(points.reshape(-1, 3)[idx]).to(dtype),
        normals=torch.from_numpy(normals.reshape(-1, 3)[idx]).to(dtype),
        areas=torch.from_numpy(areas.ravel()[idx]).to(dtype),
        mesh_vertices=verts,
        mesh_faces=faces,
        units="mm",
        source=str(folder / "range.npy"),
        neighbours=TexelGrid(idx, r.shape, wrap=rig.covers_full_turn()),
    )
    tracer = RayTracer(verts, faces, threads=threads)
    mixed = mixed_footprint_grid(r, valid, geo, rig).ravel()[idx]
    unfit = unfit_windows(geo.fit_rms_mm.double().numpy(), ok, geo.spacing_mm, geo.noise_mm).ravel()[idx]
    return ScanGeometry(surface, rig, tracer, doc, folder, mixed, unfit, geo.median_size, geo.noise_mm, scale_warnings)


def observation_geometry(
    geom: ScanGeometry,
    head_positions: np.ndarray,
    *,
    shadow_offset: float = 0.05,
    min_cos_view: float = 0.0,
    min_cos_light: float = 0.0,
):
    """Light/view geometry of P head-frame lights for every texel, with Embree visibility.

    Returns dict with light_dir (P, T, 3), dist (P, T), view_dir (T, 3), cos_l (P, T), cos_v (T,),
    seen (T,) (camera sees the texel), lit (P, T) (n.l above threshold), shadowed (P, T) (traced at every lit texel,
    seen or not: the interreflection levels' emitters).
    Computed in float32 (what Embree uses) by torchrefl.core.point_light (its one shadow-offset rule); lights are
    processed in parallel on the tracer's threads (numpy and Embree both release the GIL).
    """
    surf = geom.surface
    x = surf.positions.numpy().astype(np.float32)
    n = surf.normals.numpy().astype(np.float32)
    v = geom.view_dirs().astype(np.float32)
    cos_v = np.einsum("ti,ti->t", n, v)
    cam = geom.rig.camera_positions(geom.texel_angles()).astype(np.float32)
    seen = cos_v > min_cos_view
    idx = np.flatnonzero(seen)
    if idx.size:
        seen[idx] = geom.tracer.visible(x[idx], n[idx], cam[idx], offset=shadow_offset)
    heads = np.asarray(head_positions, dtype=np.float64).reshape(-1, 3)
    P, T = len(heads), len(x)
    u, w = (a.astype(np.float32) for a in geom.rig.head_axes(geom.texel_angles()))
    l_all = np.empty((P, T, 3), dtype=np.float32)
    dist_all = np.empty((P, T), dtype=np.float32)
    cos_all = np.empty((P, T), dtype=np.float32)
    shadowed = np.zeros((P, T), dtype=bool)

    def one_light(p: int) -> None:
        lat, vert, rad = (np.float32(c) for c in heads[p])
        light = rad * u + lat * w
        light[:, 1] += vert
        pl = point_light(x, n, light, geom.tracer, offset=shadow_offset, min_cos=min_cos_light)
        l_all[p], dist_all[p], cos_all[p], shadowed[p] = pl.direction, pl.distance, pl.cosine, pl.shadowed

    thread_map(one_light, range(P), geom.tracer.threads)
    return {
        "light_dir": l_all,
        "dist": dist_all,
        "view_dir": v,
        "cos_l": cos_all,
        "cos_v": cos_v,
        "seen": seen,
        "lit": cos_all > min_cos_light,
        "shadowed": shadowed,
    }


def _read_textures(geom: ScanGeometry, lights: list, where: str, threads: int) -> tuple[np.ndarray, int, list[str]]:
    """(P, T, 3) texture values at the surface's texels, the bit depth and warnings; CaptureError for a file
    used by two lights, a texture whose size, depth or channels differ, constant or all-black textures."""
    paths = [geom.folder / e["image"] for e in lights]
    distinct_image_files(paths, [e["image"] for e in lights], where)
    images, bits = read_images(paths, threads=threads)
    H, W = geom.surface.grid_shape
    if images.shape[1:3] != (H, W):
        raise CaptureError(
            f"{paths[0]}: texture is {images.shape[2]}x{images.shape[1]}, expected {W}x{H} like the range image "
            f"{geom.folder / 'range.npy'}"
        )
    intensity = images.reshape(len(lights), H * W, 3)[:, geom.surface.texel_index.numpy()]
    warnings = image_content_checks(intensity, paths)
    warnings += unlisted_images(
        geom.folder / "textures",
        [geom.folder / e["image"] for e in read_scan_yaml(geom.folder)["lights"]],
        "*.png",
        where,
    )
    return intensity, bits, warnings


#: load_scan_observations' reason for the lit observations next to a cast shadow (untrusted_texels)
SHADOW_EDGE = "at a cast shadow's edge (a shadowed neighbour on the same face)"


def _excluded_observations(
    geom: ScanGeometry, og: dict, intensity: np.ndarray, saturation_level: float, edge_width: int, crease_angle_deg
) -> tuple[dict, np.ndarray, dict]:
    """load_scan_observations' exclusions: {reason: (P, T) bool observations it removes}, and the saturated
    (P, T) and untrusted_geometry's (T,) masks (for the statistics)."""
    saturated = (intensity >= saturation_level).any(-1)
    finite = np.isfinite(intensity).all(-1)
    texels = untrusted_geometry(geom, edge_width, crease_angle_deg)
    every = lambda mask: np.broadcast_to(mask[None], saturated.shape)
    removed = {
        "not seen by the camera (facing away or occluded)": every(~og["seen"]),
        "not lit (n.l at or below the threshold)": ~og["lit"],
        "in cast shadow": og["shadowed"],
        SHADOW_EDGE: shadow_edge_observations(
            og["shadowed"], face_neighbours(geom.surface.neighbours, geom.surface.normals.numpy())
        ),
        f"saturated (>= {saturation_level:g})": saturated,
        "not finite": ~finite,
        f"edge texels (geometry.edge_width {edge_width})": every(texels["edge"]),
        "crease texels (geometry.crease_angle_deg)": every(texels["crease"]),
        "mixed-footprint texels (rims, thin edges, depth steps in the range image)": every(texels["mixed"]),
        "texels no range-fitting window describes (strips narrower than the window)": every(texels["unfit"]),
    }
    return removed, saturated, texels


def load_scan_observations(
    geom: ScanGeometry,
    *,
    light_subset=None,
    saturation_level: float | None = None,
    kappa=None,
    shadow_offset: float = 0.05,
    min_cos_view: float = 0.0,
    min_cos_light: float = 0.0,
    threads: int = 2,
    dtype=torch.float32,
    edge_width: int = 0,
    crease_angle_deg: float | None = None,
) -> tuple[Observations, dict]:
    """Texture images + light table -> Observations (and load statistics, with stats['warnings'] a list).

    saturation_level, kappa: None = scan.yaml's (saturation_level, light.kappa), or 0.995 and pi where it
    gives none (CylindricalScanLoader passes the values its precedence rule chose).
    edge_width: observations of texels within this many texels of the mesh boundary (silhouettes,
    depth discontinuities: mixed pixels) are not valid (counted in the statistics); crease_angle_deg:
    neither are those of texels on a crease sharper than this (range_mesh.crease_texels; None: none), nor those
    of texels whose footprint the range image shows to be mixed (geom.mixed) or that no range-fitting window
    describes (geom.unfit)."""
    doc = read_scan_yaml(geom.folder)
    where = str(geom.folder / "scan.yaml")
    if not doc["lights"]:
        raise CaptureError(f"{where}: key 'lights' lists no light (expected one entry per texture image)")
    lights = [doc["lights"][i] for i in light_indices(light_subset, len(doc["lights"]), where)]
    saturation_level = doc.get("saturation_level", DEFAULT_SATURATION) if saturation_level is None else saturation_level
    kappa = np.asarray(doc["light"].get("kappa", [math.pi] * 3) if kappa is None else kappa, dtype=np.float64)
    intensity, bits, warnings = _read_textures(geom, lights, where, threads)
    head = np.array([e["position_mm"] for e in lights], dtype=np.float64)
    og = observation_geometry(
        geom, head, shadow_offset=shadow_offset, min_cos_view=min_cos_view, min_cos_light=min_cos_light
    )
    idx = geom.surface.texel_index.numpy()
    removed, saturated, texels = _excluded_observations(
        geom, og, intensity, saturation_level, edge_width, crease_angle_deg
    )
    valid = ~np.logical_or.reduce(list(removed.values()))
    observations_left(valid, removed, where)
    Y = np.array([e.get("intensity", doc["light"]["intensity"]) for e in lights], dtype=np.float64)
    falloff = 1.0 / np.maximum(og["dist"], 1e-9) ** 2
    implied_albedo_check(
        intensity,
        valid,
        og["cos_l"],
        Y[:, None, :] * falloff[..., None],
        kappa,
        f"{where} (light.intensity, lights[i].intensity)",
    )
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(dtype)
    obs = Observations(
        intensity=t(intensity),
        valid=torch.from_numpy(valid),
        saturated=torch.from_numpy(saturated),
        shadowed=torch.from_numpy(og["shadowed"]),
        light_dir=t(og["light_dir"]),
        falloff=t(falloff),
        light_intensity=t(Y),
        view_dir=t(og["view_dir"]),
        kappa=t(kappa),
        light_positions=t(head),
        light_names=[e["image"] for e in lights],
        source=where,
    )
    stats = {
        "bit_depth": bits,
        "lights": len(lights),
        "texels": int(idx.size),
        "saturation_level": float(saturation_level),
        "saturated_observations": int((saturated & og["seen"][None] & og["lit"]).sum()),
        "shadowed_observations": int((og["shadowed"] & og["seen"][None]).sum()),
        "shadow_edge_observations": int((removed[SHADOW_EDGE] & og["seen"][None] & og["lit"]).sum()),
        "valid_observations": int(valid.sum()),
        **untrusted_counts(texels),
        "warnings": warnings,
    }
    return obs, stats


def load_truth(folder, surface: Surface, doc: dict | None = None) -> dict | None:
    """Ground truth per valid texel from the truth file scan.yaml names (truth.file; truth.npz when scan.yaml
    names none and the file is there), or None for a folder without truth."""
    folder = Path(folder)
    doc = read_scan_yaml(folder) if doc is None else doc
    name = doc.get("truth", {}).get("file")
    if name is None and not (folder / TRUTH).is_file():
        return None
    return read_truth(folder / (name or TRUTH), surface)


class CylindricalScanLoader(CaptureLoader):
    """capture.kind cylindrical_scan: scan.yaml, range.npy, textures/*.png (and truth.npz when synthetic)."""

    kind = "cylindrical_scan"

    def load_geometry(self, folder: Path, cfg: Config, check_scale: bool = True) -> ScanGeometry:
        """The range image's Surface and the rig geometry (what light selection needs before any texture)."""
        g = cfg.geometry
        kw = dict(median_size=g.median_size, fit_window=g.fit_window, threads=cfg.threads, dtype=cfg.torch_dtype)
        return load_scan_geometry(folder, check_scale=check_scale, **kw)

    def load(self, folder: Path, cfg: Config, log: Log, geometry: ScanGeometry | None = None) -> Capture:
        geom = geometry if geometry is not None else self.load_geometry(folder, cfg)
        s = geom.surface
        log(f"surface: {s.num_texels} texels on a {s.grid_shape} grid, {len(s.mesh_faces)} triangles")
        g = cfg.geometry
        saturation_level, kappa = folder_over_config(geom.meta, cfg, geom.folder / "scan.yaml", log)
        obs, stats = load_scan_observations(
            geom,
            light_subset=cfg.capture.light_subset,
            saturation_level=saturation_level,
            kappa=kappa,
            shadow_offset=g.shadow_offset_mm,
            threads=cfg.threads,
            dtype=cfg.torch_dtype,
            edge_width=g.edge_width,
            crease_angle_deg=g.crease_angle_deg,
        )
        stats["range_noise_mm"] = geom.noise_mm
        stats["range_median_size"] = geom.median_size
        stats["preprocessing"] = median_note(geom.median_size, geom.noise_mm, g.median_size)
        log(f"geometry: {stats['preprocessing']}")
        if stats["crease_texels_excluded"]:
            log(
                f"geometry: {stats['crease_texels_excluded']} texels on creases sharper than "
                f"{g.crease_angle_deg:g} deg (mixed pixels) are not fitted"
            )
        if stats["mixed_footprint_texels_excluded"]:
            log(
                f"geometry: {stats['mixed_footprint_texels_excluded']} texels whose footprint the range image shows "
                "to be mixed (rims, thin edges, depth steps) are not fitted"
            )
        if stats["unfit_range_texels_excluded"]:
            log(
                f"geometry: {stats['unfit_range_texels_excluded']} texels that no range-fitting window describes "
                "(every window spans a crease, an edge or a turn too fast for a quadratic: their normals are "
                "extrapolated) are not fitted"
            )
        warnings = geom.scale_warnings + stats.pop("warnings")
        untrusted = np.logical_or.reduce(list(untrusted_geometry(geom, g.edge_width, g.crease_angle_deg).values()))
        truth = load_truth(folder, s, geom.meta)
        return Capture(s, obs, stats, truth, Path(folder), warnings, torch.from_numpy(untrusted))


def folder_over_config(doc: dict, cfg: Config, where: Path, log: Log) -> tuple[float, list]:
    """saturation_level and kappa by one rule: a value scan.yaml gives is the capture's own and wins; the
    config's capture.* value applies where scan.yaml gives none. A config value overridden is logged."""
    chosen = []
    for key, folder_value, config_value in (
        ("saturation_level", doc.get("saturation_level"), cfg.capture.saturation_level),
        ("light.kappa", doc["light"].get("kappa"), list(cfg.capture.kappa)),
    ):
        config_key = f"capture.{key.split('.')[-1]}"
        if folder_value is None:
            chosen.append(config_value)
            continue
        if not np.allclose(folder_value, config_value, rtol=1e-12, atol=0):
            log(
                f"{config_key} {config_value} (config) is overridden by {key} {folder_value} in {where}: "
                "a value the capture folder gives is its own"
            )
        chosen.append(folder_value)
    return float(chosen[0]), [float(k) for k in chosen[1]]
