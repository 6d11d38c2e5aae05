"""scripts/next_best_compare.py: the averaging and the target's reading on known rows, and its tiny mode runs both
selectors end to end."""

import json

import pytest
from conftest import load_script

compare = load_script("next_best_compare")


def rows():
    R = compare.Row
    return [
        R("coverage", 1, 3, 0.20, 0.10, 0.3, 0.2, 5),
        R("coverage", 2, 3, 0.10, 0.30, 0.3, 0.2, 5),
        R("coverage", 1, 9, 0.02, 0.02, 0.1, 0.1, 9),
        R("coverage", 2, 9, 0.04, 0.02, 0.1, 0.1, 9),
        R("planner", 1, 5, 0.04, 0.01, 0.1, 0.1, 7),
        R("planner", 2, 5, 0.04, 0.05, 0.1, 0.1, 7),  # mean sigma 3 % > coverage's 2 %
        R("planner", 1, 6, 0.01, 0.02, 0.1, 0.1, 8),
        R("planner", 2, 6, 0.03, 0.02, 0.1, 0.1, 8),
    ]


def test_curves_average_over_seeds():
    curves = compare.mean_curves(rows())
    assert curves["coverage"][3] == pytest.approx((0.15, 0.2, 2))
    ps, sigma, seeds = curves["planner"][5]
    assert abs(ps - 0.04) < 1e-12 and abs(sigma - 0.03) < 1e-12 and seeds == 2


def test_a_run_without_measured_texels_is_left_out_of_the_mean():
    R = compare.Row
    none = [R("coverage", 1, 3, None, None, 0.9, 1.1, 0), R("coverage", 2, 3, 0.1, 0.2, 0.5, 0.6, 10)]
    assert compare.mean_curves(none)["coverage"][3] == pytest.approx((0.1, 0.2, 2))
    assert "| 3 | - | - |" in compare.table(compare.mean_curves(none[:1]))


def test_the_planner_reaches_the_reference_where_both_errors_are_at_most_its():
    assert compare.planner_reach(compare.mean_curves(rows()), 9)[0] == 6
    assert compare.planner_reach(compare.mean_curves(rows()), 3)[0] == 5
    assert compare.planner_reach(compare.mean_curves(rows()), 4) == (None, None)


def test_the_paired_table_averages_the_seeds_and_leaves_empty_sets_out():
    P = compare.Paired
    rows = [P(1, 6, 100, 0.02, 0.04, 0.03, 0.01), P(2, 6, 300, 0.04, 0.02, 0.01, 0.03), P(1, 7, 0, *[float("nan")] * 4)]
    text = compare.paired_table(rows, 9)
    assert "| 6 | 200 | 3.00% | 3.00% | 2.00% | 2.00% |" in text
    assert "| 7 | 0 | - | - | - | - |" in text


def test_tiny_mode_fits_both_selectors(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert compare.main(["--tiny", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| lights | coverage-greedy Ps |" in text and "the planner reaches" in text
    assert "the texels both the planner's run and coverage-greedy's 3-light run measured" in text
    assert len(compare.paired_rows(out, 3)) == 1 and "| 4 |" in text.split("measured (glossy)")[1]
    got = json.loads((out / "results.json").read_text())
    assert {(r["selector"], r["lights"]) for r in got} == {("coverage", 3), ("planner", 4)}
    assert (out / "next_best.png").stat().st_size > 0
