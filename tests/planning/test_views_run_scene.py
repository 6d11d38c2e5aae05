"""planning.views_run_scene on the tiny synthetic mesh_views run (conftest.tiny_views_run: an ellipsoid, 4 cameras,
8 images of 6 lights, image 1 held out): a mesh_views run read back for the next-best light planner."""

import copy
import json

import numpy as np
import pytest
import torch

from torchrefl.capture.mesh_views import load_views_observations
from torchrefl.config import load_config
from torchrefl.core.rays import RayTracer
from torchrefl.errors import ConfigError
from torchrefl.plan import main
from torchrefl.planning.next_best import choose
from torchrefl.planning.next_best_plan import plan_next_best
from torchrefl.planning.scenes import load_planning_scene


@pytest.fixture(scope="module")
def scene(tiny_views_run):
    return load_planning_scene(tiny_views_run)


def test_the_run_s_own_images_are_predicted_as_the_loader_reads_them(scene):
    cfg = copy.deepcopy(scene.cfg)
    cfg.capture.light_subset = scene.fitted
    tracer = RayTracer(scene.geometry.mesh.vertices, scene.geometry.mesh.faces, threads=1)
    loaded = load_views_observations(scene.meta, scene.geometry, tracer, cfg, lambda m: None)[0]
    predicted = next(iter(scene.fitted_observations(len(scene.fitted))))
    assert scene.fitted == [0, 2, 3, 4, 5, 6, 7]  # images.json's 8 images but the held-out image 1
    # the loader's valid also drops saturated and masked pixels, which the planner predicts from the estimate
    assert torch.equal(predicted.valid, loaded.valid | loaded.saturated)
    assert torch.equal(predicted.shadowed, loaded.shadowed)  # at every lit texel, seen or not (the emitters)
    assert predicted.valid.any(1).all()
    for key in ("light_dir", "falloff", "view_dir", "light_intensity", "lobe_spread"):
        torch.testing.assert_close(getattr(predicted, key), getattr(loaded, key).to(predicted.falloff.dtype))
    assert (predicted.lobe_spread[..., :2] > 0).any()  # the lobe is predicted over the footprint, as it is fitted


def test_a_candidate_is_photographed_by_every_camera_that_sees_the_object(scene):
    centre = scene.geometry.mesh.vertices.mean(0)
    cameras = scene.meta.cameras.centres().numpy()
    obs = scene.observations(np.stack([cameras[0], cameras[2]]) * 1.2 - 0.2 * centre)
    assert scene.images_per_light == 4 and obs.num_lights == 8
    # images 0 and 6 (light 0 at camera 0, light 1 at camera 2): the light beside a camera lights what it sees
    seen = np.stack([v.seen for v in scene.views])
    assert (obs.valid[[0, 6]].numpy() == seen[[0, 2]]).mean() > 0.95


def test_a_light_inside_the_object_gains_nothing_and_a_light_beside_a_camera_ranks_first(scene):
    centre = scene.geometry.mesh.vertices.mean(0)
    beside = scene.meta.cameras.centres().numpy()[0] * 1.2 - 0.2 * centre  # beyond camera 0, facing the object
    result = choose(scene, np.stack([centre, beside]), 2)
    assert result.chosen == [1, 0]
    assert result.gain[0] > 1.0 and result.gain[1] == 0.0


def test_the_plan_of_a_mesh_views_run_lists_world_lights_and_an_image_per_camera(tiny_views_run, tmp_path, capsys):
    assert main([str(tiny_views_run), "--lights", "2", "--out", str(tmp_path / "plan.json")]) == 0
    doc = json.loads((tmp_path / "plan.json").read_text())
    assert doc["kind"] == "mesh_views" and doc["layout"] == "dome" and "positions_mm" not in doc
    assert [light["name"] for light in doc["lights"]] == [f"L{c:03d}" for c in doc["chosen"]]
    names = [light["name"] for light in doc["lights"]]
    assert [(im["camera"], im["light"]) for im in doc["images"]] == [
        (c, n) for n in names for c in ("cam00", "cam01", "cam02", "cam03")
    ]
    assert "next-best lights for" in capsys.readouterr().out
    assert (tmp_path / "plan_report.txt").is_file()


def test_a_run_of_another_kind_is_named(tiny_views_run, tmp_path, monkeypatch):
    from torchrefl.planning import scenes

    cfg = copy.deepcopy(load_config(tiny_views_run / "config.yaml"))
    cfg.capture.kind = "photometric_stereo"  # a run's config.yaml is hashed in its marker: read it as another kind
    monkeypatch.setattr(scenes, "load_config", lambda path: cfg)
    with pytest.raises(ConfigError, match="capture.kind is 'photometric_stereo'; the next-best light planner reads"):
        plan_next_best(tiny_views_run, 1, out=tmp_path / "plan")
