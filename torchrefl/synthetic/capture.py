"""capture.kind synthetic_cylindrical: a synthetic object scanned into a cylindrical_scan folder, then read back.

The scene's range image and truth are written first; the lights are chosen on that geometry (when
selection.enabled), only the chosen lights' textures are rendered, and the folder is read by the
cylindrical_scan loader like any scan on disk.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.capture.base import Capture, Log
from torchrefl.capture.cylindrical_scan import CylindricalScanLoader, ScanGeometry
from torchrefl.capture.scale_check import ObjectSize, Reference, ScaleCheck, check_scale
from torchrefl.capture.scan_scale import head_distances
from torchrefl.config import Config
from torchrefl.core.progress import Stages, bar
from torchrefl.errors import ConfigError
from torchrefl.planning.capture_plan import FIGURE_FILE, PLAN_FILE, choose_lights, selection_line, write_plan
from torchrefl.planning.light_selection import SelectionResult
from torchrefl.synthetic.scan import SyntheticScan


def synthetic_scale_check(cfg: Config, scan: SyntheticScan) -> ScaleCheck:
    """The scale check of the scene the config describes, about the rotation axis as for a cylindrical_scan folder
    (capture.scan_scale): the object's largest horizontal radius against synthetic.camera_distance_mm,
    synthetic.height_step_mm and the candidate lights of selection.grid."""
    s, axis = cfg.synthetic, "the rotation axis"
    if scan.object is None:
        radius = max(scan.axes[0], scan.axes[2])
        obj = ObjectSize(radius, "config", "synthetic.size_mm", "multiply it by {factor:g}", axis)
    else:
        radius = float(np.hypot(scan.object.vertices[:, 0], scan.object.vertices[:, 2]).max())
        obj = ObjectSize(
            radius,
            "config",
            f"the {s.object} mesh's lengths (mm, its own)",
            "give the rig's lengths in mm",
            axis,
        )
    grid_fix = "write selection.grid.spacing_mm, radial_mm, center_lateral_mm and center_vertical_mm in mm"
    refs = [
        Reference.of("camera", "config", "synthetic.camera_distance_mm", s.camera_distance_mm),
        Reference.of("step", "config", "synthetic.height_step_mm", s.height_step_mm),
        Reference.of(
            "light", "config", "selection.grid candidates[{i}]", head_distances(scan.candidate_positions()), grid_fix
        ),
    ]
    return check_scale(obj, refs)


def stand_in_geometry(
    cfg: Config, folder: Path, stages: Stages, log: Log
) -> tuple[SyntheticScan, ScanGeometry, list[str]]:
    """The synthetic object of cfg scanned into `folder` (range image, truth; no texture) and its geometry read back,
    with the scale check's warnings (a ConfigError where the config's lengths disagree by orders of magnitude)."""
    with stages.stage("synthetic scan"):
        scan = SyntheticScan(
            cfg.synthetic, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa, threads=cfg.threads
        )
        scan.saturation_level = cfg.capture.saturation_level
        scale_warnings = synthetic_scale_check(cfg, scan).enforce(ConfigError)
        scan.write_geometry(folder)
    log(f"synthetic {cfg.synthetic.object} written to {folder}")
    with stages.stage("geometry"):
        geom = CylindricalScanLoader().load_geometry(
            folder, cfg, check_scale=False
        )  # checked above, in the config's terms
    return scan, geom, scale_warnings


def synthetic_capture(cfg: Config, out: Path, stages: Stages, log: Log) -> tuple[Capture, SelectionResult | None]:
    """Render cfg.synthetic into out/capture and load it; the light selection (None when disabled)."""
    folder = out / "capture"
    scan, geom, scale_warnings = stand_in_geometry(cfg, folder, stages, log)
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
    capture.warnings[:0] = scale_warnings
    return capture, selection
