"""Synthetic mesh_views scenes: a mesh object photographed by calibrated cameras under point lights, written as a
capture folder in the mesh_views format (docs/capture-formats.md):

    mesh.obj            v, vt (the atlas), vn (exact normals), f v/vt/vn; or mesh.ply without UVs; millimetres
    scene.yaml          units: mm
    cameras.json        {name: {width, height, fx, fy, cx, cy, k1, k2, p1, p2, k3, R, t}, ...}
    lights.json         {name: {position, intensity}, ...}
    images.json         {encoding: linear, saturation_level, kappa, images: [{file, camera, light, exposure}]}
    images/<camera>_<light>.png   16-bit linear RGB: round(65535 (kappa exposure L_o + noise)), clipped
    truth.npz           pd (S, S, 3), ps (S, S, 3), sigma (S, S), region (S, S) on the atlas (NaN / -1 in the
                        gutter), brdf

Objects (synthetic.uv_objects): `ellipsoid` (convex, non-uniform glossy papers, a mesh with UVs),
`ellipsoid_no_uv` (the same surface as mesh.ply without UVs: its truth lies on the atlas that xatlas makes of
it, as the loader makes it) and `bowl` (a deep concavity, rendered with path-traced interreflection). The
images come from synthetic.views_render.ViewsRenderer; cameras, lights and pairing from synthetic.views_layout.

The truth maps are written through one function of the texel centres' surface points (truth_maps: the object's
material at each point) on the atlas of the written mesh file as the loader makes it (truth_on_atlas: read back,
parametrised by xatlas at texture_size when it has no UVs, rasterised), so the loader's capture.texture_size must
equal the writer's texture_size.

The scene's settings are the config's `views` section (torchrefl.config.MeshViewsConfig).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
import yaml

from torchrefl.capture.images import write_png
from torchrefl.config import MeshViewsConfig
from torchrefl.errors import ConfigError
from torchrefl.geometry.atlas import rasterise_atlas
from torchrefl.geometry.atlas_parametrise import parametrise
from torchrefl.geometry.mesh_file import read_mesh
from torchrefl.synthetic.uv_objects import ViewsObject, make_views_object
from torchrefl.synthetic.views_layout import (
    ViewCamera,
    ViewImage,
    ViewLight,
    direction,
    pair_images,
    ring_cameras,
)
from torchrefl.synthetic.views_render import ViewsRenderer

# per object: camera ring elevations (deg) and light [azimuth, elevation] (deg) when the config leaves them null
_PRESETS = {
    "ellipsoid": ([-15.0, 30.0], [[30.0, 20.0], [150.0, -10.0], [270.0, 40.0]]),
    "ellipsoid_no_uv": ([-15.0, 30.0], [[30.0, 20.0], [150.0, -10.0], [270.0, 40.0]]),
    "bowl": ([35.0, 65.0], [[0.0, 60.0], [120.0, 75.0], [240.0, 50.0]]),
}


@dataclass
class MeshViewsScene:
    """What a folder shows: the object, its cameras, lights and images (pairings)."""

    object: ViewsObject
    cameras: list[ViewCamera]
    lights: list[ViewLight]
    images: list[ViewImage]


@dataclass
class WrittenCapture:
    """A written folder: its path, the mesh file's name, the scene, and the truth maps (S, S, ...) written."""

    folder: Path
    mesh_file: str
    scene: MeshViewsScene
    truth: dict


def build_scene(cfg: MeshViewsConfig, seed: int = 0) -> MeshViewsScene:
    """The object, the camera rings about its bounding box's centre, the lights and the pairing of cfg."""
    obj = make_views_object(cfg.object, seed)
    v = obj.mesh.vertices
    centre = (v.min(0) + v.max(0)) / 2.0
    rings, lights_deg = _PRESETS[cfg.object]
    rings = cfg.camera_elevations_deg if cfg.camera_elevations_deg is not None else rings
    lights_deg = cfg.lights_deg if cfg.lights_deg is not None else lights_deg
    cams = ring_cameras(
        centre, cfg.camera_distance_mm, rings, cfg.cameras_per_ring, cfg.width, cfg.height, cfg.focal_px
    )
    intensity = np.asarray(cfg.light_intensity, dtype=np.float64)
    if intensity.shape != (3,) or (intensity < 0).any():
        raise ConfigError(f"light_intensity is {cfg.light_intensity}, expected three values >= 0 (RGB)")
    lights = []
    for k, entry in enumerate(lights_deg):
        if len(entry) != 2:
            raise ConfigError(f"lights_deg[{k}] is {entry}, expected [azimuth, elevation] in degrees")
        pos = centre + cfg.light_distance_mm * direction(*entry)
        lights.append(ViewLight(f"L{k:02d}", pos, intensity.copy()))
    return MeshViewsScene(obj, cams, lights, pair_images(cams, lights, cfg.lights_per_view, cfg.exposures, centre))


# ---------------------------------------------------------------------------- the atlas and the truth


def truth_maps(obj: ViewsObject, positions: np.ndarray, faces: np.ndarray) -> dict:
    """The true material at texel centres: positions (T, 3) on the mesh, faces (T,) their triangles ->
    pd, ps (T, 3), sigma, region (T,)."""
    return obj.mesh.material(np.asarray(positions, dtype=np.float64), np.asarray(faces, dtype=np.int64))


