"""A dry run: the fake GRBL device on a pseudo-terminal and a simulated camera rendering the
synthetic object of a fitting config (torchrefl.synthetic.scan.SyntheticScan, or for a config of
capture.kind synthetic_mesh_views its `views` scene: ViewsDryScene), so that a capture writes real
images and a folder `python -m torchrefl.train` can fit."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from torchrefl.errors import RigError
from torchrefl.rig.camera import SimulatedCamera
from torchrefl.rig.fake_grbl import FakeGrbl
from torchrefl.rig.settings import RigSettings


class ViewsDryScene:
    """The `views` scene of a synthetic_mesh_views config for a dry run: its mesh and cameras written into the
    capture folder (with scene.yaml and the truth on the capture.texture_size atlas), one image rendered per
    (light world position, camera) by the scene's renderer at exposure 1. grid: the config's selection.grid (the
    gantry layout's nodes); light_intensity: the scene's."""

    #: the file whose presence says the folder's geometry is already written
    marker = "cameras.json"

    def __init__(self, cfg):
        from torchrefl.synthetic.mesh_views import build_scene
        from torchrefl.synthetic.views_render import ViewsRenderer

        v = cfg.views
        self.cfg = cfg
        self.scene = build_scene(v, cfg.seed)
        self.grid = cfg.selection.grid
        self.light_intensity = np.asarray(v.light_intensity, dtype=np.float64)
        self.renderer = ViewsRenderer(
            self.scene.object,
            brdf=v.brdf,
            kappa=cfg.capture.kappa,
            supersample=v.supersample,
            indirect_samples=v.indirect_samples,
            noise_dn=v.noise_dn,
            seed=cfg.seed,
            threads=cfg.threads,
        )
        self.rendered = 0

    def write_geometry(self, folder) -> Path:
        from torchrefl.synthetic.mesh_views import truth_on_atlas, write_geometry

        folder = Path(folder)
        mesh_file = write_geometry(folder, self.scene)
        truth = truth_on_atlas(self.scene.object, folder / mesh_file, self.cfg.capture.texture_size)
        np.savez(folder / "truth.npz", **truth, brdf=self.renderer.brdf)
        return folder

    def render_texture(self, position_mm, camera: str) -> np.ndarray:
        """(H, W, 3) uint16 image of `camera` under a point light at world position_mm (3,)."""
        from torchrefl.synthetic.views_layout import ViewLight

        names = [c.name for c in self.scene.cameras]
        if camera not in names:
            raise RigError(f"dry run: the plan names camera {camera!r}, the scene has {', '.join(names)}")
        k = names.index(camera)
        cam = self.scene.cameras[k]
        light = ViewLight("rig", np.asarray(position_mm, dtype=np.float64), self.light_intensity)
        view = self.renderer.radiance(cam, [light], camera_index=k)
        values = view.values[0].reshape(cam.height, cam.width, 3)
        image = self.renderer.sensor(values, view.covered.reshape(cam.height, cam.width), 1.0, self.rendered)
        self.rendered += 1
        return image


def synthetic_scene(config=None, overrides=()):
    """SyntheticScan of a fitting config (its `synthetic`, `selection.grid`, `seed`, `capture.kappa`), or its
    ViewsDryScene when its capture.kind is synthetic_mesh_views."""
    from torchrefl.config import load_config
    from torchrefl.synthetic.scan import SyntheticScan

    cfg = load_config(config, list(overrides))
    if cfg.capture.kind == "synthetic_mesh_views":
        return ViewsDryScene(cfg)
    return SyntheticScan(cfg.synthetic, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa, threads=cfg.threads)


def match_grid(settings: RigSettings, scan) -> RigSettings:
    """Rig settings whose light grid and radial distance are the synthetic scene's (and for a mesh_views scene
    its lights' intensity)."""
    if isinstance(scan, ViewsDryScene):
        light = dataclasses.replace(settings.light, intensity=[float(v) for v in scan.light_intensity])
        settings = dataclasses.replace(settings, light=light)
    g = scan.grid
    grid = dataclasses.replace(
        settings.grid,
        columns=g.columns,
        rows=g.rows,
        spacing_mm=g.spacing_mm,
        center_lateral_mm=g.center_lateral_mm,
        center_vertical_mm=g.center_vertical_mm,
    )
    return dataclasses.replace(settings, grid=grid, radial_mm=g.radial_mm)


def fake_device_for(settings: RigSettings, time_scale: float = 0.01) -> FakeGrbl:
    """A FakeGrbl whose machine travel ($130-$132, GRBL's [-max, 0]) covers the rig's soft limits."""
    travel = {}
    for ax in (settings.lateral, settings.vertical):
        k = "XYZ".index(ax.axis) if ax.axis in "XYZ" else None
        if k is None:
            raise RigError(f"dry run: the fake GRBL has axes X, Y, Z only (got {ax.axis})")
        if ax.max_mm > 0:
            raise RigError(
                f"dry run: {ax.axis} travel max_mm {ax.max_mm} > 0; GRBL's machine space after homing is "
                f"[-max travel, 0]"
            )
        travel[130 + k] = float(max(-ax.min_mm + 1.0, 1.0))
    return FakeGrbl(travel, time_scale=time_scale)


def prepare_folder(scan, out) -> Path:
    """Write the scene's geometry into out (scan.yaml, range.npy, truth.npz; a ViewsDryScene's mesh, scene.yaml,
    cameras.json, truth.npz) unless it is already there."""
    out = Path(out)
    if not (out / getattr(scan, "marker", "scan.yaml")).is_file():
        scan.write_geometry(out)
    return out


def simulated_camera(scan) -> SimulatedCamera:
    return SimulatedCamera(scan.render_texture)
