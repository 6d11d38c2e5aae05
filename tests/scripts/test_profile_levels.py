"""scripts/profile_levels.py: its tiny mode profiles a photon fit of the tiny fold stage by stage."""

import json

import pytest
from conftest import load_script

prof = load_script("profile_levels")


def test_tiny_mode_profiles_every_stage_of_the_photon_fit(tiny_fold_run, tmp_path, capsys):
    argv = ["--tiny", "--capture", str(tiny_fold_run / "capture"), "--out", str(tmp_path)]
    assert prof.main(argv) == 0
    assert "| refresh > cache > tracing |" in capsys.readouterr().out
    report = json.loads((tmp_path / "profile.json").read_text())
    stages = report["stages"]
    for name in ("radiosity prepare > form factors", "refresh > cache > reduction into the cache",
                 "refresh > cache > specular gather", "re-estimation > sigma search", "refit (LM)",
                 "final images > cache > tracing"):  # fmt: skip
        assert stages[name]["calls"] >= 1 and stages[name]["cpu_s"] >= 0, name
    assert stages["refresh"]["calls"] == len(report["photon"]["image_difference_per_refresh"]) == 2
    # every second of the run is in one stage: their wall seconds add up to the run's, outputs and loading included
    assert sum(s["wall_s"] for s in stages.values()) == pytest.approx(report["timing_s"]["total"], rel=0.05, abs=0.5)
    assert prof.time.perf_counter is not None and prof.pipeline.refine.__name__ == "refine"  # unwrapped again
