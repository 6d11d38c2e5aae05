"""scripts/relight_holdout.py: its tiny mode fits a tiny mesh_views capture and relights its held-out image."""

import re

from conftest import load_script

relight = load_script("relight_holdout")


def test_tiny_mode_relights_the_held_out_image(capsys):
    assert relight.main(["--tiny"]) == 0
    out = capsys.readouterr().out
    assert "(synthetic_mesh_views): fit's held-out error " in out
    assert [float(v) >= 0 for v in re.findall(r"relit ([0-9.]+) DN", out)] == [True]
