"""Synthetic objects scanned by the seed's cylindrical rig, with known ground truth.

The object is scanned the way the rangefinder does it: one ray per texel along the
scanner's line of sight (horizontal, towards the rotation axis). Texture images are
rendered at a finer level than the fitter uses: `supersample^2` sub-samples per texel
with exact (analytic) surface points and normals, cast shadows from Embree, then
sensor noise, clipping at full scale and 8-bit quantisation. The fitter instead sees
the (optionally quantised, noisy) range image, median-filtered and quadratic-fitted,
so tests do not just invert their own forward model.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import torch
import trimesh
import yaml

from torchrefl import brdf as brdf_mod
from torchrefl.capture.cylindrical_rig import CylindricalRig, light_grid_positions
from torchrefl.capture.images import write_png
from torchrefl.capture.synthetic_materials import region_materials
from torchrefl.config import LightGridConfig, SyntheticConfig
from torchrefl.errors import GeometryError
from torchrefl.rays import RayTracer


class SyntheticScan:
    """A synthetic ellipsoid (or sphere) on the cylindrical rig with ground-truth maps."""

    def __init__(self, cfg: SyntheticConfig, grid: LightGridConfig | None = None, seed: int = 0,
                 kappa=(math.pi,) * 3, threads: int = 2):
        self.cfg = cfg
        self.grid = grid or LightGridConfig()
        self.seed = seed
        self.kappa = np.asarray(kappa, dtype=np.float64)
        self.threads = threads
        a, b, c = cfg.size_mm if cfg.object == "ellipsoid" else [cfg.size_mm[0]] * 3
        self.axes = np.array([a, b, c], dtype=np.float64)
        height = cfg.rows * cfg.height_step_mm
        self.rig = CylindricalRig(
            rows=cfg.rows, columns=cfg.columns,
            angle0=0.0, angle_step=math.radians(cfg.angle_step_deg),
            height0=-height / 2.0 + cfg.height_step_mm / 2.0, height_step=cfg.height_step_mm,
            camera_distance=cfg.camera_distance_mm, camera_height=cfg.camera_height_mm,
        )
        if self.axes[1] >= height / 2.0:
            raise GeometryError(
                f"synthetic.size_mm: object half-height {self.axes[1]} mm does not fit the scan height "
                f"{height:.1f} mm (synthetic.rows x synthetic.height_step_mm)")
        mesh = trimesh.creation.icosphere(subdivisions=cfg.mesh_subdivisions)
        mesh.apply_scale(self.axes)
        self.mesh = mesh
        self.tracer = RayTracer(mesh.vertices, mesh.faces, threads=threads)
        self.truth = region_materials(cfg.rows, cfg.columns, seed=seed, uniform=cfg.materials == "uniform")
        self._samples = None

    # ------------------------------------------------------------------ geometry

    def _ray_ellipsoid(self, origins: np.ndarray, dirs: np.ndarray):
        """Exact first intersection of rays with the ellipsoid: points (N,3), normals (N,3), hit (N,)."""
        o = origins / self.axes
        d = dirs / self.axes
        A = (d * d).sum(-1)
        B = 2 * (o * d).sum(-1)
        C = (o * o).sum(-1) - 1
        disc = B * B - 4 * A * C
        hit = disc > 0
        t = (-B - np.sqrt(np.where(hit, disc, 0))) / (2 * A)
        hit &= t > 0
        p = origins + t[:, None] * dirs
        n = p / (self.axes ** 2)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        return p, n, hit

    def _scan_rays(self, s: np.ndarray, t: np.ndarray):
        """Rays along the scanner's lines of sight for angles s (N,) and heights t (N,)."""
        far = 4.0 * float(self.axes.max()) + 10.0
        u, _ = CylindricalRig.head_axes(s)
        origins = far * u
        origins[:, 1] = -t
        return origins, -u

    def range_image(self) -> np.ndarray:
        """(H, W) float64 range r(s, t) in mm, NaN where the scanner ray misses.

        The hit is found by Embree on the object mesh and refined onto the exact surface;
        range noise and quantisation follow the config.
        """
        cfg = self.cfg
        S, T = np.meshgrid(self.rig.angles(), self.rig.heights())
        o, d = self._scan_rays(S.ravel(), T.ravel())
        hits = self.tracer.closest_hit(o, d)
        p, _, exact_hit = self._ray_ellipsoid(o, d)
        hit = hits.hit & exact_hit
        r = np.where(hit, np.hypot(p[:, 0], p[:, 2]), np.nan).reshape(S.shape)
        rng = np.random.default_rng([self.seed, 1])
        if cfg.range_noise_mm > 0:
            r = r + rng.normal(0.0, cfg.range_noise_mm, size=r.shape)
        if cfg.range_bits:
            lo, hi = np.nanmin(r), np.nanmax(r)
            levels = 2 ** cfg.range_bits - 1
            step = (hi - lo) / levels
            r = lo + np.round((r - lo) / step) * step
        return r

    def _subsamples(self) -> dict:
        """Cached visible sub-samples (N of them): points, normals, unit view vectors (N, 3) float64,
        head axes u, w (N, 3) float32, texel (N,) flat texel index, count (H*W,) sub-samples per texel."""
        if self._samples is not None:
            return self._samples
        k = self.cfg.supersample
        offs = (np.arange(k) + 0.5) / k - 0.5
        du, dv = np.meshgrid(offs, offs)
        du, dv = du.ravel(), dv.ravel()
        s = self.rig.angles()[:, None] + du[None, :] * self.rig.angle_step          # (W, S)
        t = self.rig.heights()[:, None] + dv[None, :] * self.rig.height_step         # (H, S)
        H, W, Sn = self.rig.rows, self.rig.columns, du.size
        S_full = np.broadcast_to(s[None], (H, W, Sn)).ravel()
        T_full = np.broadcast_to(t[:, None, :], (H, W, Sn)).ravel()
        o, d = self._scan_rays(S_full, T_full)
        p, n, hit = self._ray_ellipsoid(o, d)
        cam = self.rig.camera_positions(S_full)
        seen = hit & ((n * (cam - p)).sum(-1) > 0)
        idx = np.flatnonzero(seen)
        vis = np.zeros_like(seen)
        if idx.size:
            vis[idx] = self.tracer.visible(p[idx], n[idx], cam[idx], offset=0.01)
        keep = np.flatnonzero(seen & vis)
        texel = keep // Sn
        v = cam[keep] - p[keep]
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        u, w = CylindricalRig.head_axes(S_full[keep])
        self._samples = {
            "points": p[keep], "normals": n[keep], "view": v, "texel": texel,
            "u": u.astype(np.float32), "w": w.astype(np.float32),
            "count": np.bincount(texel, minlength=H * W),
        }
        return self._samples

    def candidate_positions(self) -> np.ndarray:
        """(P, 3) head-frame candidate light positions [lateral, vertical, radial] of the light grid."""
        g = self.grid
        return light_grid_positions(g.columns, g.rows, g.spacing_mm, g.radial_mm, g.center_lateral_mm, g.center_vertical_mm)

    # ------------------------------------------------------------------ rendering

    def radiance_image(self, head_position) -> np.ndarray:
        """(H, W, 3) float64 noiseless sensor value (fraction of full range) for a light at head_position:
        the mean over each texel's visible sub-samples of kappa * Y / C^2 * f * cos, with Embree shadows."""
        cfg = self.cfg
        smp = self._subsamples()
        H, W = self.rig.rows, self.rig.columns
        lat, vert, rad = (float(c) for c in np.asarray(head_position, dtype=np.float64))
        light = rad * smp["u"].astype(np.float64) + lat * smp["w"].astype(np.float64)
        light[:, 1] += vert
        p, n = smp["points"], smp["normals"]
        to_light = light - p
        dist = np.sqrt(np.einsum("ni,ni->n", to_light, to_light))
        l = to_light / np.maximum(dist, 1e-12)[:, None]
        lit = np.einsum("ni,ni->n", n, l) > 0
        idx = np.flatnonzero(lit)
        if idx.size:
            lit[idx] = self.tracer.visible(p[idx], n[idx], light[idx], offset=0.01)
        idx = np.flatnonzero(lit)
        img = np.zeros((H * W, 3))
        if idx.size:
            tex = smp["texel"][idx]
            tt = lambda x: torch.from_numpy(np.ascontiguousarray(x))
            flat = lambda key: self.truth[key].reshape((H * W,) + self.truth[key].shape[2:])[tex]
            with torch.no_grad():
                g = brdf_mod.cosine_weighted_brdf(cfg.brdf, tt(n[idx]), tt(l[idx]), tt(smp["view"][idx]),
                                                  tt(flat("pd")), tt(flat("ps")), tt(flat("sigma"))).numpy()
            value = self.kappa * cfg.light_intensity * g / (dist[idx, None] ** 2)
            for c in range(3):
                img[:, c] = np.bincount(tex, weights=value[:, c], minlength=H * W)
        count = smp["count"]
        img /= np.maximum(count, 1)[:, None]
        return img.reshape(H, W, 3)

    def render_texture(self, head_position) -> np.ndarray:
        """(H, W, 3) uint8 (or uint16) texture image for a light at head_position, with noise."""
        cfg = self.cfg
        img = self.radiance_image(head_position)
        head = np.asarray(head_position, dtype=np.float64)
        key = int.from_bytes(hashlib.sha256(np.round(head, 6).tobytes()).digest()[:8], "little")
        rng = np.random.default_rng([self.seed, key])
        levels = 2 ** cfg.texture_bits - 1
        noisy = img * levels + rng.normal(0.0, cfg.noise_dn * levels / 255.0, size=img.shape)
        q = np.clip(np.round(noisy), 0, levels)
        return q.astype(np.uint8 if cfg.texture_bits == 8 else np.uint16)

    # ------------------------------------------------------------------ files

    def scan_yaml(self, lights: list | str | None = None) -> dict:
        doc = {"kind": "cylindrical_scan"}
        doc.update(self.rig.to_yaml_dict())
        doc["light"] = {"intensity": [float(self.cfg.light_intensity)] * 3, "kappa": [float(k) for k in self.kappa]}
        doc["saturation_level"] = 0.995
        doc["range"] = {"file": "range.npy"}
        doc["truth"] = {"file": "truth.npz", "brdf": self.cfg.brdf}
        doc["lights"] = lights if lights is not None else []
        return doc

    def write_geometry(self, folder) -> Path:
        """Write scan.yaml (no lights yet), range.npy and truth.npz into `folder`."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        np.save(folder / "range.npy", self.range_image().astype(np.float32))
        np.savez(folder / "truth.npz", pd=self.truth["pd"], ps=self.truth["ps"], sigma=self.truth["sigma"],
                 region=self.truth["region"], brdf=self.cfg.brdf)
        (folder / "scan.yaml").write_text(yaml.safe_dump(self.scan_yaml(), sort_keys=False))
        return folder

    def write_textures(self, folder, head_positions, progress=None) -> list:
        """Render one texture per head position into folder/textures and list them in scan.yaml."""
        folder = Path(folder)
        (folder / "textures").mkdir(parents=True, exist_ok=True)
        lights = []
        positions = np.asarray(head_positions, dtype=np.float64).reshape(-1, 3)
        for i, pos in enumerate(positions):
            name = f"textures/{i:03d}.png"
            write_png(folder / name, self.render_texture(pos), bits=self.cfg.texture_bits)
            lights.append({"image": name, "position_mm": [float(x) for x in pos]})
            if progress is not None:
                progress.update(1)
        doc = yaml.safe_load((folder / "scan.yaml").read_text())
        doc["lights"] = lights
        (folder / "scan.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        return lights
