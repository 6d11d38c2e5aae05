"""python -m torchrefl.rig {probe,home,move,capture} [--config configs/rig.yaml] [--set key=value ...]

probe   connect, print the banner, the state and GRBL's settings
home    run the homing cycle ($H)
move    move the light to a grid node (--grid I J) or a head-frame position (--mm LATERAL VERTICAL)
capture run a capture plan into a folder (resumable: run it again after any interruption); with --dry-run
        --adaptive: capture, fit, choose the next lights from the fit, refit, until a stopping rule or a budget
--dry-run (every subcommand) talks to a simulated GRBL 1.1 device on a pseudo-terminal; capture
then renders the synthetic object of a fitting config (--scene) with a simulated camera.
Streams: each command's result (probe's report, where the light is, the capture's summary) on stdout;
progress lines, warnings and errors on stderr (--quiet: warnings and errors only).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import numpy as np

from torchrefl.errors import RigError, TorchReflError
from torchrefl.rig.adaptive import AdaptiveSettings
from torchrefl.rig.board_check import check_board, check_connected_board
from torchrefl.rig.camera import ExternalCommandCamera
from torchrefl.rig.folder import CaptureFolder
from torchrefl.rig.grbl import GrblClient
from torchrefl.rig.link import SerialLink
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import load_plan, targets_from_grid, targets_from_positions
from torchrefl.rig.runner import CaptureRunner
from torchrefl.rig.settings import RigSettings, load_rig_settings


def _pair(text: str, what: str, n=(2, 3)) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in n:
        raise TorchReflError(f"{what} {text!r}: expected {' or '.join(str(k) for k in n)} comma-separated numbers")
    return vals


def _common_options() -> argparse.ArgumentParser:
    """The options every subcommand takes (settings, port, dry run, output)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", default=None, help="rig settings YAML (e.g. configs/rig.yaml); defaults otherwise")
    common.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a rig setting, e.g. --set feed_mm_min=2000 --set light.output=spindle",
    )
    common.add_argument("--port", default=None, help="serial port URL (overrides the settings' port)")
    common.add_argument(
        "--dry-run",
        action="store_true",
        help="use a simulated GRBL 1.1 device on a pseudo-terminal (and a simulated camera)",
    )
    common.add_argument(
        "--quiet", action="store_true", help="no progress lines on stderr (results, warnings and errors stay)"
    )
    common.add_argument(
        "--time-scale",
        type=float,
        default=0.01,
        help="dry run: simulated motion time / real motion time (default 0.01)",
    )
    return common


def build_parser() -> argparse.ArgumentParser:
    common = _common_options()
    p = argparse.ArgumentParser(
        prog="python -m torchrefl.rig",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("probe", parents=[common], help="connect and report banner, state and settings")
    sub.add_parser("home", parents=[common], help="run the homing cycle ($H)")
    mv = sub.add_parser("move", parents=[common], help="move the light to a grid node or position")
    where = mv.add_mutually_exclusive_group(required=True)
    where.add_argument("--grid", nargs=2, type=int, metavar=("I", "J"), help="grid column I, row J")
    where.add_argument("--mm", nargs=2, type=float, metavar=("LATERAL", "VERTICAL"), help="head-frame position, mm")
    mv.add_argument("--no-home", action="store_true", help="do not home first (the controller must be unlocked)")
    cap = sub.add_parser("capture", parents=[common], help="run a capture plan into a folder")
    _capture_options(cap)
    _adaptive_options(cap)
    return p


def _capture_options(cap: argparse.ArgumentParser) -> None:
    """capture: what to capture (a plan, positions, grid nodes, the adaptive loop), where, and the dry run's scene."""
    what = cap.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--plan", help="plan file: YAML/JSON with positions_mm or grid, or a mesh_views plan (selection.json works)"
    )
    what.add_argument("--positions", nargs="+", metavar="LAT,VERT[,RAD]", help="head-frame positions, mm")
    what.add_argument("--grid-positions", nargs="+", metavar="I,J", help="grid nodes (column,row)")
    what.add_argument("--all-grid", action="store_true", help="every node of the light grid")
    what.add_argument(
        "--adaptive",
        action="store_true",
        help="dry run: capture a start set, fit, choose the next lights from the fit, refit, until the stopping rule "
        "or the light budget (docs/rig.md)",
    )
    cap.add_argument(
        "--out", required=True, help="capture folder (cylindrical_scan layout; mesh_views for a mesh_views plan)"
    )
    cap.add_argument(
        "--scene",
        default=None,
        help="dry run: fitting config whose synthetic object is rendered (default: built-in defaults)",
    )
    cap.add_argument(
        "--scene-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="dry run: override a key of the scene config, e.g. synthetic.rows=64",
    )


