"""capture.kind synthetic_cylindrical: a synthetic object scanned into a cylindrical_scan folder, then read back.

The scene's range image and truth are written first; the lights are chosen on that geometry (when
selection.enabled), only the chosen lights' textures are rendered, and the folder is read by the
cylindrical_scan loader like any scan on disk.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from torchrefl.capture.base import Capture, Log
from torchrefl.capture.cylindrical_scan import CylindricalScanLoader
from torchrefl.capture.scale_check import ObjectSize, Reference, ScaleCheck, check_scale
from torchrefl.capture.scan_scale import head_distances
from torchrefl.config import Config
from torchrefl.core.progress import Stages, bar
from torchrefl.errors import ConfigError
from torchrefl.planning.light_selection import SelectionResult, plot_coverage, select_for_scan
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


def synthetic_capture(cfg: Config, out: Path, stages: Stages, log: Log) -> tuple[Capture, SelectionResult | None]:
    """Render cfg.synthetic into out/capture and load it; the light selection (None when disabled)."""
    loader = CylindricalScanLoader()
    with stages.stage("synthetic scan"):
        scan = SyntheticScan(
            cfg.synthetic, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa, threads=cfg.threads
        )
        scan.saturation_level = cfg.capture.saturation_level
        scale_warnings = synthetic_scale_check(cfg, scan).enforce(ConfigError)
        folder = scan.write_geometry(out / "capture")
    log(f"synthetic {cfg.synthetic.object} written to {folder}")
    with stages.stage("geometry"):
        geom = loader.load_geometry(folder, cfg, check_scale=False)  # checked above, in the config's terms
    positions = candidates = scan.candidate_positions()
    selection = None
    if cfg.selection.enabled:
        with stages.stage("light selection"):
            selection = select_for_scan(geom, candidates, cfg.selection, cfg.reflectance, cfg.geometry.shadow_offset_mm)
            positions = candidates[selection.chosen]
            (out / "selection").mkdir(parents=True, exist_ok=True)
            plot_coverage(selection, out / "selection" / "coverage.png")
            (out / "selection" / "selection.json").write_text(json.dumps(selection.to_json(), indent=2))
        t = selection.table()
        log(
            f"light selection: {t['lights_selected']} of {t['candidates']} lights ({t['lights_for_diffuse']} for "
            "diffuse); "
            f"diffuse coverage {t['diffuse_coverage']:.1%} (all: {t['diffuse_coverage_all_candidates']:.1%}), "
            f"specular {t['specular_coverage']:.1%} (all: {t['specular_coverage_all_candidates']:.1%})"
        )
    with stages.stage("render textures"):
        with bar(len(positions), "render", cfg.output.progress, unit="image") as pb:
            scan.write_textures(folder, positions, progress=pb)
    with stages.stage("observations"):
        capture = loader.load(folder, cfg, log, geometry=geom)
    capture.warnings[:0] = scale_warnings
    return capture, selection
