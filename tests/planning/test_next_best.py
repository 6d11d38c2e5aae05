"""planning.next_best on a flat patch whose answers follow from the geometry: two groups of texels, one facing the
camera (normal +z), one tilted 30 deg about x; the camera far above (view direction +z). A light straight above puts
a highlight (half-angle 0) on the first group only; a light along the second group's mirror direction (0, sin 60,
cos 60) on the second only (each group's half-angle under the other's light is 30 deg > theta_th2 = 20 deg)."""

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from torchrefl.config import Config
from torchrefl.core.observations import Observations
from torchrefl.fit.uncertainty import ParameterRanges
from torchrefl.planning.next_best import LightInformation, Planner, TexelState, choose, light_information

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
        self.unobserved = torch.zeros(T, dtype=torch.bool)
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


def test_halving_the_std_of_many_determined_texels_beats_one_first_lobe():
    """The score is the log posterior variance (D-optimal): 8 texels whose Ps and sigma are known to 5 % (candidate A
    gives them 3 x their information: their stds halve) against one texel without a measured lobe (candidate B gives
    it its second highlight, Ps and sigma then known to 20 %). By hand, with the broad prior's variances v0 (Ps
    16 / 12, sigma 0.59^2 / 12) and diagonal blocks: A gains 8 x sum log((4 I + 1/v0) / (I + 1/v0)) ~ 8 x 2 log 4
    = 22.2; B gains sum log(v0 / v) ~ log(1.333 / 0.04^2) + log(0.029 / 0.03^2) = 10.2. (A saturating score,
    log(1 + r^2 / 0.1^2), would rank them the other way: A 2.6, B 9.8.)"""
    N, ps, sigma = 8, 0.2, 0.15
    ranges = ParameterRanges(4.0, 0.01, 0.6)
    v0 = ranges.prior_var(1)
    scene = SimpleNamespace(
        ps=torch.full((N + 1, 1), ps, dtype=torch.float64),
        sigma=torch.full((N + 1,), sigma, dtype=torch.float64),
        ranges=ranges,
        lobe_measured=torch.tensor([True] * N + [False]),
        n_specular=torch.tensor([2] * N + [1]),
        estimated=torch.ones(N + 1, dtype=torch.bool),
    )

    def block(ps_rel_std, sigma_rel_std):
        """A diagonal (5, 5) information: Pd well known, Ps and sigma to the given relative stds without prior."""
        d = [1e6] * 3 + [1.0 / (ps_rel_std * ps) ** 2, 1.0 / (sigma_rel_std * sigma) ** 2]
        return torch.diag(torch.tensor(d, dtype=torch.float64))

    info = torch.stack([block(0.05, 0.05)] * N + [torch.diag(torch.tensor([1e6] * 3 + [0.0, 0.0]))]).double()
    state = TexelState(scene, info.clone())
    light = LightInformation(
        texels=[torch.arange(N), torch.tensor([N])],
        info=[3.0 * info[:N], block(0.2, 0.2)[None]],
        specular=[torch.zeros(N, dtype=torch.long), torch.ones(1, dtype=torch.long)],
    )
    I = torch.diagonal(info[0])[3:]
    gain_a = N * float(torch.log((4 * I + 1 / v0[3:]) / (I + 1 / v0[3:])).sum())
    gain_b = float(torch.log(v0[3:] * (torch.diagonal(block(0.2, 0.2))[3:] + 1 / v0[3:])).sum())
    assert gain_a == pytest.approx(22.2, abs=0.1) and gain_b == pytest.approx(10.2, abs=0.1)
    assert state.gain(light, 0) == pytest.approx(gain_a, rel=1e-9)
    assert state.gain(light, 1) == pytest.approx(gain_b, rel=1e-9)


