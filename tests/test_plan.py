"""python -m torchrefl.plan: light selection without a fit writes the plan the rig reads, with the lights a
selection-enabled synthetic run chooses for the same config."""

import json

import numpy as np
import pytest

from torchrefl.config import load_config
from torchrefl.core.progress import Stages
from torchrefl.errors import OutputError
from torchrefl.plan import _plan_views, main, plan_files
from torchrefl.rig.dry_run import match_grid, synthetic_scene
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import load_plan
from torchrefl.rig.settings import RigSettings
from torchrefl.synthetic.capture import synthetic_capture

#: the default config at a quarter of its resolution (the same object and light grid), rendered at 1 sub-sample
SMALL = [
    "synthetic.columns=128",
    "synthetic.rows=113",
    "synthetic.angle_step_deg=2.8",
    "synthetic.height_step_mm=2.24",
    "synthetic.supersample=1",
    "output.progress=false",
]


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan") / "plan"
    assert main(["default", *SMALL, "--out", str(out), "--quiet"]) == 0
    return out


def test_plan_folder_holds_the_plan_and_its_figure(planned):
    assert sorted(p.name for p in planned.iterdir()) == ["coverage.png", "selection.json"]
    assert (planned / "coverage.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_rig_reads_the_plan(planned):
    doc = json.loads((planned / "selection.json").read_text())
    model = RigModel(match_grid(RigSettings(), synthetic_scene("default", SMALL)))
    targets = load_plan(planned / "selection.json", model)
    assert len(targets) == len(doc["chosen"]) > 0
    # every planned light is a node of the rig's grid, at the node the selection chose (flat index j*columns + i)
    columns = model.grid.columns
    assert [t.grid for t in targets] == [(c % columns, c // columns) for c in doc["chosen"]]


def test_plan_chooses_the_lights_of_a_selection_enabled_run(planned, tmp_path):
    cfg = load_config("default", [*SMALL, "selection.enabled=true"])
    _, selection = synthetic_capture(cfg, tmp_path, Stages(), lambda message: None)
    doc = json.loads((planned / "selection.json").read_text())
    assert doc["chosen"] == [int(c) for c in selection.chosen]
    assert np.allclose(doc["positions_mm"], selection.positions[selection.chosen])
    run_doc = json.loads((tmp_path / "selection" / "selection.json").read_text())
    assert run_doc == doc


def test_plan_does_not_need_selection_enabled(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main(["default", *SMALL, "selection.enabled=false", "selection.num_lights=3", "--out", str(out)]) == 0
    assert len(json.loads(out.read_text())["chosen"]) == 3
    assert (tmp_path / "p_coverage.png").is_file()
    printed = capsys.readouterr().out
    assert "3 of 60 lights" in printed and str(out) in printed


def test_an_existing_plan_is_kept_without_overwrite(planned, capsys):
    before = (planned / "selection.json").read_text()
    assert main(["default", *SMALL, "--out", str(planned), "--quiet"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (planned / "selection.json").read_text() == before


def test_a_capture_without_a_stand_in_is_refused(tmp_path, capsys):
    assert main(["diligent_ball", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "capture.kind" in err and "synthetic_cylindrical" in err
    assert not (tmp_path / "p").exists()


def test_out_names_a_json_file_or_a_folder(tmp_path):
    assert plan_files(tmp_path / "a.json").figure == tmp_path / "a_coverage.png"
    assert plan_files(tmp_path / "d").plan == tmp_path / "d" / "selection.json"
    with pytest.raises(OutputError, match="plan.png"):
        plan_files(tmp_path / "plan.png")


#: configs/mesh_views.yaml's scene, small (4 cameras, a 16 x 16 atlas), with a 5 x 3 gantry of candidates
VIEWS_SMALL = [
    "views.width=160",
    "views.height=120",
    "views.focal_px=260",
    "views.cameras_per_ring=2",
    "views.camera_elevations_deg=[0,40]",
    "capture.texture_size=16",
    "selection.world.layout=gantry",
    "selection.grid.columns=5",
    "selection.grid.rows=3",
    "selection.grid.spacing_mm=100",
    "selection.max_lights=4",
]


def test_a_mesh_views_plan_pairs_lights_with_cameras_and_the_rig_reads_it(tmp_path, capsys):
    from torchrefl.synthetic.mesh_views import build_scene, write_geometry

    assert main(["mesh_views", *VIEWS_SMALL, "--out", str(tmp_path / "synthetic.json"), "--quiet"]) == 0
    assert "4 lights" in capsys.readouterr().out
    doc = json.loads((tmp_path / "synthetic.json").read_text())
    assert doc["kind"] == "mesh_views" and doc["lights_selected"] == len(doc["lights"]) == 4
    assert {im["light"] for im in doc["images"]} == {light["name"] for light in doc["lights"]}
    # each light on the gantry plane, 350 mm in front of the object's centre (the default origin)
    for light in doc["lights"]:
        assert light["position_mm"][2] == pytest.approx(350.0)
        assert light["position_mm"][:2] == pytest.approx(light["gantry_mm"])
    targets = load_plan(tmp_path / "synthetic.json", RigModel(RigSettings()))
    assert [(t.camera, t.light) for t in targets] == [(im["camera"], im["light"]) for im in doc["images"]]
    # the same scene as a capture folder (mesh and cameras.json, no photograph) gives the same plan
    cfg = load_config("mesh_views", VIEWS_SMALL)
    write_geometry(tmp_path / "folder", build_scene(cfg.views, cfg.seed))
    cfg = load_config("mesh_views", [*VIEWS_SMALL, "capture.kind=mesh_views", f"capture.path={tmp_path / 'folder'}"])
    views = _plan_views(cfg, plan_files(tmp_path / "folder.json"), Stages(lambda m: None), lambda m: None).views
    assert views.to_json() == doc


def test_a_run_folder_gets_its_next_best_lights_as_a_plan_the_rig_reads(tiny_fold_run, tmp_path, capsys):
    out = tmp_path / "next"
    assert main([str(tiny_fold_run), "--lights", "2", "--out", str(out)]) == 0
    doc = json.loads((out / "selection.json").read_text())
    assert doc["planner"] == "next_best" and len(doc["chosen"]) == 2 == len(set(doc["chosen"]))
    grid = load_config(tiny_fold_run / "config.yaml").selection.grid
    assert doc["candidates"] == grid.columns * grid.rows
    assert len(load_plan(out / "selection.json", RigModel(RigSettings()))) == 2
    report = (out / "next_best.txt").read_text()
    assert report in capsys.readouterr().out and "sigma known to 10 %" in report


def test_a_run_folder_takes_its_candidates_from_a_file(tiny_fold_run, tmp_path):
    positions = [[0.0, 0.0, 300.0], [-100.0, 50.0, 300.0], [100.0, -50.0, 300.0]]
    (tmp_path / "c.json").write_text(json.dumps({"positions_mm": positions}))
    out = tmp_path / "p.json"
    assert main([str(tiny_fold_run), "--lights", "3", "--candidates", str(tmp_path / "c.json"), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert sorted(doc["chosen"]) == [0, 1, 2] and sorted(map(tuple, doc["positions_mm"])) == sorted(
        map(tuple, positions)
    )
    assert (tmp_path / "p_report.txt").is_file()


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["{empty}", "--lights", "2"], "params.npz: missing"),
        (["{incomplete}", "--lights", "2"], "run_complete"),
        (["{missing}", "--lights", "2"], "no such run folder"),
        (["{incomplete}"], "give --lights K"),
        (["{run}", "--lights", "0"], "--lights 0: expected a number of lights >= 1"),
        (["{run}", "--lights", "2", "--candidates", "{bad}"], "expected (M, 3) light positions"),
        (["{run}", "--lights", "2", "--candidates", "{short}"], "shape (2, 2), expected (M, 3)"),
        (["{run}", "--lights", "2", "--candidates", "{nofile}"], "no such file"),
    ],
)
def test_next_best_errors_are_named(tmp_path, capsys, argv, expected):
    from conftest import write_grid_run

    (tmp_path / "empty").mkdir()
    grid = np.zeros((2, 2, 3))
    grid[..., 2] = 1.0
    write_grid_run(tmp_path / "run", grid, grid)
    write_grid_run(tmp_path / "incomplete", grid, grid)
    (tmp_path / "incomplete" / "run_complete.json").unlink()
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "short.txt").write_text("1, 2\n3, 4\n")
    names = dict(empty="empty", incomplete="incomplete", missing="missing", run="run", bad="bad.json")
    names.update(short="short.txt", nofile="none.npy")
    args = [a.format(**{k: str(tmp_path / v) for k, v in names.items()}) for a in argv]
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    assert expected in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_run_whose_config_file_named_its_capture_relatively_is_planned_from_any_folder(
    tiny_fold_run, tmp_path, monkeypatch
):
    """capture.path relative to the config file's folder: the run folder's config.yaml records it absolute, so a
    reader of the run (the planner here) finds the capture from another working folder."""
    import yaml

    from torchrefl.train import main as train

    (tmp_path / "scan").symlink_to(tiny_fold_run / "capture", target_is_directory=True)
    data = yaml.safe_load((tiny_fold_run / "config.yaml").read_text())
    data["capture"].update(kind="cylindrical_scan", path="../scan")
    data["output"]["dir"] = str(tmp_path / "run")
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "fold.yaml").write_text(yaml.safe_dump(data))
    assert train([str(tmp_path / "configs" / "fold.yaml"), "fit.model=local", "--quiet"]) == 0
    recorded = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["capture"]["path"]
    assert recorded == str(tmp_path / "configs" / ".." / "scan")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert main([str(tmp_path / "run"), "--lights", "1", "--out", str(tmp_path / "next.json")]) == 0
    assert len(json.loads((tmp_path / "next.json").read_text())["chosen"]) == 1
