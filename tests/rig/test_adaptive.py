"""The adaptive capture loop (torchrefl.rig.adaptive) and `capture --dry-run --adaptive`."""

import json

import numpy as np
import pytest
from conftest import TINY_QUICK_SCENE

from torchrefl.errors import RigError
from torchrefl.rig.__main__ import main
from torchrefl.rig.adaptive import AdaptiveSettings, CoverageOrder, Ranking, run_adaptive
from torchrefl.train import main as train

#: a 4 x 2 grid of candidates (head frame, mm)
GRID = np.array([[x, y, 300.0] for y in (-50.0, 50.0) for x in (-150.0, -50.0, 50.0, 150.0)])


class Recorder:
    """capture and fit stand-ins: the positions asked for each round, the warm starts, a given share per round."""

    def __init__(self, shares):
        self.shares = list(shares)
        self.captured, self.starts = [], []

    def capture(self, positions):
        self.captured.append(np.asarray(positions).copy())

    def fit(self, run_dir, init_from):
        self.starts.append((run_dir.name, None if init_from is None else init_from.name))
        return {"uncertainty": {"determined_share": self.shares[len(self.starts) - 1]}}


def loop(tmp_path, shares, reachable=(1.0,) * 8, **settings):
    """The loop on GRID with the Recorder's shares; reachable: the ceiling's answer in each round (it is told the run
    folder of the round and the candidates not yet captured, recorded in rec.asked)."""
    rec = Recorder(shares)
    rec.asked = []

    def ceiling(run_dir, remaining):
        rec.asked.append((run_dir.name, len(remaining)))
        return reachable[len(rec.asked) - 1]

    lines = []
    report = run_adaptive(
        tmp_path,
        GRID,
        Ranking(GRID[::-1]),
        rec.capture,
        rec.fit,
        AdaptiveSettings(**settings),
        CoverageOrder(GRID),
        lines.append,
        ceiling,
    )
    return report, rec, lines


def test_the_loop_stops_by_its_rule_when_the_share_is_reached(tmp_path):
    report, rec, lines = loop(tmp_path, [0.2, 0.5, 0.7, 0.9], start=2, per_round=2, max_lights=8, target=0.6)
    assert report.stopped_by == "rule" and [r.lights for r in report.rounds] == [2, 4, 6]
    # the start set is the first of start_order; then the chooser's order (CoverageOrder(GRID): GRID's order)
    np.testing.assert_array_equal(rec.captured[0], GRID[[7, 6]])
    np.testing.assert_array_equal(rec.captured[2], GRID[[7, 6, 0, 1, 2, 3]])
    # each round's fit starts from the round before
    assert rec.starts == [("round_01", None), ("round_02", "round_01"), ("round_03", "round_02")]
    doc = json.loads((tmp_path / "adaptive.json").read_text())
    assert doc["stopped_by"] == "rule" and [r["determined_share"] for r in doc["rounds"]] == [0.2, 0.5, 0.7]
    assert (
        "adaptive round 3: 6 lights (+2: [50, -50], [150, -50]); determined_share 0.700 (0.70 of the reachable "
        "1.000, target 0.6); choice 0.0 s" in lines[2]
    )
    assert lines[-1] == "adaptive capture stopped by the rule after 6 lights"


def test_the_rule_is_relative_to_each_rounds_reachable_share(tmp_path):
    # the ceiling is asked each round, with that round's fit and the candidates not yet captured
    shares, reachable = [0.3, 0.46, 0.5], [0.5, 0.6, 0.5]
    report, rec, _ = loop(tmp_path, shares, reachable, start=2, per_round=2, max_lights=8, target=0.9)
    assert report.stopped_by == "rule" and [r.lights for r in report.rounds] == [2, 4, 6]
    assert [r.statistic for r in report.rounds] == pytest.approx([0.6, 0.46 / 0.6, 1.0])
    assert [r.reachable for r in report.rounds] == reachable
    assert rec.asked == [("round_01", 6), ("round_02", 4), ("round_03", 2)]


def test_a_fit_at_or_above_the_ceiling_stops_the_loop(tmp_path):
    # nothing more to gain from the grid (the prediction at or below the fit's own share): statistic 1
    report, _, _ = loop(tmp_path, [0.2, 0.2], [0.0, 0.0], start=2, per_round=2, max_lights=8, target=0.9)
    assert report.stopped_by == "rule" and report.rounds[0].statistic == 1.0