def _adaptive_options(cap: argparse.ArgumentParser) -> None:
    """capture --adaptive: the loop's rounds, budget, stopping rule and fits."""
    ad = AdaptiveSettings()
    cap.add_argument("--start", type=int, default=ad.start, help=f"--adaptive: lights of the first round ({ad.start})")
    cap.add_argument(
        "--per-round", type=int, default=ad.per_round, help=f"--adaptive: lights added per round ({ad.per_round})"
    )
    cap.add_argument(
        "--max-lights", type=int, default=ad.max_lights, help=f"--adaptive: the light budget ({ad.max_lights})"
    )
    cap.add_argument(
        "--target",
        type=float,
        default=ad.target,
        help="--adaptive: stop when the share of the texels with Ps and sigma known to 10 %% reaches this fraction of "
        f"the share the next-best planner predicts with every grid light ({ad.target})",
    )
    cap.add_argument(
        "--chooser",
        choices=("next_best", "coverage"),
        default="next_best",
        help="--adaptive: next lights from the next-best-light planner (next_best) or the coverage-greedy order",
    )
    cap.add_argument(
        "--fit-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="--adaptive: override a key of every round's fit config, e.g. fit.iterations=30",
    )


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr)


def _warnings_only(msg: str) -> None:
    if msg.lstrip().startswith("WARNING"):
        _stderr(msg)


def _progress(args):
    """Where progress lines go: stderr; with --quiet only the warnings among them (board_check's notes)."""
    return _warnings_only if args.quiet else _stderr


def _client(settings: RigSettings, progress) -> GrblClient:
    t = settings.timeouts
    link = SerialLink(settings.port, settings.baudrate)
    return GrblClient(
        link,
        reply_s=t.reply_s,
        home_s=t.home_s or None,
        move_s=t.move_s,
        poll_s=t.poll_s,
        banner_s=t.banner_s,
        status_retries=t.status_retries,
        log=lambda m: progress(f"  {m}"),
    )


def _probe(client: GrblClient, settings: RigSettings, state: str) -> int:
    """Print GRBL's settings and the checks of board_check, then fail when a check failed."""
    board = client.read_settings()
    for k, v in sorted(board.items()):
        print(f"  ${k}={v:g}")
    print("board settings checked against the rig config:")
    for check in check_board(board, settings):
        print(f"  {check.line()}")
    if state == "Alarm":
        print("  locked in Alarm: run `python -m torchrefl.rig home` (or unlock with $X)")
    check_connected_board(client, settings, note=_stderr, board=board)
    return 0


def _targets(args, model: RigModel):
    if args.plan:
        return load_plan(args.plan, model)
    if args.positions:
        return targets_from_positions(model, [_pair(p, "position") for p in args.positions])
    if args.grid_positions:
        return targets_from_grid(model, [[int(v) for v in _pair(g, "grid node", (2,))] for g in args.grid_positions])
    g = model.grid
    return targets_from_grid(model, [(i, j) for j in range(g.rows) for i in range(g.columns)])


def run(args, settings: RigSettings) -> int:
    scan = None
    progress = _progress(args)
    if args.cmd == "capture" and args.adaptive and not args.dry_run:
        raise RigError(
            "capture --adaptive runs in a dry run only (add --dry-run): it fits the synthetic scene's images"
        )
    if args.cmd == "capture" and args.dry_run:
        from torchrefl.rig.dry_run import match_grid, synthetic_scene

        progress("dry run: building the synthetic scene")
        scan = synthetic_scene(args.scene, args.scene_set)
        settings = match_grid(settings, scan)
    model = RigModel(settings)
    with contextlib.ExitStack() as stack:
        if args.dry_run:
            from torchrefl.rig.dry_run import fake_device_for

            fake = stack.enter_context(fake_device_for(settings, args.time_scale))
            settings.port = fake.path
            settings.timeouts.banner_s = min(settings.timeouts.banner_s, 0.3)
            progress(f"dry run: simulated GRBL 1.1 on {fake.path}")
        client = _client(settings, progress)
        if args.cmd == "capture":
            return _capture(args, settings, model, client, scan, progress)
        axes = None
        if args.cmd == "move":  # checked against the soft limits before the port is opened
            pos = (
                model.grid_position(*args.grid) if args.grid else np.array([args.mm[0], args.mm[1], settings.radial_mm])
            )
            axes = model.target(pos, what="move")
        stack.enter_context(client.link.open())
        banner = client.connect()
        st = client.last_status
        connected = f"{settings.port}: {banner or '(no banner)'}; state {st.state}, MPos {list(st.mpos)}"
        if args.cmd == "probe":
            print(connected)
            return _probe(client, settings, st.state)
        progress(connected)
        check_connected_board(client, settings, note=_stderr)
        if args.cmd == "home" or not args.no_home:
            client.home(progress=progress)
            (print if args.cmd == "home" else progress)(f"homed: MPos {list(client.last_status.mpos)}")
        if axes is not None:
            client.move_to(axes, settings.feed_mm_min)
            st = client.wait_idle()
            print(f"reached head-frame {model.axes_to_head(st.mpos).round(3).tolist()} (MPos {list(st.mpos)})")
        return 0


