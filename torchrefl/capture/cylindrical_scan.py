"""Loader of the `cylindrical_scan` capture kind (the seed's Cyberware-style rig).

Folder layout (written by the synthetic scanner and by the rig, see README "Capture folders"):
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

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import Capture, CaptureLoader, Log
from torchrefl.capture.cylindrical_rig import CylindricalRig
from torchrefl.capture.images import read_images
from torchrefl.core.observations import Observations
from torchrefl.config import Config, read_yaml_mapping
from torchrefl.errors import CaptureError, GeometryError
from torchrefl.geometry.range_image import preprocess_range_image
from torchrefl.geometry.range_mesh import boundary_texels, crease_texels, grid_triangulation, texel_areas
from torchrefl.core.surface import Surface
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.core.threads import thread_map


@dataclass
class ScanGeometry:
    """What the range image gives: the Surface, the rig geometry, the tracer and the scan metadata."""

    surface: Surface
    rig: CylindricalRig
    tracer: RayTracer
    meta: dict
    folder: Path

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


def _need(doc: dict, key: str, where: str, kind=dict):
    if key not in doc:
        raise CaptureError(f"{where}: missing key '{key}'")
    value = doc[key]
    if kind is not None and not isinstance(value, kind):
        raise CaptureError(f"{where}: key '{key}' must be a {kind.__name__}, got {type(value).__name__}")
    return value


def _number(doc: dict, key: str, where: str, positive: bool = False) -> float:
    value = _need(doc, key, where, kind=None)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CaptureError(f"{where}: key '{key}' must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise CaptureError(f"{where}: key '{key}' must be > 0, got {value!r}")
    return float(value)


def _triple(value, key: str, where: str, positive: bool = False) -> list:
    ok = isinstance(value, list) and len(value) == 3 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)
    if not ok:
        raise CaptureError(f"{where}: key '{key}' must be a list of 3 finite numbers, got {value!r}")
    if positive and any(x <= 0 for x in value):
        raise CaptureError(f"{where}: key '{key}' must be 3 positive numbers (negative or zero light intensity?), got {value!r}")
    return [float(x) for x in value]


def read_scan_yaml(folder) -> dict:
    """Parse and check scan.yaml; returns the document with 'lights' resolved to a list."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: capture folder not found")
    path = folder / "scan.yaml"
    where = str(path)
    doc = read_yaml_mapping(path, CaptureError, "file (a cylindrical_scan capture needs scan.yaml)")
    kind = doc.get("kind", "cylindrical_scan")
    if kind != "cylindrical_scan":
        raise CaptureError(f"{where}: key 'kind' is '{kind}', expected 'cylindrical_scan'")
    grid = _need(doc, "grid", where)
    for key in ("angle_step_deg", "height_step_mm"):
        _number(grid, key, f"{where} [grid]", positive=True)
    for key in ("angle0_deg", "height0_mm"):
        _number(grid, key, f"{where} [grid]")
    cam = _need(doc, "camera", where)
    _number(cam, "distance_mm", f"{where} [camera]", positive=True)
    _number(cam, "height_mm", f"{where} [camera]")
    light = _need(doc, "light", where)
    light["intensity"] = _triple(_need(light, "intensity", f"{where} [light]", kind=None), "light.intensity", where, positive=True)
    light["kappa"] = _triple(light.get("kappa", [math.pi] * 3), "light.kappa", where, positive=True)
    lights = doc.get("lights", [])
    if isinstance(lights, str):
        lights = read_manifest(folder / lights)
    if not isinstance(lights, list):
        raise CaptureError(f"{where}: key 'lights' must be a list or the name of a manifest file")
    for i, entry in enumerate(lights):
        if not isinstance(entry, dict) or "image" not in entry or "position_mm" not in entry:
            raise CaptureError(f"{where}: lights[{i}] must have 'image' and 'position_mm' (got {entry!r})")
        entry["position_mm"] = _triple(entry["position_mm"], f"lights[{i}].position_mm", where)
        if "intensity" in entry:
            entry["intensity"] = _triple(entry["intensity"], f"lights[{i}].intensity", where, positive=True)
    doc["lights"] = lights
    return doc


def read_manifest(path: Path) -> list:
    """The rig's manifest.jsonl as a list of light entries (image, position_mm, ...)."""
    if not path.is_file():
        raise CaptureError(f"{path}: manifest file not found")
    entries = []
    for k, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError as exc:
            raise CaptureError(f"{path}: line {k} is not valid JSON ({exc.msg})") from None
    return entries


