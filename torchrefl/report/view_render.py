"""A mesh_views run's estimate rendered into one photograph of its capture: the photograph, the re-render and their
difference in the camera's own pixels (a held-out image as a picture; the notebook tour's mesh_views section).

    from torchrefl.report.run_result import load_run
    from torchrefl.report.view_render import render_view
    view = render_view(load_run("outputs/mesh_views"), image=5)   # images.json's image 5
    view.photograph, view.rendered, view.shown, view.difference()

The re-render is the relighting renderer's (torchrefl.report.relight: supersample x supersample rays per pixel with
the camera's distortion undone, Embree's first hit on the run's mesh, the normal blended from its corner normals,
the image's light with a cast-shadow ray, the fitted BRDF through the fitter's observation model, and the
interreflection of a radiosity or photon run unless interreflection=False) through the image's camera under its
light (the capture's cameras.json and lights.json, scaled from scene.yaml's units to mm like the mesh), times the
image's exposure. By default a hit reads the texel under it (interpolation "nearest": the fit's own model, one
reflectance per texel, so a texel's border shows where the photograph's does; "bilinear" blends the hit chart's four
nearest texels, smoother and blurred across material borders).
A pixel is shown when every sub-sample meets the object and lands on estimated texels (silhouettes and
texels without an estimate are left out).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.images_json import IMAGES_JSON
from torchrefl.capture.mesh_views import read_units
from torchrefl.capture.view_folder import read_view_folder
from torchrefl.errors import RunFolderError
from torchrefl.geometry.mesh_file import UNIT_SCALE_MM
from torchrefl.report.metrics import image_difference
from torchrefl.report.relight import Light, relight, relight_scene
from torchrefl.report.run_result import RunResult


@dataclass
class ViewRender:
    """Image `image` of the capture (images.json's index; `file`, its path): photograph (H, W, 3) as stored
    (fractions of full range, exposure included), rendered (H, W, 3) the estimate's re-render (0 where not
    shown), shown (H, W) bool the pixels compared."""

    image: int
    file: Path
    photograph: np.ndarray
    rendered: np.ndarray
    shown: np.ndarray

    def difference(self) -> dict:
        """rendered - photograph over the shown pixels on the 8-bit scale (metrics.image_difference's keys)."""
        t = lambda a: torch.from_numpy(np.asarray(a, dtype=np.float64))[None]
        return image_difference(t(self.rendered), t(self.photograph), torch.from_numpy(self.shown)[None])


def capture_folder(run: RunResult, capture=None) -> Path:
    """`capture` when given, else the folder of the run's mesh when it holds images.json (a mesh with its own UVs),
    else the run's own capture/ (a synthetic run's); RunFolderError asking for it otherwise."""
    if capture is not None:
        return Path(capture)
    beside = [(run.folder / run.mesh).parent] if run.mesh is not None else []
    for folder in [*beside, run.folder / "capture"]:
        if (folder / IMAGES_JSON).is_file():
            return folder
    raise RunFolderError(
        f"{run.folder}: the capture folder is not beside the run's mesh ({run.mesh}); give it: capture=PATH"
    )


def render_view(
    run: RunResult,
    image: int,
    capture=None,
    supersample: int = 2,
    threads: int = 2,
    interpolation: str = "nearest",
    interreflection: bool | None = None,
) -> ViewRender:
    """Photograph `image` (images.json's index) of the run's capture and the estimate re-rendered in its camera
    (module doc). capture: the capture folder (default: capture_folder); threads: Embree's; interpolation:
    "nearest" or "bilinear" (module doc); interreflection: relight's (None: the run's level)."""
    folder = capture_folder(run, capture)
    meta = read_view_folder(folder)
    if not 0 <= image < len(meta.paths):
        raise RunFolderError(f"{meta.views.source}: no image {image} (it lists {len(meta.paths)})")
    if run.mesh is None:
        raise RunFolderError(f"{run.folder}/params.npz: no 'mesh' key (expected a mesh_views run)")
    scale = UNIT_SCALE_MM[read_units(folder)]
    cameras, lights = meta.cameras.scaled(scale), meta.lights.scaled(scale)
    k = int(meta.light_index[image])
    where = {"position": lights.position[k]} if lights.point[k] else {"direction": lights.direction[k]}
    relit = relight(
        run,
        cameras,
        Light(lights.intensity[k], **where),
        index=int(meta.camera_index[image]),
        supersample=supersample,
        shadows=True,
        interpolation=interpolation,
        scene=relight_scene(run, threads),
        interreflection=interreflection,
    )
    shown = relit.filled & relit.estimated
    rendered = np.where(shown[..., None], relit.image * meta.views.images[image].exposure, 0.0)
    return ViewRender(image, meta.paths[image], meta.read_image(image), rendered, shown)
