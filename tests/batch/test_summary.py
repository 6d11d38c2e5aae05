"""The summary files: one row per capture in summary.json and summary.csv, and the command's last line."""

import csv

from torchrefl.batch.summary import CSV, Row, last_line, read_summary, row_of, write_summary


def test_rows_round_trip_through_json_and_csv(tmp_path):
    metrics = {
        "model": "photon",
        "holdout": {"mean_abs_diff_8bit": 1.5, "rmse_8bit": 2.0},
        "ground_truth": {"pd_rmse": 0.1},
    }
    rows = [row_of("a", "complete", tmp_path / "a", metrics, 12.345), Row("b", "failed", "x", error="bad input")]
    write_summary(tmp_path, rows)
    assert read_summary(tmp_path) == rows
    table = list(csv.DictReader((tmp_path / CSV).open()))
    assert [r["name"] for r in table] == ["a", "b"]
    assert table[0]["model"] == "photon" and table[0]["seconds"] == "12.35" and table[0]["pd_rmse"] == "0.1"
    assert table[0]["holdout_mean_abs_diff_8bit"] == "1.5" and table[1]["error"] == "bad input"
    assert not any(p.name.startswith(".tmp-") for p in tmp_path.iterdir())


def test_the_last_line_counts_the_failed():
    ok, skipped, bad = Row("a", "complete", "a"), Row("b", "skipped", "b"), Row("c", "failed", "c", error="e")
    assert last_line([ok, skipped, bad]) == "1 of 3 captures failed (summary.csv has each one's error)"
    assert last_line([ok, skipped]) == "all 2 captures complete (1 already complete, skipped)"
