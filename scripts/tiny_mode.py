"""The tiny mode (--tiny) of the scripts under scripts/: the glossy fold (configs/fold.yaml) at a few hundred texels,
4 lights, a few thousand photons, so that a test runs a script end to end in seconds (tests/scripts/). Its numbers
say nothing about accuracy or speed; they only show that the script still runs."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLD = ROOT / "configs" / "fold.yaml"

#: the scan shrunk (the fold's 358 deg x 252 mm at 32 x 24 texels), one path per texel, the fit cut short
TINY_SCAN = [
    "synthetic.columns=32",
    "synthetic.rows=24",
    "synthetic.angle_step_deg=11.2",
    "synthetic.height_step_mm=10.5",
    "synthetic.supersample=1",
    "synthetic.indirect_samples=2",
    "selection.num_lights=4",
    "fit.holdout=[1]",
    "fit.iterations=3",
    "output.progress=false",
    "output.map_lights=0",
    "threads=1",
]
#: the interreflection levels at a few thousand photons and rays
TINY_LEVELS = [
    "photon.photons_per_light=4000",
    "photon.outer_iterations=1",
    "photon.specular_gather=8",
    "radiosity.hemisphere_samples=16",
    "radiosity.solve_samples=8",
]
TINY = TINY_SCAN + TINY_LEVELS
#: a synthetic mesh_views capture (configs/mesh_views.yaml) at a 16 x 16 texel atlas, 4 views of 96 x 72 pixels
TINY_VIEWS = [
    "capture.texture_size=16",
    "views.width=96",
    "views.height=72",
    "views.focal_px=160",
    "views.camera_elevations_deg=[-20.0,30.0]",
    "views.cameras_per_ring=2",
    "views.lights_per_view=2",
    "views.supersample=1",
    "fit.holdout=[1]",
    "fit.iterations=3",
    "output.progress=false",
    "output.map_lights=0",
    "threads=1",
]


def tiny_run(folder: Path, config: Path = FOLD, model: str = "photon", extra: tuple[str, ...] = ()) -> Path:
    """Fit a bundled synthetic config, tiny (TINY, or TINY_VIEWS for a mesh_views one), at `model` into folder (its
    capture rendered there, folder/capture); returns folder."""
    import torchrefl

    tiny = TINY_VIEWS if "mesh_views" in Path(config).name else TINY
    cfg = torchrefl.load_config(config, tiny + [f"output.dir={folder}", f"fit.model={model}", *extra])
    torchrefl.fit(cfg, overwrite=True)
    return folder
