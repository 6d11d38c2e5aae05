"""What the next-best light planner (planning.next_best) needs from a fitted mesh_views run: its estimate on the
atlas texels, the capture's mesh and calibrated cameras, and the observation model of a light at a world position.

The geometry is read back from the capture folder the run was fitted on (a synthetic_mesh_views run's own
`capture/`, a mesh_views run's capture.path) by the loader (capture.mesh_views.MeshViewsLoader.load_geometry: the
mesh on its atlas at capture.texture_size, cameras and lights in mm), so the texels are the fit's; a run whose
texel positions differ from the folder's is refused.

A candidate light is photographed by every camera that sees some texel of the object (the choice this planner
makes: the plan lists one image per camera for each chosen light), so it is images_per_light rows of
Observations, one per such camera, each as the loader computes an image's geometry: the camera's view of the
texels (capture.mesh_views.frame_view: projection, Embree visibility, silhouettes, footprints too narrow), the
light's direction, 1 / d^2 falloff and cast shadow (core.point_light.light_geometry, traced for the texels some
camera sees; texels at a cast shadow's edge left out, capture.shadow_edges), n.l above
reflectance.min_cos_light. Its radiant intensity is the per-channel median of the run's fitted lights', its
exposure 1; kappa is the run's; an observation saturates at the folder's saturation level
(images.json, else capture.saturation_level), which next_best applies to the predicted values.

The run's own information comes from its fitted images (capture.light_subset minus fit.holdout), each with its own
camera and light, as the loader saw them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from torchrefl.capture.checks import light_indices
from torchrefl.capture.mesh_views import MeshViewsLoader, TexelFrame, frame_view, texel_frame, view_spread
from torchrefl.capture.shadow_edges import shadow_edge_observations
from torchrefl.capture.view_folder import ViewFolder
from torchrefl.capture.views_sampling import CameraView
from torchrefl.config import Config, resolve_path
from torchrefl.core.observations import Observations
from torchrefl.core.point_light import PointLight, light_geometry
from torchrefl.core.rays import RayTracer
from torchrefl.errors import RunFolderError
from torchrefl.fit.pipeline import held_out
from torchrefl.fit.uncertainty import ParameterRanges
from torchrefl.geometry.atlas_surface import AtlasGeometry
from torchrefl.planning.run_scene import run_noise, texel_estimate
from torchrefl.planning.world_candidates import WorldCandidates, world_candidates
from torchrefl.report.run_result import RunResult

#: the capture kinds whose runs this scene reads (world light positions)
VIEWS_KINDS = ("synthetic_mesh_views", "mesh_views")
#: texel positions (mm) of the folder's atlas and the run's may differ by this much (float32 round trips)
POSITION_TOLERANCE_MM = 1e-3


@dataclass
class ViewsRunScene:
    """A fitted mesh_views run seen by a planner, over the T atlas texels (module docstring).

    run, cfg: the RunResult and its resolved Config; geometry: the atlas (the fit's texels); meta: the capture
    folder's cameras, lights and images (mm); tracer: the mesh's Embree scene; frame: the texels' points, normals and
    steps as the loader traces them; views: the CameraView of each camera in `cameras` (the indices of meta.cameras
    that see some texel); fitted: images.json indices of the run's fitted images; pd, ps, sigma, estimated,
    unobserved, lobe_measured, n_specular: the estimate (planning.run_scene.TexelEstimate);
    lights (P, 3) world mm: the distinct positions of the fitted images' point lights; intensity (3,): a
    candidate's radiant intensity; kappa (3,); saturation_level; noise_dn (3,) DN; ranges: the broad prior."""

    run: RunResult
    cfg: Config
    geometry: AtlasGeometry
    meta: ViewFolder
    tracer: RayTracer
    frame: TexelFrame
    cameras: list[int]
    views: list[CameraView]
    fitted: list[int]
    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    estimated: torch.Tensor
    unobserved: torch.Tensor
    lobe_measured: torch.Tensor
    n_specular: torch.Tensor
    lights: np.ndarray
    intensity: np.ndarray
    kappa: np.ndarray
    saturation_level: float
    noise_dn: torch.Tensor
    ranges: ParameterRanges

    @property
    def images_per_light(self) -> int:
        """Rows of `observations` per candidate light: one per camera that sees the object."""
        return len(self.cameras)

    @property
    def normals(self) -> torch.Tensor:
        """(T, 3) unit texel normals (the estimate's dtype)."""
        return self.geometry.surface.normals.to(self.pd.dtype)

    def world_candidates(self) -> WorldCandidates:
        """The config's selection.world candidates about the mesh (planning.world_candidates)."""
        c = self.cfg
        return world_candidates(c.selection.world, c.selection.grid, self.geometry.mesh.vertices, c.config_dir)

    def default_candidates(self) -> np.ndarray:
        """(M, 3) world mm: the config's selection.world candidates."""
        return self.world_candidates().positions

    @cached_property
    def _frame(self) -> tuple[np.ndarray, np.ndarray]:
        """float32 texel points and normals (T, 3) as the loader traces them."""
        f = self.frame
        return f.points.astype(np.float32), f.normals.astype(np.float32)

    def _light(self, position=None, direction=None) -> PointLight:
        """A light's geometry over the texels (shadows traced at every lit texel, as the loader does)."""
        points, normals = self._frame
        return light_geometry(
            points,
            normals,
            self.tracer,
            position=position,
            direction=direction,
            offset=self.cfg.geometry.shadow_offset_mm,
            min_cos=self.cfg.reflectance.min_cos_light,
        )

    def _rows(self, pairs: list[tuple[int, PointLight]], point: list[bool], intensity, what: str) -> Observations:
        """Observations of images (v, light): view index v in self.views under the light, a point light where
        `point` (else directional: no distance); intensity (R, 3)."""
        distances = [pl.distance if near else np.full(len(pl.distance), np.inf) for (_, pl), near in zip(pairs, point)]
        dtype = self.pd.dtype
        t = lambda a: torch.from_numpy(np.ascontiguousarray(np.stack(a))).to(dtype)
        adjacent = self.frame.adjacent
        valid = [
            self.views[v].seen & pl.lit & ~pl.shadowed & ~shadow_edge_observations(pl.shadowed, adjacent)
            for v, pl in pairs
        ]
        shadowed = torch.from_numpy(np.stack([pl.shadowed for _, pl in pairs]))
        centres = self.meta.cameras.centres().numpy()
        brdf = self.cfg.reflectance.brdf
        spread = [
            view_spread(self.views[v], self.frame, centres[self.cameras[v]], pl.direction, far, brdf)
            for (v, pl), far in zip(pairs, distances)
        ]
        return Observations(
            intensity=torch.zeros(len(pairs), len(valid[0]), 3, dtype=dtype),
            valid=torch.from_numpy(np.stack(valid)),
            saturated=torch.zeros(shadowed.shape, dtype=torch.bool),
            shadowed=shadowed,
            light_dir=t([pl.direction for _, pl in pairs]),
            falloff=t([1.0 / np.maximum(pl.distance, 1e-9) ** 2 for _, pl in pairs]),
            light_intensity=torch.from_numpy(np.array(intensity, dtype=np.float64)).to(dtype),
            view_dir=t([self.views[v].view_dir for v, _ in pairs]),
            kappa=torch.from_numpy(self.kappa).to(dtype),
            lobe_spread=t(spread),
            source=f"{self.run.folder}: {what}",
        )

    def observations(self, positions: np.ndarray) -> Observations:
        """The geometry of M point lights at world positions (M, 3) mm, each photographed by every camera that
        sees the object: M * images_per_light rows, light after light (intensity 0: nothing measured)."""
        pairs = [
            (v, pl)
            for pos in np.asarray(positions)
            for pl in [self._light(position=pos)]
            for v in range(len(self.views))
        ]
        return self._rows(
            pairs, [True] * len(pairs), np.broadcast_to(self.intensity, (len(pairs), 3)), "predicted lights"
        )

    def fitted_observations(self, chunk: int) -> Iterator[Observations]:
        """The geometry of the run's fitted images (each its own camera and light), chunk images at a time."""
        m = self.meta
        view_of = {c: v for v, c in enumerate(self.cameras)}
        lights = m.lights
        for start in range(0, len(self.fitted), chunk):
            images = [i for i in self.fitted[start : start + chunk] if int(m.camera_index[i]) in view_of]
            if not images:
                continue
            pairs, point = [], []
            for i in images:
                k = int(m.light_index[i])
                pl = self._light(lights.position[k]) if lights.point[k] else self._light(direction=lights.direction[k])
                pairs.append((view_of[int(m.camera_index[i])], pl))
                point.append(bool(lights.point[k]))
            intensity = lights.intensity[[int(m.light_index[i]) for i in images]]
            yield self._rows(pairs, point, intensity, "fitted images")


def views_capture_folder(run: RunResult, cfg: Config) -> Path:
    """The folder a mesh_views run was fitted on: a synthetic run's `capture/`, a mesh_views run's capture.path."""
    if cfg.capture.kind == "synthetic_mesh_views":
        return run.folder / "capture"
    return resolve_path(cfg, cfg.capture.path)


def views_run_scene(run: RunResult, cfg: Config) -> ViewsRunScene:
    """The ViewsRunScene of a loaded run of a VIEWS_KINDS capture (RunFolderError: its folder's atlas is not the
    run's; the loader's CaptureError for a folder it cannot read)."""
    folder = views_capture_folder(run, cfg)
    meta, geom = MeshViewsLoader().load_geometry(folder, cfg)
    s = geom.surface
    index = s.texel_index.numpy()
    if tuple(s.grid_shape) != run.grid_shape:
        raise RunFolderError(
            f"{folder}: its atlas {tuple(s.grid_shape)} is not the run's {run.grid_shape} (params.npz)"
        )
    drift = np.abs(run.positions.reshape(-1, 3)[index] - s.positions.double().numpy()).max(initial=0.0)
    if not drift <= POSITION_TOLERANCE_MM:
        raise RunFolderError(
            f"{folder}: the mesh's atlas texels lie up to {drift:.3g} mm from the run's (params.npz positions): "
            "expected the capture folder the run was fitted on"
        )
    est = texel_estimate(run, index, cfg.torch_dtype)
    tracer = RayTracer(geom.mesh.vertices, geom.mesh.faces, threads=cfg.threads)
    frame = texel_frame(geom)
    views = [frame_view(meta, c, frame, tracer, cfg) for c in range(len(meta.cameras))]
    cameras = [c for c, v in enumerate(views) if v.seen.any()]
    chosen = light_indices(cfg.capture.light_subset, len(meta.views.images), meta.views.source)
    fitted = [i for i, out in zip(chosen, held_out(cfg.fit.holdout, len(chosen)).tolist()) if not out]
    used = sorted({int(meta.light_index[i]) for i in fitted})
    point = [k for k in used if meta.lights.point[k]]
    v = meta.views
    rc = cfg.reflectance
    return ViewsRunScene(
        run=run,
        cfg=cfg,
        geometry=geom,
        meta=meta,
        tracer=tracer,
        frame=frame,
        cameras=cameras,
        views=[views[c] for c in cameras],
        fitted=fitted,
        pd=est.pd,
        ps=est.ps,
        sigma=est.sigma,
        estimated=est.estimated,
        unobserved=est.unobserved,
        lobe_measured=est.lobe_measured,
        n_specular=est.n_specular,
        lights=np.asarray(meta.lights.position[point], dtype=np.float64).reshape(-1, 3),
        intensity=np.median(np.asarray(meta.lights.intensity[used], dtype=np.float64), axis=0),
        kappa=np.asarray(run.kappa, dtype=np.float64),
        saturation_level=float(v.saturation_level if v.saturation_level is not None else cfg.capture.saturation_level),
        noise_dn=run_noise(run, cfg),
        ranges=ParameterRanges(rc.ps_max, rc.sigma_min, rc.sigma_max),
    )
