"""scripts/relight_holdout.py on the tiny mesh_views run its tiny mode fits (conftest.tiny_views_run, shared with
the planner's tests): it relights the held-out image."""

import re

from conftest import load_script

relight = load_script("relight_holdout")


def test_the_tiny_run_s_held_out_image_is_relit(capsys, tiny_views_run):
    assert relight.main([str(tiny_views_run)]) == 0
    out = capsys.readouterr().out
    assert "(synthetic_mesh_views): fit's held-out error " in out
    assert [float(v) >= 0 for v in re.findall(r"relit ([0-9.]+) DN", out)] == [True]
