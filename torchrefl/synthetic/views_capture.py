"""capture.kind synthetic_mesh_views: the config's `views` scene rendered into a mesh_views folder, then read back.

The scene (synthetic.mesh_views.build_scene of cfg.views, deterministic in cfg.seed) is rendered into
out/capture with its truth on the capture.texture_size atlas, and the folder is read by the mesh_views loader like
any capture on disk (mirrors synthetic.capture for the cylindrical scan; there is no light selection).
"""

from __future__ import annotations

from pathlib import Path

from torchrefl.capture.base import Capture, Log
from torchrefl.capture.mesh_views import MeshViewsLoader
from torchrefl.config import Config
from torchrefl.core.progress import Stages, bar
from torchrefl.synthetic.mesh_views import write_capture


def synthetic_views_capture(cfg: Config, out: Path, stages: Stages, log: Log) -> tuple[Capture, None]:
    """Render cfg.views into out/capture and load it (no light selection: None)."""
    v = cfg.views
    with stages.stage("render views"):
        with bar(1, "render", cfg.output.progress, unit="image") as pb:

            def progress(done: int, total: int) -> None:
                pb.total = total
                pb.n = done
                pb.refresh()

            written = write_capture(
                out / "capture",
                v,
                texture_size=cfg.capture.texture_size,
                seed=cfg.seed,
                kappa=cfg.capture.kappa,
                saturation_level=cfg.capture.saturation_level,
                threads=cfg.threads,
                progress=progress,
            )
    s = written.scene
    log(
        f"synthetic mesh_views {v.object}: {len(s.images)} images from {len(s.cameras)} cameras under "
        f"{len(s.lights)} lights written to {written.folder}"
    )
    with stages.stage("observations"):
        return MeshViewsLoader().load(written.folder, cfg, log), None
