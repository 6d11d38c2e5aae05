"""render_view: a mesh_views estimate re-rendered in a photograph's camera (through report.relight). At the true maps
of a noiseless synthetic capture it reproduces the photograph (rendered independently, by the synthetic renderer)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from torchrefl.config import MeshViewsConfig
from torchrefl.errors import RunFolderError
from torchrefl.geometry.atlas_surface import load_atlas_geometry
from torchrefl.report.run_result import RunResult
from torchrefl.report.view_render import render_view
from torchrefl.synthetic.mesh_views import write_capture

S = 32
SCENE = dict(width=96, height=72, focal_px=160.0, cameras_per_ring=2, camera_elevations_deg=[10.0], lights_per_view=1)


def run_of(truth: dict, mesh: Path | None, folder: Path) -> RunResult:
    """A RunResult holding the given maps (the truth) on the capture's atlas, with the atlas's texel positions and
    normals (as the loader writes them into params.npz) when the mesh is given."""
    mask = np.isfinite(truth["sigma"])
    positions = normals = np.zeros(mask.shape + (3,))
    if mesh is not None:
        surface = load_atlas_geometry(mesh, S).surface
        positions, normals = (surface.to_grid(a.numpy()) for a in (surface.positions, surface.normals))
    maps = {k: np.nan_to_num(truth[k]) for k in ("pd", "ps", "sigma")}
    return RunResult(
        folder=folder, mask=mask, positions=positions, normals=normals, kappa=np.full(3, np.pi),
        brdf="torrance_sparrow", units="mm", coverage=None, n_diffuse=None, n_specular=None, metrics={}, config={},
        mesh=None if mesh is None else str(mesh), **maps,
    )  # fmt: skip


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    folder = tmp_path_factory.mktemp("vr") / "capture"
    return write_capture(folder, MeshViewsConfig(noise_dn=0.0, **SCENE), texture_size=S)


def test_the_true_maps_rerender_the_photograph(capture):
    run = run_of(capture.truth, capture.folder / "mesh.obj", capture.folder.parent)
    view = render_view(run, 1)
    assert view.file == capture.folder / capture.scene.images[1].file
    assert view.shown.sum() > 1500 and (view.rendered[view.shown].max(-1) > 0.05).sum() > 1000
    diff = np.abs(view.rendered - view.photograph)[view.shown] * 255
    # the photograph takes the exact normal and material at each sub-sample, the re-render its texel's maps and the
    # interpolated normal: within 0.2 DN on average (docs/outputs.md), no pixel off by a quantisation-sized 2 DN
    assert view.difference()["mean_abs_diff_8bit"] < 0.2 and np.percentile(diff, 99) < 2.0
    assert not view.rendered[~view.shown].any()
    brighter = render_view(replace(run, pd=run.pd * 1.1), 1)  # an estimate 10 % off shows as such
    assert brighter.difference()["mean_abs_diff_8bit"] > 5 * view.difference()["mean_abs_diff_8bit"]


def test_a_run_without_its_mesh_or_capture_is_a_named_error(capture, tmp_path):
    with pytest.raises(RunFolderError, match="the capture folder is not beside the run's mesh"):
        render_view(run_of(capture.truth, None, tmp_path), 0)
    with pytest.raises(RunFolderError, match=r"params\.npz: no 'mesh' key"):
        render_view(run_of(capture.truth, None, tmp_path), 0, capture=capture.folder)
    with pytest.raises(RunFolderError, match="no image 9"):
        render_view(run_of(capture.truth, capture.folder / "mesh.obj", tmp_path), 9)