def read_range(folder: Path, doc: dict, rig_shape=None) -> np.ndarray:
    """(H, W) float64 range image in mm (NaN = no surface)."""
    spec = doc.get("range", {"file": "range.npy"})
    path = folder / spec.get("file", "range.npy")
    if not path.is_file():
        raise CaptureError(f"{path}: range image not found")
    try:
        r = np.load(path).astype(np.float64)
    except Exception as exc:  # numpy raises many kinds for corrupt files
        raise CaptureError(f"{path}: unreadable range image ({exc})") from None
    if r.ndim != 2:
        raise CaptureError(f"{path}: range image has shape {r.shape}, expected (H, W)")
    r = r * float(spec.get("scale_mm", 1.0)) + float(spec.get("offset_mm", 0.0))
    if np.isfinite(r).sum() == 0:
        raise CaptureError(f"{path}: range image has no valid (finite) pixel: the mask selects nothing")
    return r


def rig_from_yaml(doc: dict, shape) -> CylindricalRig:
    g, c = doc["grid"], doc["camera"]
    return CylindricalRig(
        rows=shape[0], columns=shape[1],
        angle0=math.radians(g["angle0_deg"]), angle_step=math.radians(g["angle_step_deg"]),
        height0=float(g["height0_mm"]), height_step=float(g["height_step_mm"]),
        camera_distance=float(c["distance_mm"]), camera_height=float(c["height_mm"]),
    )


def load_scan_geometry(folder, *, median_size: int = 5, fit_window: int = 5, noise_tolerance: float = 2.0, threads: int = 2,
                       dtype=torch.float32) -> ScanGeometry:
    """Range image -> Surface (points, normals, areas, mesh) and the rig geometry."""
    folder = Path(folder)
    doc = read_scan_yaml(folder)
    r = read_range(folder, doc)
    rig = rig_from_yaml(doc, r.shape)
    valid = np.isfinite(r)
    r_t = torch.from_numpy(np.where(valid, r, 0.0))
    geo = preprocess_range_image(
        r_t, torch.from_numpy(valid), s0=rig.angle0, ds=rig.angle_step, t0=rig.height0, dt=rig.height_step,
        median_size=median_size, window=fit_window, wrap=rig.covers_full_turn(), noise_tolerance=noise_tolerance,
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
        mesh_vertices=verts, mesh_faces=faces, units="mm", source=str(folder / "range.npy"),
    )
    tracer = RayTracer(verts, faces, threads=threads)
    return ScanGeometry(surface, rig, tracer, doc, folder)