def truth_on_atlas(obj: ViewsObject, mesh_file: Path, size: int) -> dict:
    """truth.npz's maps on the S x S atlas of the written mesh file, made as the loader makes it
    (geometry.mesh_file.read_mesh; geometry.atlas_parametrise.parametrise when the file has no UVs;
    geometry.atlas.rasterise_atlas): pd, ps (S, S, 3), sigma (S, S) (NaN in the gutter), region (S, S) (-1 there).
    The file keeps the object's face order, so the texels' faces index the object's own triangles."""
    mesh = read_mesh(mesh_file)
    if mesh.uvs is None:
        mesh = parametrise(mesh, size)
    texels = rasterise_atlas(mesh, size)
    positions = np.einsum("tk,tki->ti", texels.barycentric, mesh.vertices[mesh.faces[texels.face]])
    m = truth_maps(obj, positions, texels.face)
    S = int(size)
    out = {
        "pd": np.full((S * S, 3), np.nan),
        "ps": np.full((S * S, 3), np.nan),
        "sigma": np.full(S * S, np.nan),
        "region": np.full(S * S, -1, dtype=np.int64),
    }
    for key in out:
        out[key][texels.texel_index] = m[key]
    return {k: v.reshape((S, S) + v.shape[1:]) for k, v in out.items()}


# ---------------------------------------------------------------------------- files


def write_obj(path: Path, obj: ViewsObject) -> None:
    """mesh.obj: v, vt, vn and f v/vt/vn with one index per corner (seam vertices are duplicated in the mesh)."""
    v, vt, vn = obj.mesh.vertices, obj.uv, obj.vertex_normals
    f = obj.mesh.faces + 1
    lines = ["# torchrefl synthetic mesh_views object, millimetres"]
    lines += [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in v]
    lines += [f"vt {a:.9g} {b:.9g}" for a, b in vt]
    lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in vn]
    lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")


def write_mesh(folder: Path, obj: ViewsObject) -> str:
    """Write mesh.obj (with UVs) or mesh.ply (without); returns the file name."""
    if obj.uv is not None:
        write_obj(folder / "mesh.obj", obj)
        return "mesh.obj"
    mesh = trimesh.Trimesh(obj.mesh.vertices, obj.mesh.faces, vertex_normals=obj.vertex_normals, process=False)
    mesh.export(folder / "mesh.ply")
    return "mesh.ply"


def _write_json(path: Path, doc: dict) -> None:
    path.write_text(json.dumps(doc, indent=2) + "\n")


def write_geometry(folder, scene: MeshViewsScene) -> str:
    """Write what a folder holds before any photograph: the mesh (write_mesh), scene.yaml and cameras.json;
    returns the mesh file's name (a light plan needs no more: torchrefl.plan)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    mesh_file = write_mesh(folder, scene.object)
    (folder / "scene.yaml").write_text(yaml.safe_dump({"units": "mm"}))
    _write_json(folder / "cameras.json", {c.name: c.to_json() for c in scene.cameras})
    return mesh_file


def write_capture(
    folder,
    cfg: MeshViewsConfig,
    *,
    texture_size: int,
    seed: int = 0,
    kappa=(np.pi,) * 3,
    saturation_level: float = 0.995,
    threads: int = 2,
    progress=None,
) -> WrittenCapture:
    """Build cfg's scene (build_scene), render it and write it as a mesh_views folder (write_scene) with its truth
    on a texture_size^2 atlas (the loader's capture.texture_size)."""
    if texture_size % 16:
        raise ConfigError(
            f"texture_size is {texture_size}, expected a multiple of 16 (material borders on texel edges)"
        )
    renderer = dict(
        brdf=cfg.brdf,
        kappa=kappa,
        supersample=cfg.supersample,
        indirect_samples=cfg.indirect_samples,
        noise_dn=cfg.noise_dn,
        seed=seed,
        threads=threads,
    )
    scene = build_scene(cfg, seed)
    return write_scene(folder, scene, ViewsRenderer(scene.object, **renderer), texture_size, saturation_level, progress)


def write_scene(
    folder,
    scene: MeshViewsScene,
    renderer: ViewsRenderer,
    texture_size: int,
    saturation_level: float = 0.995,
    progress=None,
) -> WrittenCapture:
    """Write `scene` as a mesh_views folder (module doc), its images rendered by `renderer` (whose object is the
    scene's), its truth on a texture_size^2 atlas; progress: called with (done, total) images."""
    folder = Path(folder)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    mesh_file = write_geometry(folder, scene)
    _write_json(folder / "lights.json", {light.name: light.to_json() for light in scene.lights})
    lights = {light.name: light for light in scene.lights}
    done = 0
    for k, cam in enumerate(scene.cameras):
        mine = [i for i, im in enumerate(scene.images) if im.camera == cam.name]
        if not mine:
            continue
        view = renderer.radiance(cam, [lights[scene.images[i].light] for i in mine], camera_index=k)
        covered = view.covered.reshape(cam.height, cam.width)
        for j, i in enumerate(mine):
            values = view.values[j].reshape(cam.height, cam.width, 3)
            image = renderer.sensor(values, covered, scene.images[i].exposure, i)
            write_png(folder / scene.images[i].file, image, bits=16)
            done += 1
            if progress is not None:
                progress(done, len(scene.images))
    _write_json(
        folder / "images.json",
        {
            "encoding": "linear",
            "saturation_level": float(saturation_level),
            "kappa": [float(k) for k in renderer.kappa],
            "images": [im.to_json() for im in scene.images],
        },
    )
    truth = truth_on_atlas(scene.object, folder / mesh_file, texture_size)
    np.savez(folder / "truth.npz", **truth, brdf=renderer.brdf)
    return WrittenCapture(folder, mesh_file, scene, truth)
