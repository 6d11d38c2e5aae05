"""The next-best light planner (torchrefl.planning.next_best on a mesh_views run: planning.views_run_scene) against
the mesh_views coverage-greedy selection (planning.views_selection) on a synthetic mesh_views scene: Ps and sigma
median relative errors (against the truth) versus the number of lights, both selectors, averaged over seeds.

The scene is configs/mesh_views.yaml (its ellipsoid, its 12 cameras) at REDUCED size; the candidates are the
config's selection.world dome (48 positions, radius 350 mm = views.light_distance_mm, so a candidate is rendered
as views.lights_deg [azimuth, elevation] about the same centre), and every chosen light is photographed by every
camera (views.lights_per_view = the number of lights), as the planner assumes. A seed is the config's `seed`: it
draws the object's papers and the sensor noise (the synthetic mesh_views scene has no separate noise seed).

Per seed: coverage-greedy's order over the candidates (the plan command's selection with selection.num_lights =
the largest of --greedy; n lights are the first n), each count of --greedy fitted; the planner starts from the
coverage-greedy run with --start lights, plans --plan more at once, and each prefix is fitted. Tables and the
target's reading as scripts/next_best_compare.py (its Row, summary and plot).

    python scripts/next_best_views_compare.py [--seeds 0 1 2] [--greedy 3 4 5 6 8] [--start 3] [--plan 3]
        [--reference 8] [--out FOLDER] [dotted.key=value ...]
    python scripts/next_best_views_compare.py --tabulate A/results.json B/results.json [--reference 8]
    python scripts/next_best_views_compare.py --tiny [--per-round 1]  # a 16 x 16 atlas, 4 small views, one seed
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # next_best_compare beside this script

from next_best_compare import ROOT, Row, fit, paired_rows, paired_table, plot, row, summary  # noqa: E402
from tiny_mode import TINY_VIEWS  # noqa: E402

from torchrefl.config import load_config  # noqa: E402
from torchrefl.plan import plan_capture  # noqa: E402
from torchrefl.planning.next_best import choose  # noqa: E402
from torchrefl.planning.scenes import load_planning_scene  # noqa: E402
from torchrefl.synthetic.mesh_views import build_scene  # noqa: E402

CONFIG = ROOT / "configs" / "mesh_views.yaml"
#: half-size images at half the focal length (a texel of the 32 x 32 atlas spans as many pixels as one of the
#: config's 64 x 64 at full size), no held-out image, one thread
REDUCED = [
    "capture.texture_size=32",
    "views.width=240",
    "views.height=180",
    "views.focal_px=390",
    "fit.holdout=[]",
    "output.map_lights=0",
    "output.export=false",
    "output.progress=false",
    "threads=1",
]
#: scripts/tiny_mode.py's tiny mesh_views scene (a 16 x 16 atlas, 4 views of 96 x 72 px)
TINY = [*TINY_VIEWS, "output.export=false"]


def lights_overrides(positions: np.ndarray, centre: np.ndarray) -> list[str]:
    """views.lights_deg ([azimuth, elevation] of each world position about centre) and lights_per_view (all)."""
    d = positions - centre
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    deg = np.column_stack([np.degrees(np.arctan2(d[:, 0], d[:, 2])), np.degrees(np.arcsin(np.clip(d[:, 1], -1, 1)))])
    return [f"views.lights_deg={json.dumps(np.round(deg, 9).tolist())}", f"views.lights_per_view={len(positions)}"]


def greedy_order(base: list[str], n: int, tmp: Path) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Coverage-greedy's first n candidates (the plan command's choice), the candidates (M, 3) and the centre."""
    cfg = load_config(str(CONFIG), [*base, f"selection.num_lights={n}"])
    done = plan_capture(cfg, tmp / "greedy.json", overwrite=True, log=lambda message: None)
    v = build_scene(cfg.views, cfg.seed).object.mesh.vertices
    return list(done.selection.chosen), done.views.candidates.positions, (v.min(0) + v.max(0)) / 2


