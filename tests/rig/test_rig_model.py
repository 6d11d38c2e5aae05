"""Rig model (grid <-> head frame <-> machine axes, soft limits, light switch) and rig settings."""

from pathlib import Path

import numpy as np
import pytest
from rig_helpers import fast_settings

from torchrefl.capture.cylindrical_rig import light_grid_positions
from torchrefl.errors import ConfigError, RigError
from torchrefl.rig.model import RigModel
from torchrefl.rig.settings import RigSettings, load_rig_settings

ROOT = Path(__file__).resolve().parents[2]


def test_grid_matches_the_capture_modules_light_grid():
    s = fast_settings(
        grid={"columns": 7, "rows": 4, "spacing_mm": 40.0, "center_lateral_mm": 10.0, "center_vertical_mm": -5.0},
        radial_mm=280.0,
    )
    m = RigModel(s)
    truth = light_grid_positions(7, 4, 40.0, 280.0, 10.0, -5.0)
    assert np.allclose(m.grid_positions(), truth)
    for flat, p in enumerate(truth):
        assert m.grid_index(p) == (flat % 7, flat // 7)
    assert m.grid_index(truth[0] + [1.0, 0, 0]) is None
    with pytest.raises(RigError, match=r"grid index \(7, 0\) outside the 7 x 4 light grid"):
        m.grid_position(7, 0)


def test_head_frame_to_axes_and_back():
    s = fast_settings(
        lateral={"axis": "Y", "origin_mm": -100.0, "sign": -1.0},
        vertical={"axis": "X", "origin_mm": -200.0, "min_mm": -400.0},
    )
    m = RigModel(s)
    axes = m.head_to_axes([30.0, -20.0, 300.0])
    assert axes == {"Y": -130.0, "X": -220.0}
    assert np.allclose(m.axes_to_head((-220.0, -130.0, -1.0)), [30.0, -20.0, 300.0])
    with pytest.raises(RigError, match="radial 250.0 mm is not the gantry plane's radial_mm 300.0"):
        m.head_to_axes([0.0, 0.0, 250.0])
    with pytest.raises(RigError, match="no turntable axis"):
        m.head_to_axes([0.0, 0.0, 300.0], angle_deg=10.0)


def test_turntable_angle():
    m = RigModel(fast_settings(turntable={"enabled": True, "axis": "Z", "origin_mm": -180.0}))
    axes = m.target([0.0, 0.0, 300.0], angle_deg=90.0)
    assert axes["Z"] == -90.0 and m.axes_to_angle((0, 0, -90.0)) == 90.0
    with pytest.raises(RigError, match="turntable axis Z target 420.000 is outside the travel"):
        m.target([0.0, 0.0, 300.0], angle_deg=600.0)


def test_soft_limits_name_the_axis():
    m = RigModel(fast_settings())
    m.check_travel({"X": -495.0, "Y": -5.0})
    with pytest.raises(RigError, match=r"vertical axis Y target 0.000 is outside the travel \[-295.0, -5.0\]"):
        m.target([0.0, 150.0, 300.0])


def test_light_commands():
    assert (RigModel(fast_settings()).light_on_command(), RigModel(fast_settings()).light_off_command()) == ("M8", "M9")
    m = RigModel(fast_settings(light={"output": "mist"}))
    assert (m.light_on_command(), m.light_off_command()) == ("M7", "M9")
    m = RigModel(fast_settings(light={"output": "spindle", "spindle_power": 250.0}))
    assert (m.light_on_command(), m.light_off_command()) == ("M3 S250", "M5")


def test_configs_rig_yaml_documents_the_defaults():
    assert load_rig_settings(ROOT / "configs" / "rig.yaml") == RigSettings()


def test_settings_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match="unknown key 'timeouts.reply'"):
        load_rig_settings(data={"timeouts": {"reply": 1.0}})
    with pytest.raises(ConfigError, match="key 'light.output' = 'laser' is not one of"):
        load_rig_settings(overrides=["light.output=laser"])
    with pytest.raises(ConfigError, match="lateral.min_mm .* must be below lateral.max_mm"):
        load_rig_settings(data={"lateral": {"min_mm": 0.0, "max_mm": -10.0}})
    with pytest.raises(ConfigError, match="different GRBL axes"):
        load_rig_settings(data={"vertical": {"axis": "X"}})
    (tmp_path / "r.yaml").write_text("port: [\n")
    with pytest.raises(ConfigError, match="r.yaml: not valid YAML"):
        load_rig_settings(tmp_path / "r.yaml")
