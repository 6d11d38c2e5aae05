"""Held-out photographs reproduced by relighting (torchrefl.report.relight), against the fit's own held-out error.

    python scripts/relight_holdout.py RUN_DIR [RUN_DIR ...]
    python scripts/relight_holdout.py --tiny      # a tiny mesh_views fit with a held-out image (the test's mode)

For each run (its config's fit.holdout lights):
- photometric stereo (the DiLiGenT ball): each held-out light rendered through the photographs' orthographic camera
  (directional light, the capture's intensity) and compared with the loader's pixel values at the observations the
  fit judged its held-out error on (Observations.valid: seen, lit, unsaturated);
- mesh_views: each held-out image rendered from its own camera under its own point light, with cast shadows (2 x 2
  rays per pixel), times the image's exposure, compared with the photograph at the pixels wholly on estimated
  surface (the pixel and its 4 neighbours covered: silhouettes left out, as the loader leaves them out) and not
  saturated; bilinear over the texels (relight's default) and with each hit's nearest texel (the fit's one
  reflectance per texel: a material border stays where the texel's is); with the interreflection of a radiosity or
  photon run's level (relight's default) and, for those runs, without it; also without shadows, to show what the
  shadow rays buy, and as 3 x 3 pixel means of both images (the photograph's per-pixel sensor noise, which the fit's
  footprint-averaged observations largely average out, divided by 3); and the way the fit measures its held-out
  error: both images sampled by the loader's own texel footprints (the relit image passed through
  capture.mesh_views.load_views_observations in the photograph's place).
Prints the mean |relit - photo| in 8-bit DN beside metrics.json's holdout mean_abs_diff_8bit, and the ratio.
"""

from __future__ import annotations

import copy
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import uniform_filter

from torchrefl.capture.base import loader_for
from torchrefl.capture.mesh_views import MeshViewsLoader, load_views_observations
from torchrefl.capture.view_folder import read_view_folder
from torchrefl.config import load_config
from torchrefl.core.rays import RayTracer
from torchrefl.report.relight import Light, photographs_camera
from torchrefl.report.relight_camera import one_camera
from torchrefl.report.relight_indirect import INTERREFLECTION_LEVELS, run_level
from torchrefl.report.run_result import load_run
from torchrefl.transport.local import local_terms

sys.path.insert(0, str(Path(__file__).parent))
from tiny_mode import ROOT, tiny_run  # noqa: E402


def photometric_stereo(run, cfg) -> dict:
    cap = loader_for(cfg.capture.kind).load(Path(cfg.capture.path), cfg, lambda m: None)
    obs, idx = cap.obs, cap.surface.texel_index.numpy()
    est = run.mask.reshape(-1)[idx]
    diffs = []
    for p in cfg.fit.holdout:
        light = Light(obs.light_intensity[p].double().numpy(), direction=obs.light_dir[p, 0].double().numpy())
        relit = run.render(camera=photographs_camera(run), light=light).image.reshape(-1, 3)[idx]
        use = obs.valid[p].numpy() & est
        diffs.append(np.abs(relit[use] - obs.intensity[p].double().numpy()[use]).ravel() * 255)
    return {"relit": float(np.concatenate(diffs).mean())}


def inner(covered: np.ndarray) -> np.ndarray:
    """Pixels whose 4 neighbours are covered too."""
    out = covered.copy()
    out[1:-1, 1:-1] &= covered[:-2, 1:-1] & covered[2:, 1:-1] & covered[1:-1, :-2] & covered[1:-1, 2:]
    out[[0, -1]] = False
    out[:, [0, -1]] = False
    return out


