"""Synthetic objects scanned by the seed's cylindrical rig, with known ground truth.

The object is scanned the way the rangefinder does it: one ray per texel along the
scanner's line of sight (horizontal, towards the rotation axis). Texture images are
rendered at a finer level than the fitter uses: `supersample^2` sub-samples per texel
with exact (analytic) surface points and normals, cast shadows from Embree, then
sensor noise, clipping at full scale and 8-bit quantisation. The fitter instead sees
the (optionally quantised, noisy) range image, median-filtered and quadratic-fitted,
so tests do not just invert their own forward model.

Objects: the analytic ellipsoid / sphere (texel-aligned region materials), or a mesh object of
synthetic.objects (Object E setups 1 and 2, a bowl), whose scanner hits come from Embree on the
object's mesh, normals from its exact geometry, and materials from functions of the surface
point (truth.npz holds them at the texel centres' scanner hits; sub-samples are rendered with
their texel's truth so every texel has one true value). A texel is scanned only where the
scanner's ray hits the object in front of the rotation axis; elsewhere range.npy is NaN.

With synthetic.indirect_samples > 0 the textures also carry interreflection, path traced with
Embree (synthetic.path_tracer.IndirectRenderer: BRDF/lobe sampling, next-event estimation with the true
material at every path vertex, Russian roulette); 0 renders direct light only, exactly as before.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import torch
import trimesh
import yaml

from torchrefl.capture.cylindrical_rig import CylindricalRig, light_grid_positions
from torchrefl.capture.images import write_png
from torchrefl.config import LightGridConfig, SyntheticConfig
from torchrefl.core import brdf as brdf_mod
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.errors import GeometryError
from torchrefl.synthetic.materials import region_materials
from torchrefl.synthetic.objects import MESH_OBJECTS, MeshObject, make_object
from torchrefl.synthetic.path_tracer import IndirectRenderer


class SyntheticScan:
    """A synthetic ellipsoid, sphere or mesh object (synthetic.objects) on the cylindrical rig with
    ground-truth maps."""

    def __init__(
        self,
        cfg: SyntheticConfig,
        grid: LightGridConfig | None = None,
        seed: int = 0,
        kappa=(math.pi,) * 3,
        threads: int = 2,
        obj: MeshObject | None = None,
    ):
        """obj: a mesh object to scan instead of cfg.object (e.g. a mesh_views object, synthetic.uv_objects, to
        capture one physical object both ways)."""
        self.cfg = cfg
        self.grid = grid or LightGridConfig()
        self.seed = seed
        self.path_seed = seed  # the interreflection paths' random numbers (a second render of a scene: another seed)
        self.kappa = np.asarray(kappa, dtype=np.float64)
        self.threads = threads
        self.saturation_level = 0.995  # written to scan.yaml (synthetic runs: capture.saturation_level)
        self.object = obj or (make_object(cfg.object, seed, cfg.materials) if cfg.object in MESH_OBJECTS else None)
        if self.object is None:
            a, b, c = cfg.size_mm if cfg.object == "ellipsoid" else [cfg.size_mm[0]] * 3
        else:  # half extents of the mesh about the axis origin: they set the scanner's start distance
            a, b, c = np.abs(self.object.vertices).max(0)
        self.axes = np.array([a, b, c], dtype=np.float64)
        height = cfg.rows * cfg.height_step_mm
        self.rig = CylindricalRig(
            rows=cfg.rows,
            columns=cfg.columns,
            angle0=0.0,
            angle_step=math.radians(cfg.angle_step_deg),
            height0=-height / 2.0 + cfg.height_step_mm / 2.0,
            height_step=cfg.height_step_mm,
            camera_distance=cfg.camera_distance_mm,
            camera_height=0.0,
        )
        if self.object is not None:
            lo, hi = self.object.extent_y
            if max(-lo, hi) >= height / 2.0:
                raise GeometryError(
                    f"synthetic.object: {cfg.object} spans heights {lo:.1f}..{hi:.1f} mm, outside the scan height "
                    f"+-{height / 2:.1f} mm (synthetic.rows x synthetic.height_step_mm)"
                )
            self.mesh = trimesh.Trimesh(self.object.vertices, self.object.faces, process=False)
            self.tracer = RayTracer(self.object.vertices, self.object.faces, threads=threads)
            # objects without a material function (the vase) carry the texel-aligned region maps of the scan grid
            self._maps = (
                None
                if self.object.material is not None
                else region_materials(cfg.rows, cfg.columns, seed=seed, uniform=cfg.materials == "uniform")
            )
            self.truth = self._mesh_truth()
            self._samples = None
            self._gi = None
            return
        if self.axes[1] >= height / 2.0:
            raise GeometryError(
                f"synthetic.size_mm: object half-height {self.axes[1]} mm does not fit the scan height "
                f"{height:.1f} mm (synthetic.rows x synthetic.height_step_mm)"
            )
        mesh = trimesh.creation.icosphere(subdivisions=cfg.mesh_subdivisions)
        mesh.apply_scale(self.axes)
        self.mesh = mesh
        self.tracer = RayTracer(mesh.vertices, mesh.faces, threads=threads)
        self._maps = self.truth = region_materials(cfg.rows, cfg.columns, seed=seed, uniform=cfg.materials == "uniform")
        self._samples = None
        self._gi = None

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
        n = p / (self.axes**2)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        return p, n, hit

    def _scan_rays(self, s: np.ndarray, t: np.ndarray):
        """Rays along the scanner's lines of sight for angles s (N,) and heights t (N,)."""
        far = 4.0 * float(self.axes.max()) + 10.0
        u, _ = CylindricalRig.head_axes(s)
        origins = far * u
        origins[:, 1] = -t
        return origins, -u

    def _mesh_scan(self, origins: np.ndarray, dirs: np.ndarray):
        """Scanner rays against the mesh object: points (N,3), normals (N,3) (exact geometry), signed range
        rho (N,) from the axis along the ray, triangles (N,), hit (N,) (hit in front of the axis only: a
        point beyond the axis belongs to the opposite scan angle and is seen there, or not at all)."""
        hits = self.tracer.closest_hit(origins, dirs)
        far = np.linalg.norm(origins[:, [0, 2]], axis=-1)
        rho = np.where(hits.hit, far - hits.distance, -np.inf)
        hit = hits.hit & (rho > 1e-6)
        p = origins + np.where(hit, hits.distance, 0.0)[:, None] * dirs
        n = np.zeros_like(p)
        idx = np.flatnonzero(hit)
        if idx.size:
            n[idx] = self.object.normal(p[idx], hits.triangle[idx])
        return p, n, rho, hits.triangle, hit

    def _mesh_truth(self) -> dict:
        """Texel maps of the mesh object's materials at the texel centres' scanner hits (zeros, region -1,
        sigma 0.1 where the centre ray misses)."""
        H, W = self.rig.rows, self.rig.columns
        S, T = np.meshgrid(self.rig.angles(), self.rig.heights())
        o, d = self._scan_rays(S.ravel(), T.ravel())
        p, _, _, tri, hit = self._mesh_scan(o, d)
        pd = np.zeros((H * W, 3))
        ps = np.zeros((H * W, 3))
        sigma = np.full(H * W, 0.1)
        region = np.full(H * W, -1, dtype=np.int64)
        idx = np.flatnonzero(hit)
        if idx.size:
            m = self._material_at(p[idx], tri[idx])
            pd[idx], ps[idx], sigma[idx], region[idx] = m["pd"], m["ps"], m["sigma"], m["region"]
        return {
            "pd": pd.reshape(H, W, 3),
            "ps": ps.reshape(H, W, 3),
            "sigma": sigma.reshape(H, W),
            "region": region.reshape(H, W),
            "texel_hit": hit.reshape(H, W),
        }

    def range_image(self) -> np.ndarray:
        """(H, W) float64 range r(s, t) in mm, NaN where the scanner ray misses.

        The hit is found by Embree on the object mesh and refined onto the exact surface;
        range noise and quantisation follow the config.
        """
        cfg = self.cfg
        S, T = np.meshgrid(self.rig.angles(), self.rig.heights())
        o, d = self._scan_rays(S.ravel(), T.ravel())
        if self.object is not None:
            _, _, rho, _, hit = self._mesh_scan(o, d)
            r = np.where(hit, rho, np.nan).reshape(S.shape)
        else:
            hits = self.tracer.closest_hit(o, d)
            p, _, exact_hit = self._ray_ellipsoid(o, d)
            hit = hits.hit & exact_hit
            r = np.where(hit, np.hypot(p[:, 0], p[:, 2]), np.nan).reshape(S.shape)
        rng = np.random.default_rng([self.seed, 1])
        if cfg.range_noise_mm > 0:
            r = r + rng.normal(0.0, cfg.range_noise_mm, size=r.shape)
        if cfg.range_bits:
            lo, hi = np.nanmin(r), np.nanmax(r)
            levels = 2**cfg.range_bits - 1
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
        s = self.rig.angles()[:, None] + du[None, :] * self.rig.angle_step  # (W, S)
        t = self.rig.heights()[:, None] + dv[None, :] * self.rig.height_step  # (H, S)
        H, W, Sn = self.rig.rows, self.rig.columns, du.size
        S_full = np.broadcast_to(s[None], (H, W, Sn)).ravel()
        T_full = np.broadcast_to(t[:, None, :], (H, W, Sn)).ravel()
        o, d = self._scan_rays(S_full, T_full)
        if self.object is not None:
            p, n, _, tri, hit = self._mesh_scan(o, d)
        else:
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
            "points": p[keep],
            "normals": n[keep],
            "view": v,
            "texel": texel,
            "u": u.astype(np.float32),
            "w": w.astype(np.float32),
            "count": np.bincount(texel, minlength=H * W),
        }
        if self.object is not None:
            # the texel's truth where its centre is scanned, else the material at the sub-sample itself
            flat = {k: self.truth[k].reshape((H * W,) + self.truth[k].shape[2:])[texel] for k in ("pd", "ps", "sigma")}
            own = np.flatnonzero(~self.truth["texel_hit"].ravel()[texel])
            if own.size:
                m = self._material_at(p[keep][own], tri[keep][own])
                for k in flat:
                    flat[k][own] = m[k]
            self._samples.update(flat)
        return self._samples

    def candidate_positions(self) -> np.ndarray:
        """(P, 3) head-frame candidate light positions [lateral, vertical, radial] of the light grid."""
        g = self.grid
        return light_grid_positions(
            g.columns, g.rows, g.spacing_mm, g.radial_mm, g.center_lateral_mm, g.center_vertical_mm
        )

    # ------------------------------------------------------------------ rendering

    def radiance_image(self, head_position) -> np.ndarray:
        """(H, W, 3) float64 noiseless sensor value (fraction of full range) for a light at head_position:
        the mean over each texel's visible sub-samples of kappa * Y / C^2 * f * cos, with Embree shadows,
        plus path-traced interreflection when synthetic.indirect_samples > 0."""
        return self.radiance_images(np.asarray(head_position, dtype=np.float64)[None])[0]

    def radiance_images(self, head_positions, progress=None) -> np.ndarray:
        """(P, H, W, 3) float64 noiseless sensor values for head positions (P, 3); the interreflection
        paths are traced once and shaded for every light (progress(done, total) per chunk of origins)."""
        positions = np.asarray(head_positions, dtype=np.float64).reshape(-1, 3)
        H, W = self.rig.rows, self.rig.columns
        sums = np.stack([self._direct_sum(pos) for pos in positions]) if len(positions) else np.zeros((0, H * W, 3))
        if self.cfg.indirect_samples > 0 and len(positions):
            smp = self._subsamples()
            ind = self.indirect_subsamples(positions, progress=progress)
            for i in range(len(positions)):
                for c in range(3):
                    sums[i, :, c] += np.bincount(smp["texel"], weights=ind[i, :, c], minlength=H * W)
        count = self._subsamples()["count"]
        sums /= np.maximum(count, 1)[None, :, None]
        return sums.reshape(len(positions), H, W, 3)

    def _light_world(self, head_position) -> np.ndarray:
        """(N, 3) world position of the light for every visible sub-sample (its column's head frame)."""
        smp = self._subsamples()
        lat, vert, rad = (float(c) for c in np.asarray(head_position, dtype=np.float64))
        light = rad * smp["u"].astype(np.float64) + lat * smp["w"].astype(np.float64)
        light[:, 1] += vert
        return light

    def _normal_at(self, points: np.ndarray, tri: np.ndarray) -> np.ndarray:
        if self.object is not None:
            return self.object.normal(points, tri)
        n = points / (self.axes**2)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def _material_at(self, points: np.ndarray, tri: np.ndarray) -> dict:
        """Material at arbitrary surface points: the mesh object's function, or for the analytic objects
        and the vase the texel map of the column and row the point is scanned at."""
        if self.object is not None and self.object.material is not None:
            return self.object.material(points, tri)
        rig = self.rig
        s = np.arctan2(-points[:, 0], -points[:, 2])
        col = np.mod(np.round((s - rig.angle0) / rig.angle_step), round(2 * math.pi / rig.angle_step)).astype(np.int64)
        col = np.clip(col, 0, rig.columns - 1)
        row = np.clip(np.round((-points[:, 1] - rig.height0) / rig.height_step).astype(np.int64), 0, rig.rows - 1)
        return {k: self._maps[k][row, col] for k in ("pd", "ps", "sigma", "region")}

    def indirect_renderer(self) -> IndirectRenderer:
        if self._gi is None:
            cfg = self.cfg
            self._gi = IndirectRenderer(
                self.tracer, self._normal_at, self._material_at, cfg.brdf, offset=0.01, seed=self.path_seed
            )
        return self._gi

    def indirect_subsamples(self, head_positions, progress=None) -> np.ndarray:
        """(P, N, 3) interreflected sensor value kappa * Y * L_ind / full range of every visible sub-sample."""
        cfg = self.cfg
        smp = self._subsamples()
        positions = np.asarray(head_positions, dtype=np.float64).reshape(-1, 3)
        lights = np.stack([self._light_world(pos) for pos in positions])
        H, W = self.rig.rows, self.rig.columns
        mat = {}
        for k in ("pd", "ps", "sigma"):
            mat[k] = smp[k] if k in smp else self.truth[k].reshape((H * W,) + self.truth[k].shape[2:])[smp["texel"]]
        g = self.indirect_renderer().render(
            smp["points"],
            smp["normals"],
            smp["view"],
            mat["pd"],
            mat["ps"],
            mat["sigma"],
            lights,
            cfg.indirect_samples,
            progress=progress,
            groups=smp["texel"],
        )
        return self.kappa * cfg.light_intensity * g

    def _direct_sum(self, head_position) -> np.ndarray:
        """(H*W, 3) sum over each texel's visible sub-samples of the direct sensor value."""
        cfg = self.cfg
        smp = self._subsamples()
        H, W = self.rig.rows, self.rig.columns
        lat, vert, rad = (float(c) for c in np.asarray(head_position, dtype=np.float64))
        light = rad * smp["u"].astype(np.float64) + lat * smp["w"].astype(np.float64)
        light[:, 1] += vert
        p, n = smp["points"], smp["normals"]
        pl = point_light(p, n, light, self.tracer, offset=0.01)
        l, dist = pl.direction, pl.distance
        idx = np.flatnonzero(pl.visible)
        img = np.zeros((H * W, 3))
        if idx.size:
            tex = smp["texel"][idx]
            tt = lambda x: torch.from_numpy(np.ascontiguousarray(x))
            if "pd" in smp:
                flat = lambda key: smp[key][idx]
            else:
                flat = lambda key: self.truth[key].reshape((H * W,) + self.truth[key].shape[2:])[tex]
            with torch.no_grad():
                g = brdf_mod.cosine_weighted_brdf(
                    cfg.brdf,
                    tt(n[idx]),
                    tt(l[idx]),
                    tt(smp["view"][idx]),
                    tt(flat("pd")),
                    tt(flat("ps")),
                    tt(flat("sigma")),
                    cfg.minnaert_k,
                ).numpy()
            value = self.kappa * cfg.light_intensity * g / (dist[idx, None] ** 2)
            for c in range(3):
                img[:, c] = np.bincount(tex, weights=value[:, c], minlength=H * W)
        return img

    def render_texture(self, head_position) -> np.ndarray:
        """(H, W, 3) uint8 (or uint16) texture image for a light at head_position, with noise."""
        return self._sensor(self.radiance_image(head_position), head_position)

    def _sensor(self, img: np.ndarray, head_position) -> np.ndarray:
        """Noise (seeded by the head position), clipping and quantisation of a radiance image."""
        cfg = self.cfg
        head = np.asarray(head_position, dtype=np.float64)
        key = int.from_bytes(hashlib.sha256(np.round(head, 6).tobytes()).digest()[:8], "little")
        rng = np.random.default_rng([self.seed if cfg.noise_seed is None else cfg.noise_seed, key])
        levels = 2**cfg.texture_bits - 1
        noisy = img * levels + rng.normal(0.0, cfg.noise_dn * levels / 255.0, size=img.shape)
        q = np.clip(np.round(noisy), 0, levels)
        return q.astype(np.uint8 if cfg.texture_bits == 8 else np.uint16)

    # ------------------------------------------------------------------ files

    def scan_yaml(self, lights: list | str | None = None) -> dict:
        doc = {"kind": "cylindrical_scan"}
        doc.update(self.rig.to_yaml_dict())
        doc["light"] = {"intensity": [float(self.cfg.light_intensity)] * 3, "kappa": [float(k) for k in self.kappa]}
        doc["saturation_level"] = float(self.saturation_level)
        doc["range"] = {"file": "range.npy"}
        doc["truth"] = {"file": "truth.npz", "brdf": self.cfg.brdf}
        doc["lights"] = lights if lights is not None else []
        return doc

    def write_geometry(self, folder) -> Path:
        """Write scan.yaml (no lights yet), range.npy and truth.npz into `folder`."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        np.save(folder / "range.npy", self.range_image().astype(np.float32))
        np.savez(
            folder / "truth.npz",
            pd=self.truth["pd"],
            ps=self.truth["ps"],
            sigma=self.truth["sigma"],
            region=self.truth["region"],
            brdf=self.cfg.brdf,
            minnaert_k=float(self.cfg.minnaert_k),
        )
        (folder / "scan.yaml").write_text(yaml.safe_dump(self.scan_yaml(), sort_keys=False))
        return folder

    def write_textures(self, folder, head_positions, progress=None) -> list:
        """Render one texture per head position into folder/textures and list them in scan.yaml."""
        folder = Path(folder)
        (folder / "textures").mkdir(parents=True, exist_ok=True)
        lights = []
        positions = np.asarray(head_positions, dtype=np.float64).reshape(-1, 3)
        # with interreflection all lights share one set of paths: render them together
        images = self.radiance_images(positions) if self.cfg.indirect_samples > 0 else None
        for i, pos in enumerate(positions):
            name = f"textures/{i:03d}.png"
            tex = self._sensor(images[i], pos) if images is not None else self.render_texture(pos)
            write_png(folder / name, tex, bits=self.cfg.texture_bits)
            lights.append({"image": name, "position_mm": [float(x) for x in pos]})
            if progress is not None:
                progress.update(1)
        doc = yaml.safe_load((folder / "scan.yaml").read_text())
        doc["lights"] = lights
        (folder / "scan.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        return lights
