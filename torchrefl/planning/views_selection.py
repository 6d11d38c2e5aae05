"""Light selection for the mesh_views kind (dissertation Ch.2 over all views).

An observation (camera c, candidate light p) of texel x is measurable when camera c sees x (capture.views_sampling's
camera_view: its `seen`, the visibility the loader uses) and light p lights it (n.l > reflectance.min_cos_light,
shadow ray unblocked: core.point_light, as the loader); it is diffuse-only when the half-angle exceeds theta_th1
(eq. 2.20) and strong-specular when it is at most theta_th2 (eq. 2.21). A candidate's Measurability counts these
per texel over all cameras, and coverage is over the texels some camera sees, so planning.light_selection's
greedy_select picks lights exactly as for the scan. The plan's images: each chosen light with every camera that
measures some texel under it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.capture.cameras import Cameras
from torchrefl.capture.mesh_views import texel_steps
from torchrefl.capture.views_sampling import camera_view
from torchrefl.core.brdf import half_angle
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.geometry.atlas_surface import AtlasGeometry
from torchrefl.planning.light_selection import Measurability, SelectionResult, greedy_select
from torchrefl.planning.world_candidates import WorldCandidates


@dataclass(frozen=True)
class ViewsMeasurability:
    """measured: the candidates' diffuse-only / strong-specular counts over all cameras (P, T) and the texels some
    camera sees; measurable: (P, C) the texels camera c measures under candidate p (seen, lit, not shadowed)."""

    measured: Measurability
    measurable: np.ndarray


@dataclass(frozen=True)
class PlannedImage:
    """One photograph of a plan: its camera's and its light's names."""

    camera: str
    light: str


@dataclass(frozen=True)
class ViewsSelection:
    """A mesh_views light selection: the greedy result, the candidates, and the images to capture (per chosen
    light in selection order, each camera that measures some texel under it)."""

    selection: SelectionResult
    candidates: WorldCandidates
    images: tuple[PlannedImage, ...]

    def to_json(self) -> dict:
        """The plan file (`kind: mesh_views`): the selection's table and curves, the chosen lights (world
        position_mm, and gantry_mm [lateral, vertical] on a gantry layout), the gantry frame and the images."""
        c = self.candidates
        doc = self.selection.to_json()
        doc.pop("positions_mm")  # the scan's head-frame key: a mesh_views plan's lights are in the world frame
        doc.update(
            {
                "kind": "mesh_views",
                "layout": c.layout,
                "gantry": c.frame.to_json() if c.frame is not None else None,
                "lights": plan_lights(c, self.selection.chosen),
                "images": [{"camera": im.camera, "light": im.light} for im in self.images],
            }
        )
        return doc


def plan_lights(candidates: WorldCandidates, chosen) -> list[dict]:
    """A mesh_views plan's `lights`: per chosen candidate index its name, world position_mm and gantry_mm
    [lateral, vertical] (None off a gantry layout)."""
    c = candidates
    return [
        {
            "name": c.names[p],
            "position_mm": [float(x) for x in c.positions[p]],
            "gantry_mm": None if c.gantry_mm is None else [float(x) for x in c.gantry_mm[p]],
        }
        for p in chosen
    ]


def views_measurability(
    cameras: Cameras,
    geom: AtlasGeometry,
    tracer: RayTracer,
    candidates: np.ndarray,
    *,
    offset: float,
    min_cos_view: float,
    min_cos_light: float,
    theta_diffuse_deg: float,
    theta_specular_deg: float,
) -> ViewsMeasurability:
    """Measurability of candidate world positions (P, 3) mm for the atlas's texels seen by `cameras` (module doc)."""
    s = geom.surface
    x = s.positions.double().numpy()
    n = s.normals.double().numpy()
    areas = s.areas.double().numpy()
    steps = texel_steps(geom)
    T, C, P = len(x), len(cameras), len(candidates)
    views = [
        camera_view(
            cameras, c, x, n, areas, steps, tracer, offset=offset, min_cos_view=min_cos_view, neighbours=s.neighbours
        )
        for c in range(C)
    ]
    seen = np.stack([v.seen for v in views])  # (C, T)
    anyone = seen.any(0)
    x32, n32 = x.astype(np.float32), n.astype(np.float32)
    nt = torch.from_numpy(n32)
    vt = torch.from_numpy(np.stack([v.view_dir for v in views]))  # (C, T, 3)
    diffuse = np.zeros((P, T), dtype=np.int32)
    specular = np.zeros((P, T), dtype=np.int32)
    measurable = np.zeros((P, C), dtype=np.int64)
    th1, th2 = math.radians(theta_diffuse_deg), math.radians(theta_specular_deg)
    for p, L in enumerate(np.asarray(candidates, dtype=np.float32)):
        pl = point_light(
            x32, n32, np.broadcast_to(L, x32.shape), tracer, offset=offset, min_cos=min_cos_light, trace=anyone
        )
        ok = seen & pl.visible[None]  # (C, T)
        theta = half_angle(nt[None], torch.from_numpy(pl.direction)[None], vt).numpy()
        diffuse[p] = (ok & (theta > th1)).sum(0)
        specular[p] = (ok & (theta <= th2)).sum(0)
        measurable[p] = ok.sum(1)
    return ViewsMeasurability(Measurability(diffuse, specular, anyone), measurable)


def select_for_views(
    cameras: Cameras, geom: AtlasGeometry, candidates: WorldCandidates, cfg, threads: int = 2
) -> ViewsSelection:
    """The lights of cfg.selection chosen among the candidates for the cameras' views of the atlas (module doc);
    cfg: the run's Config (selection, reflectance, geometry.shadow_offset_mm)."""
    tracer = RayTracer(geom.mesh.vertices, geom.mesh.faces, threads=threads)
    r = cfg.reflectance
    vm = views_measurability(
        cameras,
        geom,
        tracer,
        candidates.positions,
        offset=cfg.geometry.shadow_offset_mm,
        min_cos_view=r.min_cos_view,
        min_cos_light=r.min_cos_light,
        theta_diffuse_deg=r.theta_diffuse_deg,
        theta_specular_deg=r.theta_specular_deg,
    )
    sel_cfg = cfg.selection
    sel = greedy_select(vm.measured, sel_cfg.stop_ratio, sel_cfg.max_lights, sel_cfg.num_lights)
    images = tuple(
        PlannedImage(cameras.names[c], candidates.names[p])
        for p in sel.chosen
        for c in range(len(cameras))
        if vm.measurable[p, c] > 0
    )
    return ViewsSelection(sel, candidates, images)