def mesh_views(run, cfg) -> dict:
    folder = Path(cfg.capture.path) if cfg.capture.path else run.folder / "capture"
    meta = read_view_folder(folder)
    saturation = meta.views.saturation_level or cfg.capture.saturation_level
    # (key, shadows, interreflection, interpolation)
    variants = [("relit", True, None, "bilinear"), ("relit_nearest", True, None, "nearest")]
    variants.append(("relit_no_shadows", False, None, "bilinear"))
    if run_level(run) in INTERREFLECTION_LEVELS:
        variants.append(("relit_no_interreflection", True, False, "bilinear"))
    out = {key: [] for key, *_ in variants}
    relit = {"relit": {}, "relit_nearest": {}}
    for i in cfg.fit.holdout:
        cam = one_camera(meta.cameras, int(meta.camera_index[i]))
        k = int(meta.light_index[i])
        lights = meta.lights
        light = Light(lights.intensity[k], position=lights.position[k]) if lights.point[k] else None
        light = light or Light(lights.intensity[k], direction=lights.direction[k])
        photo = meta.read_image(i).astype(np.float64)
        exposure = meta.views.images[i].exposure
        for key, shadows, interreflection, interpolation in variants:
            im = run.render(
                camera=cam,
                light=light,
                supersample=2,
                shadows=shadows,
                interreflection=interreflection,
                interpolation=interpolation,
            )
            use = inner(im.covered) & im.estimated & (photo < saturation).all(-1)
            out[key].append(np.abs(im.image[use] * exposure - photo[use]).ravel() * 255)
            if key in relit:
                relit[key][i] = (np.asarray(im.image * exposure, np.float32), im.filled & im.estimated)
            if key == "relit":  # 3 x 3 means of both images where all 9 pixels are used: the sensor noise / 3
                box = lambda a: uniform_filter(a, size=(3, 3, 1), mode="constant")
                whole = uniform_filter(use.astype(float), size=3, mode="constant") > 1 - 1e-9
                diff = box(im.image * exposure) - box(photo)
                out.setdefault("relit_3x3_means", []).append(np.abs(diff[whole]).ravel() * 255)
    result = {key: float(np.concatenate(v).mean()) for key, v in out.items() if v}
    for key, images in relit.items():
        result[f"{key}_texel_footprints"] = footprint_error(run, cfg, folder, images)
    return result


def footprint_error(run, cfg, folder: Path, relit: dict) -> float:
    """The mean |relit - photograph| (8-bit DN) of the held-out images' texel observations, both sampled by the
    loader's own texel footprints (capture.mesh_views.load_views_observations: the same texels, the same pixels,
    as the fit's held-out error is measured): relit {image: (image (H, W, 3) at its exposure, pixels wholly on
    estimated surface (H, W))}. Compared at the observations valid in both (seen, lit, unsaturated, the relit
    footprint on estimated pixels), with the fit's grazing-angle limits, on estimated texels."""
    meta, geom = MeshViewsLoader().load_geometry(folder, cfg)
    tracer = RayTracer(geom.mesh.vertices, geom.mesh.faces, threads=cfg.threads)
    holdout = list(cfg.fit.holdout)
    sub = copy.deepcopy(cfg)
    sub.capture.light_subset = holdout
    photo = load_views_observations(meta, geom, tracer, sub, lambda m: None)[0]
    rendered = copy.copy(meta)  # the photographs' folder reading the relit images (a frozen dataclass)
    object.__setattr__(rendered, "read_image", lambda i: relit[i][0])
    object.__setattr__(rendered, "read_mask", lambda i: relit[i][1])
    image = load_views_observations(rendered, geom, tracer, sub, lambda m: None)[0]
    terms = local_terms(cfg.reflectance.brdf, geom.surface.normals, photo)
    rc = cfg.reflectance
    estimated = torch.from_numpy(run.mask.reshape(-1)[geom.surface.texel_index.numpy()])
    fitted_way = photo.valid & (terms.cos_v > rc.min_cos_view) & (terms.cos_l > rc.min_cos_light) & estimated
    use = fitted_way & image.valid
    diff = (image.intensity.double() - photo.intensity.double()).abs()[use]
    print(f"  texel footprints: {int(use.sum())} observations compared of the photographs' {int(fitted_way.sum())}")
    return float(diff.mean() * 255)


def main(argv) -> int:
    if argv == ["--tiny"]:
        folder = Path(tempfile.mkdtemp(prefix="relight_holdout_")) / "run"
        argv = [str(tiny_run(folder, ROOT / "configs" / "mesh_views.yaml", "local"))]
    for folder in argv:
        run = load_run(folder)
        cfg = load_config(str(Path(folder) / "config.yaml"))
        kind = (
            run.metrics["capture"].get("kind", cfg.capture.kind) if isinstance(run.metrics.get("capture"), dict) else ""
        )
        result = photometric_stereo(run, cfg) if run.units == "px" else mesh_views(run, cfg)
        fit = run.metrics["holdout"]["mean_abs_diff_8bit"]
        line = ", ".join(f"{k} {v:.3f} DN ({v / fit:.2f}x)" for k, v in result.items())
        print(f"{Path(folder).name} ({kind}): fit's held-out error {fit:.3f} DN; {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
