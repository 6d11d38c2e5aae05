"""scripts/bench_tradeoff.py: its tiny mode fits the tiny fold at two points and writes the table and plot."""

import json

from conftest import load_script

trade = load_script("bench_tradeoff")


def test_pareto_front():
    assert trade.pareto([1, 2, 3, 4], [4, 3, 3.5, 1]).tolist() == [True, True, False, True]


def test_tiny_mode_writes_the_table(tmp_path):
    assert trade.main(["--tiny", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "tradeoff.json").read_text())
    assert [(r["level"], r["model"]) for r in rows] == [("local", "local"), ("photon", "photon")]
    assert all(r["time_s"] > 0 and r["pd_rmse"] is not None for r in rows)
    assert (tmp_path / "tradeoff.png").stat().st_size > 0
