"""fit.texel_chunks: the chunk plan, and a chunked local fit of a mesh_views capture equal to the unchunked one."""

from __future__ import annotations

import importlib

import torch

import torchrefl.transport.memory_estimate as memory_estimate
from torchrefl.capture.mesh_views import MeshViewsLoader
from torchrefl.config import load_config
from torchrefl.core.progress import Stages
from torchrefl.fit.pipeline import fit_capture
from torchrefl.fit.texel_chunks import plan_chunks

texel_chunks = importlib.import_module("torchrefl.fit.texel_chunks")  # torchrefl.fit is also a function's name


def test_chunks_cover_the_texels_grouped_by_the_images_that_observe_them():
    fitted = torch.zeros(3, 10, dtype=torch.bool)
    fitted[0, 0:4] = True  # image 0 sees texels 0-3, image 1 texels 4-5, image 2 texel 9; 6-8 unseen
    fitted[1, 4:6] = True
    fitted[2, 9] = True
    chunks = plan_chunks(fitted, max_pairs=4, block=2)
    # ordered by their images (none; {2}; {1}; {0}): 6 7 8 9 | 4 5 | 0 1 2 3 in blocks of one texel (4 pairs / 3
    # images): texel 4 would make 2 images x 5 texels, texel 0 2 images x 3 texels
    assert [c.texels.tolist() for c in chunks] == [[6, 7, 8, 9], [4, 5], [0, 1, 2, 3]]
    assert [c.images.tolist() for c in chunks] == [[2], [1], [0]]
    assert all(c.pairs <= 4 for c in chunks)


def test_a_chunk_no_image_observes_still_has_one_image():
    chunks = plan_chunks(torch.zeros(2, 5, dtype=torch.bool), max_pairs=100)
    assert [(c.texels.tolist(), c.images.tolist()) for c in chunks] == [([0, 1, 2, 3, 4], [0])]


def _fit(folder, log):
    cfg = load_config(
        "mesh_views",
        [
            "capture.kind=mesh_views",
            f"capture.path={folder}",
            "capture.texture_size=16",
            "fit.holdout=[1]",
            "fit.iterations=3",
            "output.progress=false",
        ],
    )
    cap = MeshViewsLoader().load(folder, cfg, lambda msg: None)
    return cap, fit_capture(cfg, cap, Stages(lambda *a, **k: None), log, torch.device("cpu"))


def test_a_chunked_local_fit_equals_the_unchunked_one_and_runs_above_the_budget(tiny_views_run, monkeypatch):
    folder = tiny_views_run / "capture"
    logged: list[str] = []
    cap, dense = _fit(folder, lambda msg, echo=True: logged.append(msg))
    assert not any("chunks of texels" in m for m in logged)  # plenty of free memory: no chunks
    # 0.3 MiB free for the plan: the dense estimate (400 bytes a pair) is above half of it, a chunk holds ~400 pairs;
    # 0.5 MiB free for the level's memory check, which refuses the dense estimate and passes the chunked one
    monkeypatch.setattr(texel_chunks, "free_mb", lambda: 0.3)
    monkeypatch.setattr(memory_estimate, "free_mb", lambda: 0.5)
    P, T = cap.obs.num_lights, cap.surface.num_texels
    assert P * T * memory_estimate.FIT_BYTES_PER_OBSERVATION > 0.5 * 2**20
    logged.clear()
    _, chunked = _fit(folder, lambda msg, echo=True: logged.append(msg))
    said = [m for m in logged if "chunks of texels" in m]
    assert len(said) == 1
    count = int(said[0].split(" run in ")[1].split()[0])
    assert count >= 4, said
    assert torch.equal(dense.estimated, chunked.estimated) and torch.equal(dense.coverage, chunked.coverage)
    for name in ("pd", "ps", "sigma"):
        torch.testing.assert_close(getattr(chunked, name), getattr(dense, name), rtol=1e-5, atol=1e-6)
    for name in ("pd_std", "ps_std", "sigma_std", "noise_dn"):
        torch.testing.assert_close(getattr(chunked.uncertainty, name), getattr(dense.uncertainty, name))
    fitted = dense.fit_mask
    torch.testing.assert_close(chunked.predicted[fitted], dense.predicted[fitted], rtol=1e-5, atol=1e-6)
    assert int(dense.estimated.sum()) > 0 and cap.surface.num_texels == dense.pd.shape[0]
