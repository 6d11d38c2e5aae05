"""The synthetic path's scale check (synthetic/capture.py): the config's object, camera, grid step and light grid,
checked in the config's own terms before anything is rendered."""

import pytest

from torchrefl.config import Config
from torchrefl.errors import ConfigError
from torchrefl.synthetic.capture import synthetic_scale_check
from torchrefl.synthetic.scan import SyntheticScan


def check(**synthetic):
    cfg = Config()
    cfg.synthetic.mesh_subdivisions = 2
    for key, value in synthetic.items():
        setattr(cfg.synthetic, key, value)
    return synthetic_scale_check(cfg, SyntheticScan(cfg.synthetic, cfg.selection.grid, threads=1))


def test_the_default_scene_passes():
    assert check().findings == []


def test_a_mesh_object_passes():
    assert check(object="bowl").findings == []


def test_size_in_metres_is_refused_naming_the_key():
    with pytest.raises(ConfigError, match=r"^config: synthetic\.size_mm look like metres"):
        check(size_mm=[0.062, 0.095, 0.05]).enforce(ConfigError)


def test_size_in_centimetres_is_warned():
    warnings = check(size_mm=[6.2, 9.5, 5.0]).enforce(ConfigError)
    assert len(warnings) == 1 and "look like centimetres" in warnings[0] and "multiply it by 10" in warnings[0]


def test_a_camera_distance_in_metres_is_refused_naming_the_key():
    with pytest.raises(ConfigError, match=r"synthetic\.camera_distance_mm in config look like metres"):
        check(camera_distance_mm=0.3).enforce(ConfigError)
