"""Candidate light positions in world coordinates for mesh_views plans: dome, gantry and file layouts."""

import json

import numpy as np
import pytest

from torchrefl.config import LightGridConfig, WorldLightsConfig
from torchrefl.errors import ConfigError
from torchrefl.planning.world_candidates import world_candidates

CUBE = np.array([[0.0, 0.0, 0.0], [2.0, 4.0, 6.0]])  # a mesh's bounding box: centre (1, 2, 3)


def test_dome_rings_about_the_mesh_centre():
    world = WorldLightsConfig(layout="dome", radius_mm=10.0, elevations_deg=[0.0, 90.0], azimuths=4)
    c = world_candidates(world, LightGridConfig(), CUBE)
    assert c.layout == "dome" and len(c) == 8 and c.gantry_mm is None
    centre = np.array([1.0, 2.0, 3.0])
    # ring 0 at elevation 0: azimuth 0 is +z, 90 is +x, 180 is -z, 270 is -x
    expected = centre + 10.0 * np.array([[0, 0, 1], [1, 0, 0], [0, 0, -1], [-1, 0, 0]])
    np.testing.assert_allclose(c.positions[:4], expected, atol=1e-9)
    np.testing.assert_allclose(c.positions[4:], np.tile(centre + [0, 10.0, 0], (4, 1)), atol=1e-9)  # the zenith


def test_gantry_nodes_on_the_plane_keep_their_gantry_coordinates():
    world = WorldLightsConfig(
        layout="gantry", gantry_origin_mm=[5.0, 0.0, 0.0], gantry_lateral=[0.0, 0.0, 2.0], gantry_vertical=[0, 1, 0]
    )
    grid = LightGridConfig(columns=3, rows=2, spacing_mm=10.0)
    c = world_candidates(world, grid, CUBE)
    # the rig's layout: column 0 is the most negative lateral, row 0 the top (vertical +5)
    np.testing.assert_allclose(c.gantry_mm[0], [-10.0, 5.0])
    np.testing.assert_allclose(c.gantry_mm[5], [10.0, -5.0])
    np.testing.assert_allclose(c.positions[0], [5.0, 5.0, -10.0])  # lateral along +z (normalised), vertical +y
    np.testing.assert_allclose(c.frame.world(c.gantry_mm), c.positions)


def test_gantry_axes_must_be_perpendicular():
    world = WorldLightsConfig(layout="gantry", gantry_lateral=[1.0, 0.0, 0.0], gantry_vertical=[1.0, 1.0, 0.0])
    with pytest.raises(ConfigError, match="gantry_vertical.*not perpendicular"):
        world_candidates(world, LightGridConfig(), CUBE)


def test_file_layout_reads_lists_and_lights_json_mappings(tmp_path):
    (tmp_path / "list.json").write_text(json.dumps([[0, 0, 100], [50, 0, 100.5]]))
    c = world_candidates(WorldLightsConfig(layout="file", file="list.json"), LightGridConfig(), CUBE, tmp_path)
    assert c.names == ("L000", "L001")
    np.testing.assert_allclose(c.positions, [[0, 0, 100], [50, 0, 100.5]])
    (tmp_path / "lights.yaml").write_text("led0: {position: [1, 2, 3], intensity: 5}\nled1: [4, 5, 6]\n")
    c = world_candidates(WorldLightsConfig(layout="file", file="lights.yaml"), LightGridConfig(), CUBE, tmp_path)
    assert c.names == ("led0", "led1")
    np.testing.assert_allclose(c.positions, [[1, 2, 3], [4, 5, 6]])


def test_file_layout_errors_name_the_file_and_the_light(tmp_path):
    (tmp_path / "bad.json").write_text(json.dumps({"led0": [0, 0]}))
    with pytest.raises(ConfigError, match=r"bad.json: light 'led0' has position \[0, 0\]"):
        world_candidates(WorldLightsConfig(layout="file", file="bad.json"), LightGridConfig(), CUBE, tmp_path)
    with pytest.raises(ConfigError, match="missing.json: candidate light file"):
        world_candidates(WorldLightsConfig(layout="file", file="missing.json"), LightGridConfig(), CUBE, tmp_path)
    with pytest.raises(ConfigError, match="selection.world.file is empty"):
        world_candidates(WorldLightsConfig(layout="file"), LightGridConfig(), CUBE, tmp_path)
