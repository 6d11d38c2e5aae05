"""scripts/next_best_views_compare.py: the chosen world candidates are rendered where they are (views.lights_deg)."""

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
