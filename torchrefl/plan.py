"""python -m torchrefl.plan CONFIG [dotted.key=value ...] [--out FILE.json | FOLDER] [--overwrite] [--quiet]

Light selection without a fit: the config's object is scanned (its synthetic stand-in: range image only, no
texture is rendered), the lights of `selection` are chosen on the light grid `selection.grid` exactly as a
synthetic run with selection.enabled chooses them, and the capture plan the rig runs
(`python -m torchrefl.rig capture --plan FILE`) is written with its coverage figure. CONFIG is a YAML file or
the name of a bundled config. Exit status: 0 done, 2 a named error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from torchrefl.config import Config, load_config
from torchrefl.core.progress import Stages
from torchrefl.errors import ConfigError, OutputError, command_status
from torchrefl.planning.capture_plan import FIGURE_FILE, PLAN_FILE, PlanFiles, choose_lights, selection_line, write_plan
from torchrefl.planning.light_selection import SelectionResult
from torchrefl.synthetic.capture import stand_in_geometry

#: where the plan goes without --out: this folder, beside the current one
DEFAULT_OUT = "plan"


@dataclass(frozen=True)
class CapturePlan:
    """A light selection and the files it was written to."""

    selection: SelectionResult
    files: PlanFiles


def plan_files(out: str | Path) -> PlanFiles:
    """The plan file and figure for --out: a .json file (figure beside it, STEM_coverage.png) or a folder."""
    out = Path(out)
    if out.suffix == ".json":
        return PlanFiles(out, out.with_name(f"{out.stem}_coverage.png"))
    if out.suffix:
        raise OutputError(f"{out}: a plan is written to a .json file or a folder, not a {out.suffix} file")
    return PlanFiles(out / PLAN_FILE, out / FIGURE_FILE)


def plan_capture(cfg: Config, out: str | Path = DEFAULT_OUT, overwrite: bool = False, log=print) -> CapturePlan:
    """Choose the lights of `cfg` for its synthetic stand-in and write the plan; an existing plan file is an
    OutputError unless `overwrite`."""
    if cfg.capture.kind != "synthetic_cylindrical":
        raise ConfigError(
            f"capture.kind: '{cfg.capture.kind}' has no geometry stand-in to plan on; the plan command needs "
            "capture.kind synthetic_cylindrical (describe the object with the synthetic section)"
        )
    files = plan_files(out)
    if files.plan.exists() and not overwrite:
        raise OutputError(f"{files.plan}: a plan is already there; pass --overwrite to replace it")
    if files.plan.parent.exists() and not files.plan.parent.is_dir():
        raise OutputError(f"{files.plan.parent}: is a file; expected a folder for the plan")
    stages = Stages(log)
    with tempfile.TemporaryDirectory(prefix="torchrefl-plan-") as tmp:
        scan, geometry, _ = stand_in_geometry(cfg, Path(tmp), stages, log)
        with stages.stage("light selection"):
            selection = choose_lights(cfg, geometry, scan.candidate_positions())
            files = write_plan(selection, files.plan, files.figure)
    return CapturePlan(selection, files)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m torchrefl.plan",
        description="Choose the light positions for CONFIG's object (no rendering, no fit) and write the capture "
        "plan the rig runs, with its coverage figure.",
    )
    parser.add_argument("config", help="YAML config file or the name of a bundled config (e.g. default)")
    parser.add_argument("overrides", nargs="*", help="dotted.key=value overrides, e.g. selection.max_lights=12")
    parser.add_argument(
        "--out",
        default=DEFAULT_OUT,
        help=f"plan file (.json; the figure beside it) or folder ({PLAN_FILE}, {FIGURE_FILE}); default: {DEFAULT_OUT}/",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing plan file")
    parser.add_argument("--quiet", action="store_true", help="no log lines on stderr (the summary is still printed)")
    args = parser.parse_intermixed_args(argv)
    log = (lambda message: None) if args.quiet else (lambda message: print(message, file=sys.stderr))

    def work() -> int:
        result = plan_capture(load_config(args.config, args.overrides), args.out, args.overwrite, log)
        files = result.files
        print(selection_line(result.selection))
        print(f"plan: {files.plan} ({len(result.selection.chosen)} lights); coverage figure: {files.figure}")
        print(f"capture it: python -m torchrefl.rig capture --plan {files.plan} --out CAPTURE_FOLDER")
        return 0

    return command_status(work)


if __name__ == "__main__":
    sys.exit(main())