def _adaptive(args, settings, model, client, scan, progress) -> int:
    """capture --adaptive (torchrefl.rig.adaptive) on the dry run's scene."""
    from torchrefl.config import load_config
    from torchrefl.rig.adaptive import (
        CoverageOrder,
        NextBestRounds,
        coverage_greedy_ranking,
        round_config,
        run_adaptive,
    )
    from torchrefl.rig.dry_run import ViewsDryScene, prepare_folder, simulated_camera
    from torchrefl.run import run as fit_run

    if isinstance(scan, ViewsDryScene):
        raise RigError("capture --adaptive: the scene is a mesh_views scene; the adaptive loop runs on a scan's scene")
    out = Path(args.out)
    folder = CaptureFolder(out)
    folder.recover()
    if folder.entries:
        raise RigError(
            f"capture --adaptive: {folder.manifest} already records {len(folder.entries)} images; the loop starts "
            "from an empty capture folder (give a new --out)"
        )
    adaptive = AdaptiveSettings(args.start, args.per_round, args.max_lights, args.target, tuple(args.fit_set))
    prepare_folder(scan, out)
    candidates = scan.candidate_positions()
    progress("adaptive capture: ranking the light grid by the coverage-greedy selection for the start set")
    ranking = coverage_greedy_ranking(load_config(args.scene, list(args.scene_set)), out, candidates)
    progress(
        f"adaptive capture: the loop stops when the share of the texels with Ps and sigma known to 10 % reaches "
        f"{adaptive.target:.0%} of the share the planner predicts with all {len(candidates)} grid lights"
    )
    runner = CaptureRunner(client, model, simulated_camera(scan), folder, settings, progress=progress)

    def fit(run_dir, init_from):
        cfg = round_config(args.scene, args.scene_set, out, run_dir, init_from, adaptive.fit_set)
        return fit_run(cfg, quiet=True, overwrite=True)

    planner = NextBestRounds()
    chooser = CoverageOrder(ranking.order) if args.chooser == "coverage" else planner.choose
    try:
        report = run_adaptive(
            out,
            candidates,
            ranking,
            lambda positions: runner.run(targets_from_positions(model, positions)),
            fit,
            adaptive,
            chooser,
            progress,
            planner.reachable,
        )
    finally:
        client.link.close()
    last = report.rounds[-1]
    share = "none" if last.reachable is None else f"{last.determined_share:.3f} of {last.reachable:.3f}"
    print(
        f"adaptive capture complete: stopped by the {report.stopped_by} after {len(report.rounds)} rounds, "
        f"{last.lights} images in {folder.manifest}; determined_share {share} reachable; {report.wall_s:.0f} s; "
        f"rounds in {out / 'adaptive.json'}, the last fit in {out / last.run}"
    )
    return 0


def _capture(args, settings, model, client, scan, progress) -> int:
    if args.adaptive:
        return _adaptive(args, settings, model, client, scan, progress)
    targets = _targets(args, model)
    folder = CaptureFolder(args.out)
    if scan is not None:
        from torchrefl.rig.dry_run import prepare_folder, simulated_camera

        prepare_folder(scan, args.out)
        camera = simulated_camera(scan)
    else:
        if not settings.camera.command:
            raise TorchReflError(
                "capture: camera.command is empty in the rig settings (set the trigger command "
                "with {path}, or use --dry-run)"
            )
        camera = ExternalCommandCamera(settings.camera.command, settings.camera.timeout_s)
    runner = CaptureRunner(client, model, camera, folder, settings, progress=progress)
    try:
        summary = runner.run(targets)
    finally:
        client.link.close()
    retried = summary.get("status_retries", 0)
    print(
        f"capture complete: {summary['captured']} new, {summary['skipped']} already recorded, "
        f"{len(folder.entries)} images in {folder.manifest}; travel {summary.get('path_mm', 0):.0f} mm"
        + (f"; {retried} status queries retried" if retried else "")
    )
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        settings = load_rig_settings(args.config, list(args.set))
        if args.port:
            settings.port = args.port
        return run(args, settings)
    except TorchReflError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: the capture folder is consistent; run the same command again to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