def observation_geometry(geom: ScanGeometry, head_positions: np.ndarray, *, shadow_offset: float = 0.05,
                         min_cos_view: float = 0.0, min_cos_light: float = 0.0):
    """Light/view geometry of P head-frame lights for every texel, with Embree visibility.

    Returns dict with light_dir (P, T, 3), dist (P, T), view_dir (T, 3), cos_l (P, T), cos_v (T,),
    seen (T,) (camera sees the texel), lit (P, T) (n.l above threshold), shadowed (P, T).
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
        pl = point_light(x, n, light, geom.tracer, offset=shadow_offset, min_cos=min_cos_light, trace=seen)
        l_all[p], dist_all[p], cos_all[p], shadowed[p] = pl.direction, pl.distance, pl.cosine, pl.shadowed

    thread_map(one_light, range(P), geom.tracer.threads)
    return {"light_dir": l_all, "dist": dist_all, "view_dir": v, "cos_l": cos_all, "cos_v": cos_v,
            "seen": seen, "lit": cos_all > min_cos_light, "shadowed": shadowed}


def load_scan_observations(geom: ScanGeometry, *, light_subset=None, saturation_level: float = 0.995,
                           shadow_offset: float = 0.05, min_cos_view: float = 0.0, min_cos_light: float = 0.0,
                           threads: int = 2, dtype=torch.float32, edge_width: int = 0,
                           crease_angle_deg: float | None = None) -> tuple[Observations, dict]:
    """Texture images + light table -> Observations (and load statistics).

    edge_width: observations of texels within this many texels of the mesh boundary (silhouettes,
    depth discontinuities: mixed pixels) are not valid (counted in the statistics); crease_angle_deg:
    neither are those of texels on a crease sharper than this (range_mesh.crease_texels; None: none)."""
    doc = read_scan_yaml(geom.folder)
    lights = doc["lights"]
    where = str(geom.folder / "scan.yaml")
    if not lights:
        raise CaptureError(f"{where}: key 'lights' lists no light (expected one entry per texture image)")
    if light_subset is not None:
        bad = [i for i in light_subset if i >= len(lights)]
        if bad:
            raise CaptureError(f"capture.light_subset: indices {bad} out of range for {len(lights)} lights in {where}")
        lights = [lights[i] for i in light_subset]
    paths = [geom.folder / e["image"] for e in lights]
    images, bits = read_images(paths, threads=threads)
    H, W = geom.surface.grid_shape
    if images.shape[1:3] != (H, W):
        raise CaptureError(
            f"{paths[0]}: texture is {images.shape[2]}x{images.shape[1]}, expected {W}x{H} like the range image "
            f"{geom.folder / 'range.npy'}")
    head = np.array([e["position_mm"] for e in lights], dtype=np.float64)
    og = observation_geometry(geom, head, shadow_offset=shadow_offset,
                              min_cos_view=min_cos_view, min_cos_light=min_cos_light)
    idx = geom.surface.texel_index.numpy()
    intensity = images.reshape(len(lights), H * W, 3)[:, idx]
    saturated = (intensity >= saturation_level).any(-1)
    finite = np.isfinite(intensity).all(-1)
    valid = og["seen"][None] & og["lit"] & ~og["shadowed"] & ~saturated & finite
    edge = boundary_texels(geom.surface.mesh_faces, (H, W), idx, edge_width)
    valid &= ~edge[None]
    crease = crease_texels(geom.surface.mesh_vertices, geom.surface.mesh_faces, geom.surface.normals.double().numpy(),
                           idx, crease_angle_deg)
    valid &= ~crease[None]
    Y = np.array([e.get("intensity", doc["light"]["intensity"]) for e in lights], dtype=np.float64)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(dtype)
    obs = Observations(
        intensity=t(intensity), valid=torch.from_numpy(valid), saturated=torch.from_numpy(saturated),
        shadowed=torch.from_numpy(og["shadowed"]), light_dir=t(og["light_dir"]),
        falloff=t(1.0 / np.maximum(og["dist"], 1e-9) ** 2), light_intensity=t(Y), view_dir=t(og["view_dir"]),
        kappa=t(np.array(doc["light"]["kappa"])), light_positions=t(head),
        light_names=[e["image"] for e in lights], source=where,
    )
    stats = {
        "bit_depth": bits,
        "lights": len(lights),
        "texels": int(idx.size),
        "saturated_observations": int((saturated & og["seen"][None] & og["lit"]).sum()),
        "shadowed_observations": int(og["shadowed"].sum()),
        "valid_observations": int(valid.sum()),
        "edge_texels_excluded": int(edge.sum()),
        "crease_texels_excluded": int((crease & ~edge).sum()),
    }
    return obs, stats


def load_truth(folder, surface: Surface) -> dict | None:
    """Ground truth per valid texel from truth.npz (synthetic captures), or None."""
    path = Path(folder) / "truth.npz"
    if not path.is_file():
        return None
    data = np.load(path)
    return {
        "pd": surface.from_grid(data["pd"]).double(),
        "ps": surface.from_grid(data["ps"]).double(),
        "sigma": surface.from_grid(data["sigma"]).double(),
        "brdf": str(data["brdf"]) if "brdf" in data else None,
        "minnaert_k": float(data["minnaert_k"]) if "minnaert_k" in data else 1.0,
    }


class CylindricalScanLoader(CaptureLoader):
    """capture.kind cylindrical_scan: scan.yaml, range.npy, textures/*.png (and truth.npz when synthetic)."""

    kind = "cylindrical_scan"

    def load_geometry(self, folder: Path, cfg: Config) -> ScanGeometry:
        """The range image's Surface and the rig geometry (what light selection needs before any texture)."""
        g = cfg.geometry
        return load_scan_geometry(folder, median_size=g.median_size, fit_window=g.fit_window,
                                  threads=cfg.threads, dtype=cfg.torch_dtype)

    def load(self, folder: Path, cfg: Config, log: Log, geometry: ScanGeometry | None = None) -> Capture:
        geom = geometry if geometry is not None else self.load_geometry(folder, cfg)
        s = geom.surface
        log(f"surface: {s.num_texels} texels on a {s.grid_shape} grid, {len(s.mesh_faces)} triangles")
        g = cfg.geometry
        obs, stats = load_scan_observations(
            geom, light_subset=cfg.capture.light_subset, saturation_level=cfg.capture.saturation_level,
            shadow_offset=g.shadow_offset_mm, threads=cfg.threads, dtype=cfg.torch_dtype,
            edge_width=g.edge_width, crease_angle_deg=g.crease_angle_deg)
        if stats["crease_texels_excluded"]:
            log(f"geometry: {stats['crease_texels_excluded']} texels on creases sharper than "
                f"{g.crease_angle_deg:g} deg (mixed pixels) are not fitted")
        return Capture(s, obs, stats, load_truth(folder, s), Path(folder))
