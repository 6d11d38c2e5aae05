"""lights.json: point and directional lights, scalar or RGB intensity, named errors."""

import numpy as np
import pytest

from torchrefl.capture.lights_json import read_lights_json
from torchrefl.errors import CaptureError


def test_point_and_directional_lights(write_json):
    doc = {
        "led": {"position": [10, -20, 300], "intensity": [6e4, 5e4, 4e4]},
        "sun": {"direction": [0, 0.6, 0.8005], "intensity": 0.5},
    }
    lights = read_lights_json(write_json("lights.json", doc))
    assert lights.names == ("led", "sun") and lights.point.tolist() == [True, False]
    assert lights.position[0].tolist() == [10.0, -20.0, 300.0] and np.isnan(lights.position[1]).all()
    assert np.isnan(lights.direction[0]).all()
    assert np.linalg.norm(lights.direction[1]) == pytest.approx(1.0, abs=1e-12)  # renormalised
    assert lights.intensity.tolist() == [[6e4, 5e4, 4e4], [0.5, 0.5, 0.5]]


@pytest.mark.parametrize(
    "light, message",
    [
        ({"intensity": 1.0}, r"light \['x'\] needs exactly one of 'position'"),
        ({"position": [0, 0, 1], "direction": [0, 0, 1], "intensity": 1}, r"light \[.x.\] needs exactly one"),
        ({"position": [0, 0, 1]}, r"missing key \['x'\]\.intensity"),
        ({"position": [0, 0, 1], "intensity": [1, 0, 1]}, r"\['x'\]\.intensity must be a number > 0 or 3"),
        ({"position": [0, 0, 1], "intensity": -2}, r"\['x'\]\.intensity must be a number > 0"),
        ({"direction": [0, 0, 2], "intensity": 1}, r"\['x'\]\.direction has length 2"),
        ({"position": [0, 0], "intensity": 1}, r"\['x'\]\.position must be 3 finite numbers"),
        ({"position": [0, 0, 1], "intensity": 1, "colour": "red"}, r"unknown key \['x'\]\.colour"),
    ],
)
def test_bad_light_names_file_and_key(write_json, light, message):
    with pytest.raises(CaptureError, match=rf"lights\.json: {message}"):
        read_lights_json(write_json("lights.json", {"x": light}))


def test_scaled_lights_keep_the_irradiance(write_json):
    doc = {"led": {"position": [0, 0, 2], "intensity": 3.0}, "sun": {"direction": [0, 0, 1], "intensity": 0.5}}
    lights = read_lights_json(write_json("lights.json", doc)).scaled(10.0)  # cm -> mm
    assert lights.position[0].tolist() == [0.0, 0.0, 20.0]
    # Y / d^2 at the origin: 3 / 2^2 in cm units, 300 / 20^2 in mm
    assert (lights.intensity[0] / 20.0**2).tolist() == pytest.approx([3.0 / 2.0**2] * 3)
    assert lights.intensity[1].tolist() == [0.5] * 3 and np.isnan(lights.position[1]).all()
