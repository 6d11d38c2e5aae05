"""A light selection as a capture plan: the lights chosen for a config, written as the plan file the rig runs
(`selection.json`, read by torchrefl.rig.plan.load_plan: a scan's head-frame `positions_mm`, or a mesh_views
plan's `lights` and `images`, planning.views_selection) and the coverage figure.

A synthetic run with selection.enabled (torchrefl.synthetic.capture) and the plan command (torchrefl.plan) both
choose and write through here, so the two give the same lights for the same config.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchrefl.config import Config
from torchrefl.core.atomic_files import atomic_file
from torchrefl.planning.light_selection import SelectionResult, plot_coverage, select_for_scan

#: names of the plan and its figure in a folder (a run's selection/, or the plan command's --out folder)
PLAN_FILE = "selection.json"
FIGURE_FILE = "coverage.png"


@dataclass(frozen=True)
class PlanFiles:
    """Where a plan was written: the plan file (JSON) and its coverage figure (PNG; None: none written)."""

    plan: Path
    figure: Path | None


def choose_lights(cfg: Config, geometry, candidates: np.ndarray) -> SelectionResult:
    """The lights of cfg.selection chosen among candidate head-frame positions (P, 3) mm for a scan's geometry."""
    return select_for_scan(geometry, candidates, cfg.selection, cfg.reflectance, cfg.geometry.shadow_offset_mm)


def write_plan(
    selection: SelectionResult | None, plan: Path, figure: Path | None, doc: dict | None = None
) -> PlanFiles:
    """Write the selection as a plan file (whole or not at all) and its coverage figure; the folders are made.
    doc: the plan file's document (default: selection.to_json(); a mesh_views plan's ViewsSelection.to_json(), the
    next-best planner's NextBest.to_json()); figure None (and selection None, with doc): no coverage figure."""
    plan = Path(plan)
    plan.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(plan) as fh:
        fh.write(json.dumps(selection.to_json() if doc is None else doc, indent=2).encode("utf-8"))
    if figure is not None:
        figure = Path(figure)
        figure.parent.mkdir(parents=True, exist_ok=True)
        plot_coverage(selection, figure)
    return PlanFiles(plan, figure)


def selection_line(selection: SelectionResult) -> str:
    """One line: how many lights were chosen and the coverage they reach against all candidates'."""
    t = selection.table()
    return (
        f"light selection: {t['lights_selected']} of {t['candidates']} lights ({t['lights_for_diffuse']} for "
        "diffuse); "
        f"diffuse coverage {t['diffuse_coverage']:.1%} (all: {t['diffuse_coverage_all_candidates']:.1%}), "
        f"specular {t['specular_coverage']:.1%} (all: {t['specular_coverage_all_candidates']:.1%})"
    )
