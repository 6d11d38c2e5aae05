"""A photon-level fit stopped at a checkpoint boundary (after its first outer iteration, during the second) and
resumed from its checkpoints ends where the uninterrupted fit ends, redoing no completed outer iteration."""

import pytest
import torch
from conftest import fold_surface, point_light_observations

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.checkpoints import Checkpoints
from torchrefl.core.progress import Stages
from torchrefl.fit.outer_state import OUTER
from torchrefl.fit.pipeline import fit_capture
from torchrefl.transport.local import local_terms, predict

LIGHTS = [[-40.0, 5.0, 50.0], [-60.0, -20.0, 30.0], [-20.0, 25.0, 70.0], [-30.0, -10.0, 60.0]]
CAMERA = [-150.0, 0.0, 150.0]


class Killed(Exception):
    """Stands for the process being killed right after a checkpoint."""


class StopAfter(Checkpoints):
    """Checkpoints that stop the run once the refinement after `outer` outer iterations is saved."""

    def __init__(self, run, outer: int):
        super().__init__(run)
        self.outer = outer

    def save(self, name, state):
        super().save(name, state)
        if name == OUTER and state["done"] == self.outer:
            raise Killed(name)


@pytest.fixture(scope="module")
def fold():
    s = fold_surface(6, 12)
    obs = point_light_observations(s.normals, s.positions, torch.tensor(LIGHTS), torch.tensor(CAMERA), 2e4)
    terms = local_terms("torrance_sparrow", s.normals, obs)
    T = s.num_texels
    pd = torch.full((T, 3), 0.5, dtype=torch.float64)
    ps = torch.full((T, 3), 0.2, dtype=torch.float64)
    obs.intensity = predict(terms, pd, ps, torch.full((T,), 0.2, dtype=torch.float64)) * 1.05  # + interreflection
    return Capture(s, obs)


def photon_config() -> Config:
    cfg = Config()
    cfg.fit.model = "photon"
    cfg.fit.iterations, cfg.fit.optimizer = 2, "adam"
    photon = dict(photons_per_light=2000, outer_iterations=2, diffuse_paths="photons", specular_gather=0)
    for key, value in photon.items():
        setattr(cfg.photon, key, value)
    cfg.output.progress = False
    return cfg


def test_a_fit_killed_in_its_second_outer_iteration_resumes_to_the_uninterrupted_result(fold, tmp_path):
    cfg = photon_config()
    cpu = torch.device("cpu")
    whole = fit_capture(cfg, fold, Stages(), lambda *a: None, cpu, Checkpoints(tmp_path / "whole"))
    with pytest.raises(Killed):
        fit_capture(cfg, fold, Stages(), lambda *a: None, cpu, StopAfter(tmp_path / "run", outer=1))
    log: list[str] = []
    again = Checkpoints(tmp_path / "run")
    resumed = fit_capture(cfg, fold, Stages(), log.append, cpu, again)
    assert any("after outer iteration 1 of 2" in line for line in log)
    assert any("start from the checkpoint" in line for line in log)
    refreshes = [line.split(":")[0] for line in log if line.startswith("photon refresh")]
    assert refreshes == ["photon refresh 2"]  # refresh 0 and outer iteration 1 not redone
    assert again.saved == [OUTER]  # after outer iteration 2
    for name in ("pd", "ps", "sigma"):
        torch.testing.assert_close(getattr(resumed, name), getattr(whole, name), rtol=1e-6, atol=1e-8)
    assert resumed.history == whole.history
    assert resumed.photon["image_difference_per_refresh"] == whole.photon["image_difference_per_refresh"]
