"""Plan ordering and loading, and the capture folder's crash recovery."""

import itertools
import json

import numpy as np
import pytest
from rig_helpers import assert_consistent, fast_settings

from torchrefl.errors import CaptureError, ConfigError
from torchrefl.rig.folder import CaptureFolder
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import load_plan, order_points, path_length


def _brute_force(points, start):
    best = None
    for perm in itertools.permutations(range(len(points))):
        length = path_length(points, perm, start)
        best = length if best is None else min(best, length)
    return best


@pytest.mark.parametrize("seed", range(3))
def test_order_visits_each_once_and_beats_a_shuffled_grid(seed):
    model = RigModel(fast_settings())
    pts = model.grid_positions()[:, :2]
    rng = np.random.default_rng(seed)
    shuffled = pts[rng.permutation(len(pts))]
    start = np.array([260.0, 160.0])
    order = order_points(shuffled, start)
    assert sorted(order) == list(range(len(pts)))
    ours = path_length(shuffled, order, start)
    assert ours < 0.3 * path_length(shuffled, range(len(pts)), start)
    # within 5% of a boustrophedon sweep of the 10 x 6 grid from the nearest corner (59 steps of 50 mm)
    corner = np.linalg.norm(start - np.array([225.0, 125.0]))
    assert ours <= 1.05 * (corner + 59 * 50.0)


@pytest.mark.parametrize("seed", range(4))
def test_order_is_near_optimal_on_small_sets(seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-200, 200, size=(7, 2))
    start = rng.uniform(-200, 200, size=2)
    assert path_length(pts, order_points(pts, start), start) <= 1.05 * _brute_force(pts, start)


def test_load_plan_formats(tmp_path):
    model = RigModel(fast_settings())
    sel = {"chosen": [3, 0], "positions_mm": [[-75.0, 125.0, 300.0], [-225.0, 125.0, 300.0]]}
    (tmp_path / "selection.json").write_text(json.dumps(sel))
    t = load_plan(tmp_path / "selection.json", model)
    assert [x.grid for x in t] == [(3, 0), (0, 0)]
    (tmp_path / "plan.yaml").write_text("grid: [[9, 5], [0, 1]]\n")
    t = load_plan(tmp_path / "plan.yaml", model)
    assert np.allclose(t[0].requested_mm, [225.0, -125.0, 300.0]) and t[1].grid == (0, 1)
    (tmp_path / "off.yaml").write_text("positions_mm: [[10.0, 12.5]]\n")
    t = load_plan(tmp_path / "off.yaml", model)
    assert np.allclose(t[0].requested_mm, [10.0, 12.5, 300.0]) and t[0].grid is None
    (tmp_path / "bad.yaml").write_text("grid: [[10, 0]]\n")
    with pytest.raises(ConfigError, match="bad.yaml.*grid index \\(10, 0\\) outside"):
        load_plan(tmp_path / "bad.yaml", model)
    (tmp_path / "odd.yaml").write_text("lights: 3\n")
    with pytest.raises(ConfigError, match="odd.yaml: expected a list of positions"):
        load_plan(tmp_path / "odd.yaml", model)
    with pytest.raises(ConfigError, match="nope.yaml: plan file not found"):
        load_plan(tmp_path / "nope.yaml", model)


def _entry(i):
    return {
        "index": i,
        "image": f"textures/{i:03d}.png",
        "position_mm": [i, 0, 300],
        "requested_mm": [i, 0, 300],
        "mpos": [0, 0, 0],
        "grid": None,
        "time": "2026-01-01T00:00:00Z",
    }


def test_recover_cleans_every_crash_leftover(tmp_path):
    f = CaptureFolder(tmp_path)
    f.recover()
    for i in range(3):
        (tmp_path / f"textures/.tmp-{i:03d}.png").write_bytes(b"png")
        f.commit(tmp_path / f"textures/.tmp-{i:03d}.png", _entry(i))
    (tmp_path / "textures/.tmp-003.png").write_bytes(b"half")  # crash while the camera wrote
    (tmp_path / "textures/004.png").write_bytes(b"png")  # crash after rename, before the line
    (tmp_path / "textures/001.png").unlink()  # an image removed by hand
    with open(tmp_path / "manifest.jsonl", "a") as fh:
        fh.write('{"index": 5, "image": "textures/005.p')  # torn last line
    report = CaptureFolder(tmp_path).recover()
    assert report == {"torn_lines": 1, "entries_without_image": 1, "temp_files": 1, "orphan_images": 1}
    entries = assert_consistent(tmp_path)
    assert [e["index"] for e in entries] == [0, 2]
    g = CaptureFolder(tmp_path)
    g.recover()
    assert g.next_index() == 3


def test_corrupt_manifest_line_in_the_middle_is_an_error(tmp_path):
    (tmp_path / "textures").mkdir()
    (tmp_path / "manifest.jsonl").write_text(json.dumps(_entry(0)) + "\nnot json\n" + json.dumps(_entry(1)) + "\n")
    with pytest.raises(CaptureError, match="manifest.jsonl: line 2 is not a valid manifest entry"):
        CaptureFolder(tmp_path).recover()


def test_commit_refuses_a_missing_image(tmp_path):
    f = CaptureFolder(tmp_path)
    f.recover()
    with pytest.raises(CaptureError, match="the camera wrote no image"):
        f.commit(tmp_path / "textures/.tmp-000.png", _entry(0))
    assert assert_consistent(tmp_path) == []


def test_link_scan_yaml(tmp_path):
    f = CaptureFolder(tmp_path)
    assert f.link_scan_yaml() is False
    (tmp_path / "scan.yaml").write_text("kind: cylindrical_scan\nlights: []\n")
    assert f.link_scan_yaml() is True
    assert "lights: manifest.jsonl" in (tmp_path / "scan.yaml").read_text()
    (tmp_path / "scan.yaml").write_text("kind: cylindrical_scan\nlights: [{image: a.png, position_mm: [0, 0, 1]}]\n")
    with pytest.raises(CaptureError, match="already lists lights inline"):
        f.link_scan_yaml()
