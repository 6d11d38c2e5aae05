"""The synthetic mesh_views renderer: photographs of a mesh object from pinhole cameras under point lights.

Rendered at a higher fidelity than the fitter models the capture: per pixel supersample^2 stratified camera rays
(synthetic.views_layout.ViewCamera.rays), Embree's closest hit on the object's mesh, the exact normal and the
true material at each hit point (the object's functions, not a texel's values), direct light of each point
light with a shadow ray (torchrefl.core.point_light), and for concave objects path-traced interreflection
(synthetic.path_tracer.IndirectRenderer: one set of paths per camera, shaded for each of its lights, a pixel's
sub-samples sharing one stratified set). A sub-sample whose exact normal faces away from the camera (a
silhouette) reflects nothing; rays that miss see a black background.

The pixel value, as a fraction of the sensor's full range, is the mean over the pixel's sub-samples of
kappa * exposure * L_o (a miss counts 0). The sensor (`sensor`) adds Gaussian noise of noise_dn 8-bit digital
numbers (the synthetic scan's convention) to pixels that see the object, rounds to 16 bits and clips at full
scale; background pixels stay exactly 0. Deterministic in the seed: the paths of camera k are keyed by
(seed, k), the noise of image i by (seed, i).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.synthetic.path_tracer import IndirectRenderer
from torchrefl.synthetic.uv_objects import ViewsObject
from torchrefl.synthetic.views_layout import ViewCamera, ViewLight

OFFSET_MM = 0.01  # shadow and path rays start this far from the surface (the synthetic scan's choice)
LEVELS = 65535  # 16-bit full scale


@dataclass
class RenderedView:
    """values: (P, N, 3) noiseless kappa * L_o (fraction of full range, exposure 1) per light and pixel;
    covered: (N,) bool, the pixel has a sub-sample on the object (else it is background, 0)."""

    values: np.ndarray
    covered: np.ndarray


class ViewsRenderer:
    """Renders a ViewsObject (module doc).

    brdf: a torchrefl.core.brdf model name; kappa: (3,) camera gain; supersample: sub-pixel rays per pixel
    side; indirect_samples: interreflection paths per sub-sample (concave objects only; 0 = direct light only);
    noise_dn: sensor noise in 8-bit digital numbers; seed; threads: Embree threads."""

    def __init__(
        self,
        obj: ViewsObject,
        *,
        brdf: str = "torrance_sparrow",
        kappa=(np.pi,) * 3,
        supersample: int = 2,
        indirect_samples: int = 0,
        noise_dn: float = 0.0,
        seed: int = 0,
        threads: int = 2,
    ):
        self.obj = obj
        self.brdf = brdf_mod.check_brdf_name(brdf, "mesh_views brdf")
        self.kappa = np.asarray(kappa, dtype=np.float64)
        self.supersample = int(supersample)
        self.indirect_samples = int(indirect_samples) if obj.concave else 0
        self.noise_dn = float(noise_dn)
        self.seed = int(seed)
        self.tracer = RayTracer(obj.mesh.vertices, obj.mesh.faces, threads=threads)

    def _g(self, n, l, v, mat) -> np.ndarray:
        args = (n, l, v, mat["pd"], mat["ps"], mat["sigma"])
        with torch.no_grad():
            return brdf_mod.cosine_weighted_brdf(
                self.brdf, *(torch.as_tensor(a, dtype=torch.float64) for a in args)
            ).numpy()

    def radiance(
        self, camera: ViewCamera, lights: list[ViewLight], camera_index: int = 0, pixels: np.ndarray | None = None
    ) -> RenderedView:
        """The noiseless kappa * L_o per light and pixel, as a fraction of full range at exposure 1.

        pixels: flat pixel indices (row * width + col) to render, N of them; None renders all (N = H * W,
        row-major). camera_index keys the interreflection paths' random numbers."""
        origins, dirs, _ = camera.rays(self.supersample, pixels)
        n_pix = camera.width * camera.height if pixels is None else len(pixels)
        owner = np.repeat(np.arange(n_pix), self.supersample**2)  # each sub-sample's pixel among those rendered
        hits = self.tracer.closest_hit(origins, dirs)
        idx = np.flatnonzero(hits.hit)
        p = origins[idx] + hits.distance[idx, None] * dirs[idx]
        tri = hits.triangle[idx]
        n = self.obj.mesh.normal(p, tri)
        view = -dirs[idx]
        front = np.einsum("ni,ni->n", n, view) > 0
        p, tri, n, view, local = p[front], tri[front], n[front], view[front], owner[idx[front]]
        mat = self.obj.mesh.material(p, tri)
        P = len(lights)
        values = np.zeros((P, len(p), 3))
        for i, light in enumerate(lights):
            pl = point_light(p, n, np.broadcast_to(light.position, p.shape), self.tracer, offset=OFFSET_MM)
            vis = np.flatnonzero(pl.visible)
            if vis.size:
                g = self._g(n[vis], pl.direction[vis], view[vis], {k: v[vis] for k, v in mat.items()})
                values[i, vis] = g / pl.distance[vis, None] ** 2
        if self.indirect_samples > 0 and len(p):
            seed = int(np.random.SeedSequence([self.seed, camera_index]).generate_state(1)[0])
            gi = IndirectRenderer(self.tracer, self.obj.mesh.normal, self.obj.mesh.material, self.brdf, seed=seed)
            lights_at = np.stack([np.broadcast_to(light.position, p.shape) for light in lights])
            values += gi.render(
                p, n, view, mat["pd"], mat["ps"], mat["sigma"], lights_at, self.indirect_samples, groups=local
            )
        scale = self.kappa[None, :] * np.stack([light.intensity for light in lights])  # (P, 3)
        out = np.zeros((P, n_pix, 3))
        for i in range(P):
            for c in range(3):
                out[i, :, c] = np.bincount(local, weights=values[i, :, c], minlength=n_pix)
        covered = np.bincount(owner[idx], minlength=n_pix) > 0
        return RenderedView(out * scale[:, None, :] / self.supersample**2, covered)

    def sensor(self, values: np.ndarray, covered: np.ndarray, exposure: float, image_index: int) -> np.ndarray:
        """(H, W, 3) uint16 image of noiseless values (H, W, 3) at exposure 1 (RenderedView.values of one light):
        times exposure, plus noise on the covered (H, W) pixels, rounded, clipped to [0, 65535];
        background exactly 0."""
        rng = np.random.default_rng([self.seed, 0x3D, image_index])
        noise = rng.normal(0.0, self.noise_dn * LEVELS / 255.0, size=values.shape)
        dn = np.where(covered[..., None], values * exposure * LEVELS + noise, 0.0)
        return np.clip(np.rint(dn), 0, LEVELS).astype(np.uint16)
