"""`python -m torchrefl.plan RUN_DIR --lights K [--candidates FILE]`: the next-best lights of a finished run
(planning.next_best) as a capture plan the rig runs (`python -m torchrefl.rig capture --plan FILE`: its
`positions_mm`, written by planning.capture_plan's writer) and a short report (the chosen lights, their predicted
gains, the predicted share of the estimated texels with sigma known to 10 % before and after).

Candidates: the run config's light grid (selection.grid) by default, or a file of head-frame positions in mm: a
.npy array (M, 3), a text file of M rows of 3 numbers (numpy.loadtxt: spaces or commas, # comments), or a .json
list of [lateral, vertical, radial] or a mapping with `positions_mm` (a plan file).

A mesh_views or synthetic_mesh_views run (planning.views_run_scene) is planned in world coordinates: its
candidates are the config's selection.world positions by default, or the file's positions read as world [x, y, z]
mm (named L000, L001, ...); its plan is a mesh_views plan (`kind: mesh_views`: the chosen lights' world
position_mm, and gantry_mm on a gantry layout, and one image per camera that sees the object for each light).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchrefl.core.atomic_files import atomic_write_text
from torchrefl.errors import ConfigError, OutputError
from torchrefl.planning.capture_plan import PLAN_FILE, PlanFiles, write_plan
from torchrefl.planning.next_best import NextBest, check_candidates, choose
from torchrefl.planning.scenes import load_planning_scene
from torchrefl.planning.views_run_scene import ViewsRunScene
from torchrefl.planning.views_selection import plan_lights
from torchrefl.planning.world_candidates import WorldCandidates

#: the report's name in a plan folder (beside a .json plan: STEM_report.txt)
REPORT_FILE = "next_best.txt"


@dataclass(frozen=True)
class NextBestPlan:
    """The planner's choice and where it was written: the plan file and the report."""

    result: NextBest
    plan: Path
    report: Path


def read_candidates(path: str | Path) -> np.ndarray:
    """(M, 3) candidate positions from a file (module docstring); ConfigError naming the file otherwise."""
    path = Path(path)
    where = f"--candidates {path}"
    if not path.is_file():
        raise ConfigError(f"{where}: no such file (expected light positions, .npy, .json or text, in mm)")
    try:
        if path.suffix == ".npy":
            data = np.load(path, allow_pickle=False)
        elif path.suffix == ".json":
            data = json.loads(path.read_text())
            data = data.get("positions_mm") if isinstance(data, dict) else data
        else:
            data = np.loadtxt(path, delimiter="," if "," in path.read_text() else None, ndmin=2)
        data = np.asarray(data, dtype=np.float64)
    except (ValueError, TypeError, OSError) as exc:
        raise ConfigError(f"{where}: unreadable ({exc}); expected (M, 3) light positions in mm") from None
    return check_candidates(data, where)


def listed_candidates(positions: np.ndarray) -> WorldCandidates:
    """Candidate world positions (M, 3) from a --candidates file, named L000, L001, ... in their order."""
    return WorldCandidates("file", tuple(f"L{k:03d}" for k in range(len(positions))), positions)


def views_plan(scene: ViewsRunScene, result: NextBest, candidates: WorldCandidates) -> dict:
    """The plan file of a mesh_views run's next-best choice among candidates: the prediction (NextBest.to_json,
    without the scan's head-frame positions_mm) and a mesh_views plan the rig reads (planning.views_selection's
    keys: kind, layout, gantry, lights; images: each chosen light with every camera that sees the object)."""
    doc = result.to_json()
    doc.pop("positions_mm")
    names = [candidates.names[p] for p in result.chosen]
    cameras = scene.meta.cameras.names
    doc.update(
        {
            "kind": "mesh_views",
            "layout": candidates.layout,
            "gantry": candidates.frame.to_json() if candidates.frame is not None else None,
            "lights": plan_lights(candidates, result.chosen),
            "images": [{"camera": cameras[c], "light": n} for n in names for c in scene.cameras],
        }
    )
    return doc


def report_files(out: str | Path) -> tuple[Path, Path]:
    """The plan file and report for --out: a .json file (report beside it, STEM_report.txt) or a folder."""
    out = Path(out)
    if out.suffix == ".json":
        return out, out.with_name(f"{out.stem}_report.txt")
    if out.suffix:
        raise OutputError(f"{out}: a plan is written to a .json file or a folder, not a {out.suffix} file")
    return out / PLAN_FILE, out / REPORT_FILE


def report_text(run_dir: Path, result: NextBest) -> str:
    """The report: one line per chosen light, then the predicted shares before and after."""
    lines = [f"next-best lights for {run_dir}: {len(result.chosen)} of {len(result.candidates)} candidates"]
    lines.append(f"  gain: {result.score}")
    for i, (m, g) in enumerate(zip(result.chosen, result.gain)):
        pos = ", ".join(f"{x:g}" for x in result.candidates[m])
        lines.append(
            f"  {i + 1}. candidate {m} at [{pos}] mm: gain {g:.1f}; then sigma known to 10 % at "
            f"{result.sigma_known[i + 1]:.1%} of the estimated texels, Ps and sigma at {result.both_known[i + 1]:.1%}"
        )
    lines.append(
        f"predicted share of the estimated texels with sigma known to 10 %: {result.sigma_known[0]:.1%} now, "
        f"{result.sigma_known[-1]:.1%} after; Ps and sigma: {result.both_known[0]:.1%} now, "
        f"{result.both_known[-1]:.1%} after"
    )
    return "\n".join(lines) + "\n"


def plan_next_best(
    run_dir: str | Path, k: int, candidates: str | Path | None = None, out: str | Path = "plan", overwrite=False
) -> NextBestPlan:
    """Choose k next-best lights for the run in run_dir among the candidates (file; None: the run's selection.grid)
    and write the plan and the report; an existing plan file is an OutputError unless `overwrite`."""
    if int(k) < 1:
        raise ConfigError(f"--lights {k}: expected a number of lights >= 1")
    plan, report = report_files(out)
    if plan.exists() and not overwrite:
        raise OutputError(f"{plan}: a plan is already there; pass --overwrite to replace it")
    positions = read_candidates(candidates) if candidates is not None else None
    scene = load_planning_scene(run_dir)
    if isinstance(scene, ViewsRunScene):
        world = scene.world_candidates() if positions is None else listed_candidates(positions)
        result = choose(scene, world.positions, k)
        doc = views_plan(scene, result, world)
    else:
        result = choose(scene, scene.default_candidates() if positions is None else positions, k)
        doc = result.to_json()
    files: PlanFiles = write_plan(None, plan, None, doc)
    atomic_write_text(report, report_text(Path(run_dir), result))
    return NextBestPlan(result, files.plan, report)
