"""A dry run: the fake GRBL device on a pseudo-terminal and a simulated camera rendering the
synthetic object of a fitting config (torchrefl.synthetic.scan.SyntheticScan), so that a
capture writes real texture images and a folder `python -m torchrefl.train` can fit."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from torchrefl.errors import RigError
from torchrefl.rig.camera import SimulatedCamera
from torchrefl.rig.fake_grbl import FakeGrbl
from torchrefl.rig.settings import RigSettings


def synthetic_scene(config=None, overrides=()):
    """SyntheticScan of a fitting config (its `synthetic`, `selection.grid`, `seed`, `capture.kappa`)."""
    from torchrefl.config import load_config
    from torchrefl.synthetic.scan import SyntheticScan

    cfg = load_config(config, list(overrides))
    return SyntheticScan(cfg.synthetic, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa, threads=cfg.threads)


def match_grid(settings: RigSettings, scan) -> RigSettings:
    """Rig settings whose light grid and radial distance are the synthetic scene's."""
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
    """Write the scene's scan.yaml, range.npy, truth.npz into out (unless scan.yaml is already there)."""
    out = Path(out)
    if not (out / "scan.yaml").is_file():
        scan.write_geometry(out)
    return out


def simulated_camera(scan) -> SimulatedCamera:
    return SimulatedCamera(scan.render_texture)