def test_the_loop_stops_by_the_budget_otherwise(tmp_path):
    report, rec, _ = loop(tmp_path, [0.1, 0.2, 0.3], start=3, per_round=2, max_lights=6, target=0.6)
    assert report.stopped_by == "budget" and [r.lights for r in report.rounds] == [3, 5, 6]  # the last round: 1 light
    assert len(rec.captured[-1]) == 6 and len({tuple(p) for p in rec.captured[-1]}) == 6


def test_the_loop_stops_when_no_candidate_is_left(tmp_path):
    report, _, _ = loop(tmp_path, [0.1, 0.2, 0.3], start=4, per_round=4, max_lights=20, target=0.9)
    assert report.stopped_by == "candidates" and report.rounds[-1].lights == len(GRID)


@pytest.mark.parametrize(
    "settings, message",
    [
        (dict(start=6, max_lights=4), r"--max-lights 4 is below --start 6"),
        (dict(start=9, max_lights=12), r"--start 9: the light grid has only 8 positions"),
        (dict(target=1.5), r"--target 1.5: expected a fraction in \(0, 1\]"),
    ],
)
def test_bad_settings_are_named_errors(tmp_path, settings, message):
    with pytest.raises(RigError, match=message):
        loop(tmp_path, [0.0], **settings)


def test_a_bad_choice_is_a_named_error(tmp_path):
    rec = Recorder([0.0, 0.0])
    with pytest.raises(RigError, match=r"the chooser returned \[3, 3\], expected 1 to 2 distinct indices into the 6"):
        run_adaptive(
            tmp_path,
            GRID,
            Ranking(GRID),
            rec.capture,
            rec.fit,
            AdaptiveSettings(start=2, per_round=2),
            lambda r, c, k: [3, 3],
            ceiling=lambda r, c: 1.0,
        )


#: the tiny quick scene, each round's fit cut short
SCENE = [f"--scene-set={kv}" for kv in TINY_QUICK_SCENE]
FIT = [f"--fit-set={kv}" for kv in ("fit.iterations=3", "output.map_lights=0", "output.export=false")]
FAST = ["--set", "light.settle_s=0", "--set", "timeouts.poll_s=0.005"]


def test_dry_run_adaptive_writes_one_folder_that_trains(tmp_path, capsys):
    out = tmp_path / "cap"
    args = ["capture", "--dry-run", "--adaptive", "--start", "2", "--per-round", "2"]  # the next-best planner
    assert main([*args, "--max-lights", "4", "--scene", "quick", "--out", str(out), *SCENE, *FIT, *FAST]) == 0
    streams = capsys.readouterr()
    assert "adaptive capture complete: stopped by the budget after 2 rounds, 4 images" in streams.out
    assert "adaptive round 1: 2 lights" in streams.err and "adaptive round 2: 4 lights" in streams.err
    doc = json.loads((out / "adaptive.json").read_text())
    assert [r["lights"] for r in doc["rounds"]] == [2, 4] and doc["stopped_by"] == "budget"
    assert all(0.0 <= r["determined_share"] <= 1.0 for r in doc["rounds"])
    assert "warm start from" in (out / "adaptive" / "round_02" / "log.txt").read_text()
    assert len((out / "manifest.jsonl").read_text().splitlines()) == 4
    # the folder is a capture like any other
    overrides = [a.split("=", 1)[1] for a in SCENE] + ["fit.iterations=3", "output.map_lights=0", "output.export=false"]
    fit_dir = tmp_path / "fit"
    assert (
        train(["quick", *overrides, "capture.kind=cylindrical_scan", f"capture.path={out}", f"output.dir={fit_dir}"])
        == 0
    )
    assert json.loads((fit_dir / "metrics.json").read_text())["lights"] == 4
    # a folder that already holds images is refused
    capsys.readouterr()
    assert main([*args, "--max-lights", "4", "--scene", "quick", "--out", str(out), *SCENE, *FIT, *FAST]) == 2
    assert "already records 4 images; the loop starts from an empty capture folder" in capsys.readouterr().err


def test_adaptive_needs_a_dry_run(capsys):
    assert main(["capture", "--adaptive", "--out", "unused"]) == 2
    assert "capture --adaptive runs in a dry run only (add --dry-run)" in capsys.readouterr().err
