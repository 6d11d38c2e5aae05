"""capture.kind synthetic_cylindrical: a synthetic object scanned into a cylindrical_scan folder, then read back.

The scene's range image and truth are written first; the lights are chosen on that geometry (when
selection.enabled), only the chosen lights' textures are rendered, and the folder is read by the
cylindrical_scan loader like any scan on disk.
"""

from __future__ import annotations

from pathlib import Path

from torchrefl.capture.base import Capture, Log
from torchrefl.capture.cylindrical_scan import CylindricalScanLoader, ScanGeometry
from torchrefl.config import Config
from torchrefl.core.progress import Stages, bar
from torchrefl.planning.capture_plan import FIGURE_FILE, PLAN_FILE, choose_lights, selection_line, write_plan
from torchrefl.planning.light_selection import SelectionResult
from torchrefl.synthetic.scan import SyntheticScan


def stand_in_geometry(cfg: Config, folder: Path, stages: Stages, log: Log) -> tuple[SyntheticScan, ScanGeometry]:
    """The synthetic object of cfg scanned into `folder` (range image, truth; no texture) and its geometry read back."""
    with stages.stage("synthetic scan"):
        scan = SyntheticScan(
            cfg.synthetic, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa, threads=cfg.threads
        )
        scan.saturation_level = cfg.capture.saturation_level
        scan.write_geometry(folder)
    log(f"synthetic {cfg.synthetic.object} written to {folder}")
    with stages.stage("geometry"):
        geom = CylindricalScanLoader().load_geometry(folder, cfg)
    return scan, geom


def synthetic_capture(cfg: Config, out: Path, stages: Stages, log: Log) -> tuple[Capture, SelectionResult | None]:
    """Render cfg.synthetic into out/capture and load it; the light selection (None when disabled)."""
    folder = out / "capture"
    scan, geom = stand_in_geometry(cfg, folder, stages, log)
    positions = candidates = scan.candidate_positions()
    selection = None
    if cfg.selection.enabled:
        with stages.stage("light selection"):
            selection = choose_lights(cfg, geom, candidates)
            positions = candidates[selection.chosen]
            write_plan(selection, out / "selection" / PLAN_FILE, out / "selection" / FIGURE_FILE)
        log(selection_line(selection))
    with stages.stage("render textures"):
        with bar(len(positions), "render", cfg.output.progress, unit="image") as pb:
            scan.write_textures(folder, positions, progress=pb)
    with stages.stage("observations"):
        capture = CylindricalScanLoader().load(folder, cfg, log, geometry=geom)
    return capture, selection
