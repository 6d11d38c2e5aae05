"""capture.kind synthetic_cylindrical: a synthetic object scanned into a cylindrical_scan folder, then read back.

The scene's range image and truth are written first; the lights are chosen on that geometry (when
selection.enabled), only the chosen lights' textures are rendered, and the folder is read by the
cylindrical_scan loader like any scan on disk.
"""

from __future__ import annotations

import json
from pathlib import Path

from torchrefl.capture.base import Capture, Log
from torchrefl.capture.cylindrical_scan import CylindricalScanLoader
from torchrefl.config import Config
from torchrefl.core.progress import Stages, bar
from torchrefl.planning.light_selection import SelectionResult, plot_coverage, select_for_scan
from torchrefl.synthetic.scan import SyntheticScan


def synthetic_capture(cfg: Config, out: Path, stages: Stages, log: Log) -> tuple[Capture, SelectionResult | None]:
    """Render cfg.synthetic into out/capture and load it; the light selection (None when disabled)."""
    loader = CylindricalScanLoader()
    with stages.stage("synthetic scan"):
        scan = SyntheticScan(
            cfg.synthetic, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa, threads=cfg.threads
        )
        scan.saturation_level = cfg.capture.saturation_level
        folder = scan.write_geometry(out / "capture")
    log(f"synthetic {cfg.synthetic.object} written to {folder}")
    with stages.stage("geometry"):
        geom = loader.load_geometry(folder, cfg)
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
    return capture, selection
