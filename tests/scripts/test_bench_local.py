"""scripts/bench_local.py: its tiny mode runs Method I and times the Embree stages against bare Embree."""

import json

from conftest import load_script

bench = load_script("bench_local")


def test_tiny_mode_times_the_stages_and_the_embree_rates(tmp_path, capsys):
    assert bench.main(["--tiny", "--threads", "1", "--out", str(tmp_path)]) == 0
    assert "Method I pipeline" in capsys.readouterr().out
    report = json.loads((tmp_path / "bench_local.json").read_text())
    assert [r["stage"] for r in report["embree"]] == ["light selection (60 candidates)", "shadow rays (12 lights)"]
    assert all(r["rays"] > 0 and r["raw_1thread_rays_per_s"] > 0 for r in report["embree"])