def test_the_reachable_share_is_the_share_with_every_candidate_added():
    scene = captured_scene()
    scene.noise_dn = torch.full((3,), 0.01, dtype=torch.float64)  # precise enough that a measured lobe is determined
    shift = np.array([5.0, 0.0, 0.0])
    # no candidate sees a texel: the ceiling is the share now, the upward group (lobe measured) and not the tilted one
    assert Planner(scene, BELOW[None]).reachable() == 0.5
    # two more highlights on the tilted group (its lobe measured, and off the mirror direction for sigma): every texel
    # determined, as choosing all of the candidates predicts
    candidates = np.stack([UP + shift, MIRROR + shift, MIRROR + [0.0, 40.0, 0.0], BELOW])
    assert Planner(scene, candidates).reachable() == 1.0 == choose(scene, candidates, 4).both_known[-1]
    # the ceiling leaves out a candidate at one of the run's lights (its image is already captured)
    assert Planner(scene, np.stack([MIRROR, BELOW])).reachable() == 0.5


def test_a_near_repeat_highlight_gains_less_than_a_first_highlight_elsewhere():
    """The score is the Bayesian posterior whatever a texel's count of highlights (module docstring). The run has one
    highlight on the upward group (light UP) and a light to the side; the tilted group has none. Repeating UP adds
    its information H again: the precision A = P0 + H + D (prior, UP, side light) becomes A + H <= 2 A (H <= A), so
    no marginal variance falls below half, and each of the 8 texels gains at most 2 log 2 (two parameters): the
    repeat's gain is at most 16 log 2 = 11.1, a candidate 1 mm from UP (a near-repeat) likewise. The old rule
    counted the repeat as the upward group's second highlight, switched its Ps and sigma from the broad prior to the
    posterior and scored it about 29, and the mirror light, whose highlights are the tilted group's first, 0."""
    side = np.array([400.0, 0.0, 300.0])
    scene = FlatScene(np.stack([UP, side]), torch.tensor([1] * 4 + [0] * 4), torch.zeros(8, dtype=torch.bool))
    planner = Planner(scene, np.stack([UP + [1.0, 0.0, 0.0], MIRROR]))
    state = TexelState(scene, planner.info.clone())
    bound = 16 * math.log(2.0)
    repeat = light_information(scene, UP[None])
    assert 0.0 < state.gain(repeat, 0) <= bound
    assert 0.0 < state.gain(planner.light, 0) <= bound  # the near-repeat
    assert state.gain(planner.light, 1) > bound
    assert planner.choose(1).chosen == [1]


def test_a_first_observation_of_a_texel_the_run_never_observed_counts():
    """The run's two lights (UP and 10 mm beside it) measured only the upward group; the tilted group has no estimate.
    As unobserved texels (planning.run_scene: predicted at a stand-in, no information yet, even where the planner's
    prediction of the run's own lights would reach them) they count in the mirror light's information, which brings
    them their first observations and highlights: it gains more than it does without them (texels the fit set aside,
    where it only adds to the upward group) and more than a light beside UP."""
    lights = np.stack([UP, UP + [10.0, 0.0, 0.0]])
    spec = torch.tensor([2] * 4 + [0] * 4)
    candidates = np.stack([UP + [0.0, 10.0, 0.0], MIRROR])
    scene = FlatScene(lights, spec, spec >= 2)
    scene.estimated[4:] = False
    set_aside = Planner(scene, candidates)
    assert set_aside.info[4:].abs().sum() == 0.0 and set_aside.light.texels[1].tolist() == [0, 1, 2, 3]
    before = TexelState(scene, set_aside.info.clone()).gain(set_aside.light, 1)
    scene.unobserved[4:] = True
    planner = Planner(scene, candidates)
    assert planner.info[4:].abs().sum() == 0.0  # the run's lights' predicted observations of them do not count
    tilted = planner.light.texels[1] >= 4
    assert planner.light.texels[1][tilted].tolist() == [4, 5, 6, 7]
    assert planner.light.specular[1][tilted].tolist() == [1] * 4
    state = TexelState(scene, planner.info.clone())
    assert state.gain(planner.light, 1) > before + 1.0
    assert state.gain(planner.light, 1) > state.gain(planner.light, 0) > 0.0
    assert planner.choose(1).chosen == [1]
