"""fit.init_from: a fit warm-started from an earlier run's params.npz (torchrefl.fit.warm_start)."""

import numpy as np
import pytest
from conftest import TINY_QUICK_SCENE

from torchrefl.errors import ConfigError
from torchrefl.run import fit

#: the tiny quick scene with all 6 grid lights (no selection), the fit cut short, no export
TINY = [*TINY_QUICK_SCENE, "selection.enabled=false", "output.export=false", "fit.iterations=3", "output.map_lights=0"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("warm") / "first"
    return fit("quick", [*TINY, f"output.dir={folder}"])


def crafted_run(run, folder, pd=0.3, ps=0.15, sigma=0.25):
    """A run folder whose params.npz is run's with constant pd, ps, sigma (the values a warm start must return)."""
    folder.mkdir()
    with np.load(run.folder / "params.npz") as f:
        arrays = dict(f)
    arrays.update(
        pd=np.full_like(arrays["pd"], pd), ps=np.full_like(arrays["ps"], ps), sigma=np.full_like(arrays["sigma"], sigma)
    )
    np.savez(folder / "params.npz", **arrays)
    return folder


def test_zero_iterations_return_the_given_parameters(tiny_run, tmp_path):
    start = crafted_run(tiny_run, tmp_path / "start")
    again = fit("quick", [*TINY, f"output.dir={tmp_path / 'again'}", f"fit.init_from={start}", "fit.iterations=0"])
    m = again.mask & tiny_run.mask  # estimated by both: the same capture, so the same texels
    assert m.sum() > 0.9 * tiny_run.mask.sum()
    np.testing.assert_allclose(again.pd[m], 0.3, atol=1e-4)
    np.testing.assert_allclose(again.ps[m], 0.15, atol=1e-4)
    np.testing.assert_allclose(again.sigma[m], 0.25, atol=1e-4)
    assert "warm start from" in (again.folder / "log.txt").read_text()


def test_a_mismatched_or_missing_run_is_a_named_error(tiny_run, tmp_path):
    folder = tmp_path / "other"
    folder.mkdir()
    with np.load(tiny_run.folder / "params.npz") as f:
        arrays = dict(f)
    H, W = arrays["pd"].shape[:2]
    arrays.update(pd=np.zeros((H + 1, W, 3), np.float32))
    np.savez(folder / "params.npz", **arrays)
    with pytest.raises(
        ConfigError,
        match=rf"fit.init_from: .*params.npz lies on a {H + 1} x {W} texel grid, this "
        rf"capture's is {H} x {W}",
    ):
        fit("quick", [*TINY, f"output.dir={tmp_path / 'x'}", f"fit.init_from={folder}"])
    with pytest.raises(ConfigError, match=r"fit.init_from: .*nowhere/params.npz not found"):
        fit("quick", [*TINY, f"output.dir={tmp_path / 'y'}", f"fit.init_from={tmp_path / 'nowhere'}"])
