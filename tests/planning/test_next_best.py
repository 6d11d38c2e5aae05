"""planning.next_best on a flat patch whose answers follow from the geometry: two groups of texels, one facing the
camera (normal +z), one tilted 30 deg about x; the camera far above (view direction +z). A light straight above puts
a highlight (half-angle 0) on the first group only; a light along the second group's mirror direction (0, sin 60,
cos 60) on the second only (each group's half-angle under the other's light is 30 deg > theta_th2 = 20 deg)."""

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import torch

from torchrefl.config import Config
from torchrefl.core.observations import Observations
from torchrefl.fit.uncertainty import ParameterRanges
from torchrefl.planning.next_best import choose, light_information

TILT = math.radians(30.0)
UP = np.array([0.0, 0.0, 500.0])
MIRROR = 500.0 * np.array([0.0, math.sin(2 * TILT), math.cos(2 * TILT)])  # the tilted group's mirror direction
BELOW = np.array([0.0, 0.0, -500.0])


@dataclass
class FlatScene:
    """The attributes of planning.run_scene.RunScene that next_best reads, for the flat patch (module docstring):
    8 texels, the first 4 facing up, the last 4 tilted; lights at world positions, camera at +z infinity."""

    lights: np.ndarray
    n_specular: torch.Tensor
    lobe_measured: torch.Tensor
    intensity: float = 1.0e5
    saturation_level: float = 0.995
    images_per_light = 1

    def __post_init__(self):
        T = 8
        self.cfg = Config()
        self.run = SimpleNamespace(minnaert_k=1.0)
        tilted = torch.tensor([0.0, math.sin(TILT), math.cos(TILT)], dtype=torch.float64)
        self.normals = torch.cat([torch.tensor([[0.0, 0.0, 1.0]]).expand(4, 3), tilted.expand(4, 3)]).double()
        self.positions = np.column_stack([np.arange(T) * 2.0 - 7.0, np.zeros(T), np.zeros(T)])
        self.pd = torch.full((T, 3), 0.5, dtype=torch.float64)
        self.ps = torch.full((T, 3), 0.2, dtype=torch.float64)
        self.sigma = torch.full((T,), 0.15, dtype=torch.float64)
        self.estimated = torch.ones(T, dtype=torch.bool)
        self.noise_dn = torch.full((3,), 0.5, dtype=torch.float64)
        self.ranges = ParameterRanges(4.0, 0.01, 0.6)

    def observations(self, positions) -> Observations:
        L = torch.as_tensor(np.asarray(positions, dtype=np.float64))
        to = L[:, None] - torch.from_numpy(self.positions)[None]
        dist = to.norm(dim=-1)
        l = to / dist[..., None]
        P, T = dist.shape
        return Observations(
            intensity=torch.zeros(P, T, 3, dtype=torch.float64),
            valid=(l * self.normals[None]).sum(-1) > 0,
            saturated=torch.zeros(P, T, dtype=torch.bool),
            shadowed=torch.zeros(P, T, dtype=torch.bool),
            light_dir=l,
            falloff=1.0 / dist**2,
            light_intensity=torch.full((P, 3), self.intensity, dtype=torch.float64),
            view_dir=torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(T, 3),
            kappa=torch.full((3,), math.pi, dtype=torch.float64),
        )

    def fitted_observations(self, chunk: int):
        yield self.observations(self.lights)


def captured_scene(**kw) -> FlatScene:
    """Two highlights on the upward group (lobe measured), one on the tilted group (not measured: it needs two)."""
    lights = np.stack([UP, UP + [10.0, 0.0, 0.0], MIRROR])
    spec = torch.tensor([2] * 4 + [1] * 4)
    return FlatScene(lights, spec, spec >= 2, **kw)


def test_the_patch_classes_are_the_ones_the_module_docstring_states():
    scene = captured_scene()
    info = light_information(scene, np.stack([UP, MIRROR]))
    assert [s.tolist() for s in info.specular] == [[1] * 4 + [0] * 4, [0] * 4 + [1] * 4]


def test_a_light_that_sees_no_texel_adds_nothing():
    scene = captured_scene()
    info = light_information(scene, BELOW[None])
    assert len(info.texels[0]) == 0
    result = choose(scene, np.stack([BELOW, UP + [5.0, 0.0, 0.0]]), 2)
    assert result.chosen == [1, 0] and result.gain[1] == 0.0


def test_a_highlight_on_texels_without_one_beats_a_redundant_light():
    scene = captured_scene()
    redundant, new = UP + [5.0, 0.0, 0.0], MIRROR + [5.0, 0.0, 0.0]
    result = choose(scene, np.stack([redundant, new]), 2)
    assert result.chosen == [1, 0]
    assert result.gain[0] > result.gain[1] > 0.0


def test_greedy_never_takes_a_light_twice_even_when_it_stays_the_best():
    scene = captured_scene()
    result = choose(scene, np.stack([MIRROR + [5.0, 0.0, 0.0], BELOW]), 2)
    assert result.chosen == [0, 1]
    assert result.gain[0] > 0.0 and result.gain[1] == 0.0


def test_saturated_observations_add_nothing_and_gains_stay_finite():
    # 100 x brighter: every lit observation of the patch reads far above full range
    scene = captured_scene(intensity=1.0e7)
    shift = np.array([5.0, 0.0, 0.0])
    info = light_information(scene, np.stack([UP + shift, MIRROR + shift]))
    assert all(len(t) == 0 for t in info.texels)
    result = choose(scene, np.stack([UP + shift, MIRROR + shift, BELOW]), 3)
    assert np.isfinite(result.gain).all() and (result.gain == 0.0).all()
    assert all(np.isfinite(result.sigma_known))


def test_texels_without_any_highlight_give_finite_gains():
    scene = FlatScene(np.array([[1000.0, 0.0, 200.0]]), torch.zeros(8, dtype=torch.long), torch.zeros(8) > 0)
    result = choose(scene, np.stack([UP, MIRROR]), 2)
    assert np.isfinite(result.gain).all() and sorted(result.chosen) == [0, 1]


def test_a_light_the_run_already_has_is_not_planned_again():
    scene = captured_scene()
    # the tilted group's own light again would give its second highlight, but the capture has that image
    result = choose(scene, np.stack([MIRROR, UP + [5.0, 0.0, 0.0]]), 1)
    assert result.chosen == [1]
