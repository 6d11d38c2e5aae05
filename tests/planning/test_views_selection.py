"""Light selection for mesh_views on a hand-made folder (a plate and four cameras, no photographs): observation
counts over all cameras, the greedy pick and the plan's images, checked against angles worked out by hand."""

import json

import numpy as np
import pytest

from torchrefl.config import load_config
from torchrefl.errors import CaptureError
from torchrefl.planning.views_inputs import read_plan_inputs
from torchrefl.planning.views_selection import select_for_views
from torchrefl.planning.world_candidates import WorldCandidates
from torchrefl.synthetic.views_layout import look_at

# a 40 x 40 mm plate in z = 0 facing +z; 16 x 16 texels of 2.5 mm
PLATE = """v -20 -20 0
v 20 -20 0
v 20 20 0
v -20 20 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""
# A and B straight above, C low on the +x side (v = (0.936, 0, 0.351) at the centre), D looking away
CAMERAS = {
    "A": look_at("A", [0, 0, 100], [0, 0, 0], 200, 200, 300.0),
    "B": look_at("B", [0, 0, 150], [0, 0, 0], 200, 200, 300.0),
    "C": look_at("C", [80, 0, 30], [0, 0, 0], 200, 200, 300.0),
    "D": look_at("D", [0, 0, 100], [0, 0, 300], 200, 200, 300.0),
}
# 0: at camera A (half-angle <= 16 deg for A and B: strong specular; 35 deg for C); 1: below the plate (lights
# nothing); 2: grazing from -y (half-angle 72 deg with C's view at the centre: diffuse only; 42 deg for A, B)
LIGHTS = np.array([[0.0, 0.0, 100.0], [0.0, 0.0, -50.0], [0.0, -100.0, 10.0]])


@pytest.fixture
def plate(tmp_path):
    (tmp_path / "mesh.obj").write_text(PLATE)
    (tmp_path / "cameras.json").write_text(json.dumps({k: c.to_json() for k, c in CAMERAS.items()}))
    return read_plan_inputs(tmp_path, 16)


def test_counts_per_candidate_over_the_cameras(plate):
    cfg = load_config(None, ["selection.stop_ratio=1.0"])
    names = ("L000", "L001", "L002")
    views = select_for_views(plate.cameras, plate.geometry, WorldCandidates("file", names, LIGHTS), cfg)
    sel = views.selection
    # the grazing light is the only one with diffuse-only observations, the coaxial one the only specular one;
    # the light below gains nothing and is never picked
    assert sel.chosen == [2, 0] and sel.roles == ["diffuse", "specular"]
    # texels near the centre: two strong-specular observations (A and B) make them covered specularly, one
    # diffuse-only observation (C) diffusely
    x = plate.geometry.surface.positions.numpy()
    centre = np.linalg.norm(x[:, :2], axis=1) < 8.0
    assert centre.sum() > 10
    n_seen = sel.seen_texels
    assert sel.specular_curve[-1] * n_seen >= centre.sum()
    assert sel.diffuse_curve[-1] * n_seen >= centre.sum()
    # the plan's images: each chosen light with every camera that measures a texel under it (D sees nothing)
    pairs = {(im.light, im.camera) for im in views.images}
    assert pairs == {(light, cam) for light in ("L002", "L000") for cam in "ABC"}
    doc = views.to_json()
    assert doc["kind"] == "mesh_views" and "positions_mm" not in doc
    assert [light["name"] for light in doc["lights"]] == ["L002", "L000"]
    assert doc["lights"][0]["position_mm"] == [0.0, -100.0, 10.0] and doc["lights"][0]["gantry_mm"] is None


def test_a_specular_observation_needs_two_cameras(plate):
    # with camera B left out, the coaxial light gives each texel one strong-specular observation: never covered
    cfg = load_config(None, ["selection.stop_ratio=1.0"])
    keep = [0, 2, 3]
    cams = type(plate.cameras).from_arrays(
        [plate.cameras.names[k] for k in keep],
        plate.cameras.width[keep],
        plate.cameras.height[keep],
        plate.cameras.fx[keep],
        plate.cameras.fy[keep],
        plate.cameras.cx[keep],
        plate.cameras.cy[keep],
        plate.cameras.distortion[keep],
        plate.cameras.R[keep],
        plate.cameras.t[keep],
        "three cameras",
    )
    views = select_for_views(cams, plate.geometry, WorldCandidates("file", ("a", "b", "c"), LIGHTS), cfg)
    assert views.selection.all_specular == 0.0 and views.selection.all_diffuse > 0.0


def test_a_folder_without_cameras_is_refused(tmp_path):
    (tmp_path / "mesh.obj").write_text(PLATE)
    with pytest.raises(CaptureError, match="no cameras.json"):
        read_plan_inputs(tmp_path, 16)
