"""python -m torchrefl.plan CONFIG [dotted.key=value ...] [--out FILE.json | FOLDER] [--overwrite] [--quiet]
python -m torchrefl.plan RUN_DIR --lights K [--candidates FILE] [--out FILE.json | FOLDER] [--overwrite]

Light selection without a fit, and the capture plan the rig runs (`python -m torchrefl.rig capture --plan FILE`)
written with its coverage figure. CONFIG is a YAML file or the name of a bundled config.

With a folder instead (RUN_DIR: a finished run of a scan or of mesh_views, torchrefl.train's output.dir), the K
next-best lights for that fit (planning.next_best: the candidates whose predicted images would reduce its Ps and
sigma uncertainty most) among the config's light grid (a mesh_views run: selection.world's world positions) or the
positions in FILE (planning.next_best_plan), written as a plan and a report.

- synthetic_cylindrical: the config's object is scanned (its synthetic stand-in: range image only, no texture is
  rendered) and the lights of `selection` are chosen on the light grid `selection.grid` exactly as a synthetic run
  with selection.enabled chooses them;
- mesh_views (capture.path: a folder with the mesh and cameras.json, no photographs needed) and
  synthetic_mesh_views (the `views` scene's mesh and cameras, nothing rendered): the lights are chosen among the
  world candidates of `selection.world` over all the cameras' views (planning.views_selection), and the plan
  lists per image a camera and a light.

Exit status: 0 done, 2 a named error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from torchrefl.config import Config, load_config, resolve_path
from torchrefl.core.progress import Stages
from torchrefl.errors import ConfigError, OutputError, RunFolderError, command_status
from torchrefl.planning.capture_plan import FIGURE_FILE, PLAN_FILE, PlanFiles, choose_lights, selection_line, write_plan
from torchrefl.planning.light_selection import SelectionResult
from torchrefl.planning.next_best_plan import plan_next_best
from torchrefl.planning.views_inputs import read_plan_inputs
from torchrefl.planning.views_selection import ViewsSelection, select_for_views
from torchrefl.planning.world_candidates import world_candidates
from torchrefl.synthetic.capture import stand_in_geometry
from torchrefl.synthetic.mesh_views import build_scene, write_geometry

#: where the plan goes without --out: this folder, beside the current one
DEFAULT_OUT = "plan"
#: the capture kinds a plan can be made for
PLANNED_KINDS = ("synthetic_cylindrical", "mesh_views", "synthetic_mesh_views")


@dataclass(frozen=True)
class CapturePlan:
    """A light selection and the files it was written to; views: the mesh_views selection (None for a scan)."""

    selection: SelectionResult
    files: PlanFiles
    views: ViewsSelection | None = None


def plan_files(out: str | Path) -> PlanFiles:
    """The plan file and figure for --out: a .json file (figure beside it, STEM_coverage.png) or a folder."""
    out = Path(out)
    if out.suffix == ".json":
        return PlanFiles(out, out.with_name(f"{out.stem}_coverage.png"))
    if out.suffix:
        raise OutputError(f"{out}: a plan is written to a .json file or a folder, not a {out.suffix} file")
    return PlanFiles(out / PLAN_FILE, out / FIGURE_FILE)


def plan_capture(cfg: Config, out: str | Path = DEFAULT_OUT, overwrite: bool = False, log=print) -> CapturePlan:
    """Choose the lights of `cfg` for its synthetic stand-in or its mesh_views folder and write the plan; an
    existing plan file is an OutputError unless `overwrite`."""
    if cfg.capture.kind not in PLANNED_KINDS:
        raise ConfigError(
            f"capture.kind: '{cfg.capture.kind}' has no geometry to plan on; the plan command needs capture.kind "
            "synthetic_cylindrical (the synthetic section's object), mesh_views (a folder with the mesh and "
            "cameras.json) or synthetic_mesh_views (the views section's scene)"
        )
    files = plan_files(out)
    if files.plan.exists() and not overwrite:
        raise OutputError(f"{files.plan}: a plan is already there; pass --overwrite to replace it")
    if files.plan.parent.exists() and not files.plan.parent.is_dir():
        raise OutputError(f"{files.plan.parent}: is a file; expected a folder for the plan")
    stages = Stages(log)
    if cfg.capture.kind != "synthetic_cylindrical":
        return _plan_views(cfg, files, stages, log)
    with tempfile.TemporaryDirectory(prefix="torchrefl-plan-") as tmp:
        scan, geometry, _ = stand_in_geometry(cfg, Path(tmp), stages, log)
        with stages.stage("light selection"):
            selection = choose_lights(cfg, geometry, scan.candidate_positions())
            files = write_plan(selection, files.plan, files.figure)
    return CapturePlan(selection, files)


def _plan_views(cfg: Config, files: PlanFiles, stages: Stages, log) -> CapturePlan:
    """plan_capture for mesh_views: the folder's (or the synthetic scene's) mesh and cameras, no photograph."""
    with tempfile.TemporaryDirectory(prefix="torchrefl-plan-") as tmp:
        with stages.stage("geometry"):
            if cfg.capture.kind == "synthetic_mesh_views":
                folder = Path(tmp)
                write_geometry(folder, build_scene(cfg.views, cfg.seed))
            else:
                folder = resolve_path(cfg, cfg.capture.path)
            inputs = read_plan_inputs(folder, cfg.capture.texture_size, cfg.torch_dtype)
            s = inputs.geometry.surface
            log(f"surface: {s.num_texels} texels on the atlas; {len(inputs.cameras)} cameras")
        candidates = world_candidates(
            cfg.selection.world, cfg.selection.grid, inputs.geometry.mesh.vertices, cfg.config_dir
        )
        with stages.stage("light selection"):
            views = select_for_views(inputs.cameras, inputs.geometry, candidates, cfg, cfg.threads)
            files = write_plan(views.selection, files.plan, files.figure, views.to_json())
    return CapturePlan(views.selection, files, views)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m torchrefl.plan",
        description="Choose the light positions for CONFIG's object (no rendering, no fit) and write the capture "
        "plan the rig runs, with its coverage figure.",
    )
    parser.add_argument(
        "config", help="YAML config file or the name of a bundled config (e.g. default); or a finished run's folder"
    )
    parser.add_argument("overrides", nargs="*", help="dotted.key=value overrides, e.g. selection.max_lights=12")
    parser.add_argument(
        "--out",
        default=DEFAULT_OUT,
        help=f"plan file (.json; the figure beside it) or folder ({PLAN_FILE}, {FIGURE_FILE}); default: {DEFAULT_OUT}/",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing plan file")
    parser.add_argument("--quiet", action="store_true", help="no log lines on stderr (the summary is still printed)")
    parser.add_argument("--lights", type=int, default=None, help="RUN_DIR: the number of next-best lights to plan")
    parser.add_argument(
        "--candidates",
        default=None,
        help="RUN_DIR: candidate positions in mm, head frame for a scan, world for mesh_views (.npy, .json or text; "
        "default: the run's selection.grid, or selection.world)",
    )
    args = parser.parse_intermixed_args(argv)
    log = (lambda message: None) if args.quiet else (lambda message: print(message, file=sys.stderr))

    def work() -> int:
        if Path(args.config).is_dir() or args.lights is not None or args.candidates is not None:
            return next_best_command(args)
        result = plan_capture(load_config(args.config, args.overrides), args.out, args.overwrite, log)
        files = result.files
        print(selection_line(result.selection))
        images = f", {len(result.views.images)} images" if result.views is not None else ""
        print(f"plan: {files.plan} ({len(result.selection.chosen)} lights{images}); coverage figure: {files.figure}")
        print(f"capture it: python -m torchrefl.rig capture --plan {files.plan} --out CAPTURE_FOLDER")
        return 0

    return command_status(work)


def next_best_command(args) -> int:
    """RUN_DIR --lights K: the next-best plan (planning.next_best_plan); ConfigError for a CONFIG with --lights or
    --candidates, a RUN_DIR without --lights, overrides with a RUN_DIR."""
    if Path(args.config).is_file():
        raise ConfigError(
            f"{args.config}: --lights and --candidates plan the next lights of a finished run: give its folder "
            "(torchrefl.train's output.dir), not a config"
        )
    if not Path(args.config).is_dir():
        raise RunFolderError(f"{args.config}: no such run folder (expected the output.dir of a torchrefl.train run)")
    if args.lights is None:
        raise ConfigError(f"{args.config}: a run folder: give --lights K, the number of next-best lights to plan")
    if args.overrides:
        raise ConfigError(f"{args.config}: a run folder takes no config overrides (got {' '.join(args.overrides)})")
    done = plan_next_best(args.config, args.lights, args.candidates, args.out, args.overwrite)
    print(done.report.read_text(), end="")
    print(f"plan: {done.plan} ({len(done.result.chosen)} lights); report: {done.report}")
    print(f"capture it: python -m torchrefl.rig capture --plan {done.plan} --out CAPTURE_FOLDER")
    return 0


if __name__ == "__main__":
    sys.exit(main())