def compare_seed(args, seed: int, out: Path, log) -> list:
    """Both selectors' fits of one seed (module docstring)."""
    base = [*args.overrides, f"seed={seed}"]
    out.mkdir(parents=True, exist_ok=True)
    order, candidates, centre = greedy_order(base, max(args.greedy), out)
    log(f"seed {seed}: coverage-greedy order {order}")
    rows = []

    def fitted(selector: str, chosen: list[int]) -> None:
        lights = lights_overrides(candidates[chosen], centre)
        folder = fit(str(CONFIG), [*base, *lights], out / f"{selector}_{len(chosen)}")
        rows.append(replace(row(selector, seed, folder), lights=len(chosen)))
        log(f"seed {seed}: {selector} {len(chosen)} lights: {rows[-1]}")

    for n in sorted(set(args.greedy) | {args.start}):
        fitted("coverage", order[:n])
    if args.per_round:
        return rows + planned_in_rounds(args, seed, out, order, candidates, fitted, log, rows)
    plan = choose(load_planning_scene(out / f"coverage_{args.start}"), candidates, args.plan)
    log(f"seed {seed}: planned {plan.chosen} after {order[: args.start]}; gains {np.round(plan.gain, 1).tolist()}")
    for j in range(1, args.plan + 1):
        fitted("planner", [*order[: args.start], *plan.chosen[:j]])
    return rows


def planned_in_rounds(args, seed: int, out: Path, order, candidates, fitted, log, rows) -> list:
    """The closed loop: --per-round lights planned from the last fit, fitted, planned again, until --plan lights
    are added (the rows are appended to `rows` by `fitted`; returns nothing new)."""
    chosen, folder = list(order[: args.start]), out / f"coverage_{args.start}"
    while len(chosen) < args.start + args.plan:
        k = min(args.per_round, args.start + args.plan - len(chosen))
        plan = choose(load_planning_scene(folder), candidates, k)
        log(f"seed {seed}: planned {plan.chosen} after {chosen}; gains {np.round(plan.gain, 1).tolist()}")
        chosen += [int(c) for c in plan.chosen]
        fitted("planner", chosen)
        folder = out / f"planner_{len(chosen)}"
    return []


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="config seeds")
    parser.add_argument("--greedy", type=int, nargs="+", default=[3, 4, 5, 6, 8], help="coverage-greedy counts")
    parser.add_argument("--start", type=int, default=3, help="coverage-greedy lights the planner starts from")
    parser.add_argument("--plan", type=int, default=3, help="lights the planner adds")
    parser.add_argument("--reference", type=int, default=8, help="coverage-greedy's count the target compares with")
    parser.add_argument(
        "--per-round", type=int, default=0, help="plan this many lights, fit, plan again (0: all --plan at once)"
    )
    parser.add_argument("--out", default=None, help="folder for the runs and results.json (default: a temporary one)")
    parser.add_argument("--tabulate", nargs="+", default=None, help="no fit: the tables of these results.json files")
    parser.add_argument("--tiny", action="store_true", help="a 16 x 16 atlas, 4 views: checks that the script runs")
    parser.add_argument("overrides", nargs="*", help="dotted.key=value overrides of the config")
    args = parser.parse_args(argv)
    args.overrides = [*(TINY if args.tiny else REDUCED), *args.overrides]
    if args.tiny:
        args.seeds, args.greedy, args.start, args.reference = args.seeds[:1], [2], 2, 2
        args.plan = 2 if args.per_round else 1
    log = lambda message: print(message, file=sys.stderr, flush=True)
    if args.tabulate:
        rows = [Row(**r) for path in args.tabulate for r in json.loads(Path(path).read_text())]
        plot(rows, args.reference, Path(args.tabulate[0]).with_name("next_best_views.png"))
        paired = [p for path in args.tabulate for p in paired_rows(Path(path).parent, args.reference)]
        print(summary(rows, args.reference, len({r.seed for r in rows})))
        print(paired_table(paired, args.reference))
        return 0
    with tempfile.TemporaryDirectory(prefix="next-best-views-") as tmp:
        out = Path(args.out) if args.out else Path(tmp)
        rows = []
        for seed in args.seeds:
            rows += compare_seed(args, seed, out / f"seed_{seed}", log)
            (out / "results.json").write_text(json.dumps([asdict(r) for r in rows], indent=1))
        plot(rows, args.reference, out / "next_best_views.png")
        paired = paired_table(paired_rows(out, args.reference), args.reference)
    print(summary(rows, args.reference, len({r.seed for r in rows})))
    print(paired)
    return 0


if __name__ == "__main__":
    sys.exit(main())
