"""scripts/next_best_views_compare.py: the chosen world candidates are rendered where they are (views.lights_deg)."""

import re

import numpy as np
from conftest import load_script

from torchrefl.config import load_config
from torchrefl.planning.world_candidates import world_candidates
from torchrefl.synthetic.mesh_views import build_scene

compare = load_script("next_best_views_compare")


def test_the_scene_s_lights_stand_at_the_chosen_dome_candidates():
    cfg = load_config(str(compare.CONFIG))
    v = build_scene(cfg.views, cfg.seed).object.mesh.vertices
    centre = (v.min(0) + v.max(0)) / 2
    dome = world_candidates(cfg.selection.world, cfg.selection.grid, v).positions
    chosen = dome[[0, 13, 30, 47]]  # one of each ring (elevations -30, 0, 30, 60 deg)
    cfg = load_config(str(compare.CONFIG), compare.lights_overrides(chosen, centre))
    lights = build_scene(cfg.views, cfg.seed).lights
    assert cfg.views.lights_per_view == 4
    np.testing.assert_allclose([light.position for light in lights], chosen, atol=1e-6)


def test_tiny_mode_plans_in_rounds_from_each_round_s_fit(tmp_path, capsys):
    assert compare.main(["--tiny", "--per-round", "1", "--out", str(tmp_path)]) == 0
    log = capsys.readouterr().err
    rounds = [line for line in log.splitlines() if "planned" in line]
    assert len(rounds) == 2  # one light planned from the 2-light fit, one more from the 3-light fit
    first, second = (re.search(r"planned \[(.*?)\] after \[(.*?)\]", line).groups() for line in rounds)
    assert second[1] == f"{first[1]}, {first[0]}"  # the second round plans after the start and the first round's light
    for lights in (3, 4):
        assert (tmp_path / "seed_0" / f"planner_{lights}" / "run_complete.json").is_file()
