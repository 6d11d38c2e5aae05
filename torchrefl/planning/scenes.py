"""The planner's view of a finished run, whichever capture kind it fitted: a RunScene for a scan
(planning.run_scene), a ViewsRunScene for mesh_views (planning.views_run_scene)."""

from __future__ import annotations

from pathlib import Path

from torchrefl.config import load_config
from torchrefl.errors import ConfigError
from torchrefl.planning.run_scene import SCAN_KINDS, RunScene, load_run_scene
from torchrefl.planning.views_run_scene import VIEWS_KINDS, ViewsRunScene, views_run_scene
from torchrefl.report.run_result import CONFIG, load_run


def load_planning_scene(run_dir: str | Path) -> RunScene | ViewsRunScene:
    """The scene of the finished run in run_dir (SCAN_KINDS or VIEWS_KINDS); ConfigError naming config.yaml's
    capture.kind for the other kinds, RunFolderError for a folder that is not a finished run."""
    run = load_run(run_dir)
    cfg = load_config(run.folder / CONFIG)
    if cfg.capture.kind in VIEWS_KINDS:
        return views_run_scene(run, cfg)
    if cfg.capture.kind in SCAN_KINDS:
        return load_run_scene(run_dir)
    raise ConfigError(
        f"{run.folder / CONFIG}: capture.kind is '{cfg.capture.kind}'; the next-best light planner reads runs of "
        f"{', '.join(SCAN_KINDS + VIEWS_KINDS)} (lights at positions in mm), not of this kind"
    )
