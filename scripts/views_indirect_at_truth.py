"""How far the photon level's indirect light is from a converged render, at the true maps of a synthetic mesh_views
capture, and how much Pd error each leaves.

For a run folder of a synthetic mesh_views config (its config.yaml and capture/ with truth.npz):

1. the converged indirect light of every observation: the renderer's path tracer (synthetic.path_tracer, true
   materials and exact normals) at each texel centre towards the image's camera, `--paths` paths per texel, twice
   with independent paths (their difference is the estimate's own noise);
2. the photon level's indirect light at the truth (every texel emitting its true Pd, Ps, sigma), split into its parts:
   the radiosity level's all-diffuse paths, the photons' irradiance and specular entries, the specular gather;
3. the capture's own indirect light: the observations minus the local level's direct light at the truth;
4. per-texel local fits started at the truth on the observations minus (1) and minus (2): the Pd error each leaves.

Rows per truth region: the converged indirect light (DN), each estimate over it (a ratio of sums over the fitted
observations) and its RMS difference per observation (DN).

    python scripts/views_indirect_at_truth.py outputs/mesh_views_concave --paths 2048
    python scripts/views_indirect_at_truth.py --tiny [RUN]   # the test's mode: a tiny bowl when no run is given

docs/results/mesh_views.md ("The emitters' cast shadows") has the bowl's numbers. Slow at full size: the converged
render is about 4 minutes per 2 048 paths on the bowl on 2 cores.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import loader_for
from torchrefl.config import load_config
from torchrefl.core.rays import RayTracer
from torchrefl.fit.pipeline import level_inputs
from torchrefl.synthetic.path_tracer import IndirectRenderer
from torchrefl.synthetic.uv_objects import make_views_object
from torchrefl.transport.levels.auto import named_level, prepare
from torchrefl.transport.photon_cache import PhotonCache, indirect_radiance, specular_per_unit_ps

sys.path.insert(0, str(Path(__file__).parent))
from photon_noise_at_truth import local_fit  # noqa: E402
from tiny_mode import ROOT, TINY_LEVELS, tiny_run  # noqa: E402

BOWL = ROOT / "configs" / "mesh_views_concave.yaml"
DN = 255.0


def surface_points(obj, surface) -> tuple[np.ndarray, np.ndarray]:
    """(points (T, 3), triangles (T,)) of the object's mesh under each texel centre: a short ray against the texel's
    normal from just above it (the texel centres lie on the mesh the loader read, the object's own)."""
    tracer = RayTracer(obj.mesh.vertices, obj.mesh.faces, threads=1)
    x, n = surface.positions.double().numpy(), surface.normals.double().numpy()
    lift = 0.3 * float(surface.areas.double().sqrt().median())
    hits = tracer.closest_hit(x + lift * n, -n)
    if not hits.hit.all():
        raise SystemExit(f"{int((~hits.hit).sum())} texel centres are not on the object's mesh: not its capture?")
    return x + (lift - hits.distance[:, None]) * n, hits.triangle


def converged_indirect(cfg, cap, paths: int, seed: int) -> torch.Tensor:
    """(P, T, 3) the path-traced indirect light (sensor value) of every observation whose texel faces its camera."""
    obj = make_views_object(cfg.views.object, seed=cfg.seed)
    points, tri = surface_points(obj, cap.surface)
    normals, mat = obj.mesh.normal(points, tri), obj.mesh.material(points, tri)
    obs = cap.obs
    view = obs.view_dirs_full().double().numpy()
    tracer = RayTracer(obj.mesh.vertices, obj.mesh.faces, threads=cfg.threads)
    cameras: dict[bytes, list[int]] = {}
    for p in range(obs.num_lights):  # images of one camera share its view directions and its paths
        cameras.setdefault(view[p].round(6).tobytes(), []).append(p)
    out = np.zeros((obs.num_lights, len(points), 3))
    lights = obs.light_positions.double().numpy()
    for c, images in enumerate(cameras.values()):
        v = view[images[0]]
        idx = np.flatnonzero(np.einsum("ti,ti->t", normals, v) > 0)
        renderer = IndirectRenderer(tracer, obj.mesh.normal, obj.mesh.material, cfg.reflectance.brdf, seed=seed + c)
        at = np.stack([np.broadcast_to(lights[p], (len(idx), 3)) for p in images])
        m = {k: a[idx] for k, a in mat.items()}
        values = renderer.render(points[idx], normals[idx], v[idx], m["pd"], m["ps"], m["sigma"], at, paths)
        for j, p in enumerate(images):
            out[p, idx] = values[j]
    scale = obs.kappa.double().numpy() * obs.light_intensity.double().numpy()[:, None, :]
    return torch.from_numpy(out * scale)


def level_light(level, kappa, truth) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The photon level's indirect light at the truth (P, T, 3) (photon_cache.indirect_radiance), and its parts."""
    pd, ps, sigma = truth
    cache = level.refresher.cache(pd.float(), ps.float(), sigma.float(), refresh=0).to(torch.float64)
    gathered = int(cache.stats.get("gather_entries", 0))
    E = int(cache.entry_obs.numel())
    diffuse = kappa * pd[None] / math.pi
    exact = cache.exact_irradiance if cache.exact_irradiance is not None else torch.zeros_like(cache.irradiance)

    def specular(part: slice) -> torch.Tensor:
        sub = PhotonCache(cache.brdf, cache.irradiance, *(x[part] for x in (cache.entry_obs, cache.entry_theta_h)),
                          cache.entry_weight[part])  # fmt: skip
        return ps[None] * specular_per_unit_ps(sub, kappa, sigma)

    return indirect_radiance(cache, kappa, pd, ps, sigma), {
        "radiosity (all-diffuse paths)": diffuse * exact,
        "photons: irradiance": diffuse * (cache.irradiance_at(pd) - exact),
        "photons: specular entries": specular(slice(0, E - gathered)),
        "specular gather": specular(slice(E - gathered, E)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", nargs="?", help="a run folder of a synthetic mesh_views config (config.yaml, capture/)")
    ap.add_argument("--paths", type=int, default=2048, help="converged render: paths per texel and observation")
    ap.add_argument("--tiny", action="store_true", help="tiny sizes (a tiny bowl is fitted first when no run is given)")
    args = ap.parse_args(argv)
    over = TINY_LEVELS if args.tiny else []
    if args.tiny and args.run is None:
        args.run = str(tiny_run(Path(tempfile.mkdtemp(prefix="views_indirect_")) / "run", BOWL, model="local"))
    if args.run is None:
        ap.error("give RUN, or --tiny")
    run = Path(args.run)
    base = ["capture.kind=mesh_views", f"capture.path={run / 'capture'}", "fit.model=photon", "output.progress=false"]
    cfg = load_config(run / "config.yaml", base + over)
    cap = loader_for("mesh_views").load(run / "capture", cfg, lambda m: None)
    if cap.truth is None:
        raise SystemExit(f"{run / 'capture'}: no truth.npz (a synthetic capture is needed)")
    truth = tuple(cap.truth[k].double() for k in ("pd", "ps", "sigma"))
    region = cap.truth["region"]
    paths = 16 if args.tiny else args.paths
    runs = [converged_indirect(cfg, cap, paths, seed) for seed in (1000, 2000)]
    converged = (runs[0] + runs[1]) / 2
    inputs, _ = level_inputs(cfg, cap, lambda m: None)
    keep = inputs.fit_mask
    level = named_level(inputs)
    prepare(level)
    level.refresher.emitter_source = level.radiosity.emitter_source = None  # every texel emits its truth
    kappa = inputs.obs.kappa.double()
    with torch.no_grad():
        photon, parts = level_light(level, kappa, truth)
        direct = inputs.local_predict()(*(x.float() for x in truth)).double()
    if not torch.allclose(sum(parts.values()), photon, rtol=1e-6, atol=1e-9):
        raise SystemExit("the photon level's parts do not sum to its indirect light: this script is out of date")
    captured = cap.obs.intensity.double() - direct
    noise = float(((runs[0] - runs[1]).mean(-1)[keep] / 2 * DN).pow(2).mean().sqrt())
    print(f"converged render: {paths} paths x 2 per observation, its own noise {noise:.3f} DN RMS")
    regions = [int(r) for r in torch.unique(region[keep.any(0)]) if r >= 0]
    print("indirect light | " + " | ".join(f"region {r}" for r in regions) + " | RMS vs converged (DN)")
    rows = [("converged (DN)", converged), ("photon level / converged", photon), ("capture / converged", captured)]
    rows += [(f"  {name} (DN)", x) for name, x in parts.items()]
    for name, est in rows:
        cells = []
        for r in regions:
            m = keep & (region == r)[None]
            total = est.mean(-1)[m].sum()
            ref = converged.mean(-1)[m].sum()
            if "DN" in name:
                cells.append(f"{float(total / m.sum() * DN):.2f}")
            else:
                cells.append(f"{float(total / ref):.4f}" if ref > 0 else "-")
        rms = float(((est - converged).mean(-1)[keep] * DN).pow(2).mean().sqrt()) if "/" in name else None
        print(f"{name} | " + " | ".join(cells) + (f" | {rms:.3f}" if rms is not None else " | -"))
    measured = keep.any(0)
    names = " | ".join(f"region {r}" for r in regions)
    print(f"local fits from the truth on the observations minus | pd_rmse | {names}")
    for name, ind in (("the converged indirect light", converged), ("the photon level's", photon)):
        err = local_fit(inputs, cap.obs.intensity.double() - ind, truth) - truth[0]
        rmse = lambda m: float(err[m].pow(2).mean().sqrt()) if m.any() else float("nan")  # noqa: E731
        cells = " | ".join(f"{rmse(measured & (region == r)):.4f}" for r in regions)
        print(f"{name} | {rmse(measured):.4f} | {cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
