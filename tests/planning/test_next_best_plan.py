"""planning.next_best_plan: the candidates file formats, where the plan and report go, and a mesh_views run's plan."""

import json

import numpy as np
import pytest

from torchrefl.config import load_config
from torchrefl.errors import ConfigError, OutputError
from torchrefl.planning.next_best import choose
from torchrefl.planning.next_best_plan import read_candidates, report_files, views_plan
from torchrefl.planning.scenes import load_planning_scene
from torchrefl.planning.world_candidates import world_candidates
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import load_plan
from torchrefl.rig.settings import RigSettings

POSITIONS = [[-25.0, 25.0, 300.0], [75.0, -125.0, 300.0]]


@pytest.mark.parametrize(
    "name, write",
    [
        ("c.npy", lambda p: np.save(p, np.array(POSITIONS))),
        ("c.txt", lambda p: p.write_text("# lateral vertical radial\n-25 25 300\n75 -125 300\n")),
        ("c.csv", lambda p: p.write_text("-25, 25, 300\n75, -125, 300\n")),
        ("c.json", lambda p: p.write_text(json.dumps(POSITIONS))),
        ("p.json", lambda p: p.write_text(json.dumps({"positions_mm": POSITIONS, "chosen": [3, 7]}))),
    ],
)
def test_every_candidates_format_gives_the_positions(tmp_path, name, write):
    write(tmp_path / name)
    assert read_candidates(tmp_path / name).tolist() == POSITIONS


@pytest.mark.parametrize(
    "text, fragment",
    [("[]", "shape (0,)"), ('{"chosen": [1]}', "shape ()"), ("[[1, 2, NaN]]", "finite"), ("[[1, 2, 3]", "unreadable")],
)
def test_a_malformed_candidates_file_is_named(tmp_path, text, fragment):
    (tmp_path / "c.json").write_text(text)
    with pytest.raises(ConfigError, match="--candidates") as err:
        read_candidates(tmp_path / "c.json")
    assert fragment in str(err.value)


def test_the_report_goes_beside_a_json_plan_or_into_the_folder(tmp_path):
    assert report_files(tmp_path / "a.json") == (tmp_path / "a.json", tmp_path / "a_report.txt")
    assert report_files(tmp_path / "d") == (tmp_path / "d" / "selection.json", tmp_path / "d" / "next_best.txt")
    with pytest.raises(OutputError, match="not a .png file"):
        report_files(tmp_path / "a.png")


def test_the_next_best_plan_of_a_mesh_views_run_on_a_gantry_is_one_the_rig_reads(tiny_views_run, tmp_path):
    scene = load_planning_scene(tiny_views_run)
    grid = ["selection.grid.columns=5", "selection.grid.rows=3", "selection.grid.spacing_mm=100"]
    sel = load_config("mesh_views", ["selection.world.layout=gantry", *grid]).selection
    world = world_candidates(sel.world, sel.grid, scene.geometry.mesh.vertices)
    doc = views_plan(scene, choose(scene, world.positions, 2), world)
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    targets = load_plan(tmp_path / "plan.json", RigModel(RigSettings()))
    assert len(targets) == 2 * len(scene.cameras) == len(doc["images"])
    assert [(t.camera, t.light) for t in targets] == [(im["camera"], im["light"]) for im in doc["images"]]
    at = {light["name"]: light["gantry_mm"] for light in doc["lights"]}
    assert [t.requested_mm[:2].tolist() for t in targets] == [at[im["light"]] for im in doc["images"]]
