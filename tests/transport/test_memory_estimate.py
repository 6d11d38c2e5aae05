"""torchrefl.transport.memory_estimate: the estimate against the memory a photon refresh really takes, and the
refusal of a run the free memory cannot hold, naming the setting that brings it down."""

import sys
from pathlib import Path

import pytest
import torch
from conftest import load_script
from fresh_process import run_fresh

import torchrefl
import torchrefl.transport.memory_estimate as me
from torchrefl.capture.base import loader_for
from torchrefl.core.memory import peak_resident_mb, release_free_memory, reset_peak, resident_mb
from torchrefl.core.params import TexelParams
from torchrefl.errors import MemoryLimitError
from torchrefl.fit.pipeline import level_inputs
from torchrefl.transport.levels.auto import named_level, prepare
from torchrefl.transport.levels.photon import AVERAGE_FROM

tiny = load_script("tiny_mode")


def test_terms_grow_with_what_they_hold():
    cfg = torchrefl.load_config(tiny.FOLD)
    small = me.estimate_memory(cfg, 10_000, 10, "photon", 10, 8)
    assert set(small.terms) == {"fit", "form factors", "emitter maps", "photons", "density kernels"}
    assert set(me.estimate_memory(cfg, 10_000, 10, "local").terms) == {"fit"}
    twice = me.estimate_memory(cfg, 10_000, 10, "photon", 20, 8)  # twice the lights traced: twice the hits
    assert twice.terms["photons"] > 1.5 * small.terms["photons"] and twice.terms["fit"] == small.terms["fit"]
    # a hit has specular entries in every image of its light: 40 images of 6 lights hold more than 40 of 40
    shared, own = (me.photons_mb(1e7, 40, 300_000, 0.35, lights=n) for n in (6, 40))
    assert shared > 2 * own


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the peak is reset through /proc")
def test_a_chunked_local_fit_is_estimated_by_its_largest_chunk():
    cfg = torchrefl.load_config(None, [])
    dense = me.estimate_memory(cfg, 10**6, 48, "local").total_mb
    chunked = me.estimate_memory(cfg, 10**6, 48, "local", chunk_pairs=2**22).total_mb
    whole = 48 * 10**6 * me.CHUNKED_BYTES_PER_OBSERVATION
    assert chunked == pytest.approx((whole + 2**22 * me.FIT_BYTES_PER_OBSERVATION) / 2**20) and chunked < dense / 2


def tiny_photon_inputs(capture: str, photons: int):
    """The tiny fold's capture as the photon level's inputs at `photons` per light, and mid-range parameters."""
    cfg = torchrefl.load_config(
        tiny.FOLD,
        tiny.TINY + ["capture.kind=cylindrical_scan", f"capture.path={capture}"]
        + ["fit.model=photon", f"photon.photons_per_light={photons}"],
    )  # fmt: skip
    cap = loader_for("cylindrical_scan").load(Path(capture), cfg, lambda m: None)
    T = cap.surface.num_texels
    params = TexelParams(torch.full((T, 3), 0.5), torch.full((T, 3), 0.3), torch.full((T,), 0.15), 0.01, 0.6)
    return level_inputs(cfg, cap, lambda m: None)[0], params


def photon_level_growth(capture: str, photons: int) -> dict:
    """The peak resident memory (MiB) that preparing the tiny fold's photon level and three refreshes add (the third
    averaged with the second, the best kept: the caches the fit holds), measured after a first level has warmed the
    process (thread pools and their heaps are not the level's), with the level's estimate and counts."""
    inputs, params = tiny_photon_inputs(capture, photons)
    warm = named_level(inputs)
    prepare(warm)
    warm.refresh(params, 0)
    del warm
    level = named_level(inputs)
    release_free_memory()  # the warm level's freed heap back to the system: the level's own growth counts
    reset_peak()
    before = resident_mb()
    estimate = me.check_level_memory(level)
    prepare(level)
    for k in range(AVERAGE_FROM + 1):
        level.refresh(params, k)
    return {
        "added": peak_resident_mb() - before,
        "estimate": estimate.total_mb,
        "largest": estimate.largest(),
        "averaged": level.cache.stats["averaged_traces"],
        "emitted": level.cache.stats["photons_emitted"],
        "lights": inputs.obs.num_lights,
    }


def test_the_photon_estimate_is_within_a_factor_of_a_measured_refresh(tiny_fold_run):
    """The tiny fold's photon level at 300 000 photons per light (the photons' term dominates), measured in a new
    process, adds within a factor 2.5 of its estimate (the fixed costs, the tracer's landing tables and the smoother,
    weigh more on 432 observations than on the full fold; docs/results/performance.md, "Peak memory made
    smaller")."""
    photons = 300_000
    got = run_fresh(__file__, "photon_level_growth", str(tiny_fold_run / "capture"), photons)
    assert got["averaged"] == 2 and got["emitted"] == photons * got["lights"]
    assert got["largest"] == "photons"
    assert got["estimate"] / 2.5 < got["added"] < 2.5 * got["estimate"], got


def density_kernels_growth(rows: int, cols: int, std: float, specular_std: float) -> dict:
    """The peak resident memory (MiB) that building the photon level's density kernels (the irradiance smoother at
    `std` texels, the specular spread at `specular_std`) adds on a rows x cols grid, and the estimate's term."""
    import numpy as np

    from torchrefl.core.texel_grid import TexelGrid
    from torchrefl.transport.photon_density import SpreadKernel, smoothing_matrix

    T = rows * cols
    grid, normals = TexelGrid(np.arange(T), (rows, cols)), np.tile([0.0, 0.0, 1.0], (T, 1))
    cfg = torchrefl.load_config(None, [f"photon.smoothing={std}", f"photon.specular_smoothing={specular_std}"])
    release_free_memory()
    before = resident_mb()
    reset_peak()
    smoother = smoothing_matrix(grid, std, normals, 0.3)
    SpreadKernel(grid, specular_std, normals, 0.3)
    added = peak_resident_mb() - before
    return {"added": added, "estimate": me.kernels_mb(cfg, T), "entries": int(smoother.values().numel())}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the peak is reset through /proc")
def test_the_density_kernels_are_estimated_by_what_building_them_takes():
    """On a 250 x 250 grid at the automatic kernels' caps (4 texels: 625 smoother window slots per texel; the spread's
    3 texels: 49) the estimate's term covers the kernels' build and is not twice it. The smoother's former build (a
    COO tensor from per-offset parts, then coalesced) took about 110 bytes a slot, eight times its term: a
    313 808-texel atlas at this kernel was killed for want of 20 GB there."""
    got = run_fresh(__file__, "density_kernels_growth", 250, 250, 4.0, 3.0)
    assert got["entries"] > 0.9 * 250 * 250 * 625
    assert got["estimate"] / 2 < got["added"] <= got["estimate"], got


def test_density_kernels_that_would_not_fit_are_named_with_what_narrows_them():
    """The automatic kernels widen as photons per texel fall (to their cap), and their term with them; where it is the
    largest, the refusal names the kernels' settings and the photons that narrow them."""
    few, many = (torchrefl.load_config(None, [f"photon.photons_per_light={n}"]) for n in (400_000, 16_000_000))
    assert me.kernels_mb(few, 30_000) > 5 * me.kernels_mb(many, 30_000)
    wide = torchrefl.load_config(None, ["photon.smoothing=12"])
    est = me.estimate_memory(wide, 200_000, 10, "photon", 10)
    assert est.largest() == "density kernels"
    named = r"lower photon\.smoothing and photon\.specular_smoothing .*photons_per_light"
    with pytest.raises(MemoryLimitError, match=named):
        me.check_memory(est, 8_000.0, "the test's run")


def test_a_run_over_the_free_memory_is_refused_with_the_setting(tmp_path, monkeypatch):
    monkeypatch.setattr(me, "free_mb", lambda: 5.0)  # a machine with 5 MiB free
    over = [f"output.dir={tmp_path / 'run'}", "photon.photons_per_light=400000"]
    with pytest.raises(MemoryLimitError, match=r"lower photon\.photons_per_light to about \d+% of its value"):
        torchrefl.fit(torchrefl.load_config(tiny.FOLD, tiny.TINY + over))
    assert not (tmp_path / "run").exists()  # refused before any output


def test_the_message_names_the_largest_term():
    est = me.MemoryEstimate({"fit": 100.0, "photons": 900.0}, {"fit": "selection.num_lights", "photons": "p.n"})
    me.check_memory(est, 1000.0, "x")  # fits: nothing raised
    with pytest.raises(MemoryLimitError, match=r"x would need about 1000 MiB .* 500 MiB free: lower p\.n to about 44%"):
        me.check_memory(est, 500.0, "x")
    with pytest.raises(MemoryLimitError, match=r"other terms alone exceed"):
        me.check_memory(est, 50.0, "x")


def test_the_first_refresh_is_checked_with_the_hits_per_photon_a_pilot_trace_measures(tiny_fold_run, monkeypatch):
    """Stored hits per photon depend on the object (a closed, bright or glossy one stores more than the constant the
    up-front estimate assumes): a pilot trace measures them before the first refresh, within 15 % of what that
    refresh stores, and a refresh whose photons would not fit the free memory is refused before it traces, naming
    photon.photons_per_light."""
    inputs, params = tiny_photon_inputs(str(tiny_fold_run / "capture"), 200_000)
    level = named_level(inputs)
    prepare(level)
    pilot = level.refresher.hits_per_photon(*params.values())
    level.refresh(params, 0)
    stats = level.cache.stats
    measured = stats["stored_hits"] / stats["photons_emitted"]
    assert measured > 0 and pilot == pytest.approx(measured, rel=0.15)
    messages = []
    level.inputs.log = messages.append
    monkeypatch.setattr(me, "free_mb", lambda: 0.5)  # a machine with half a MiB free
    level.cache = None
    with pytest.raises(MemoryLimitError, match=r"lower photon\.photons_per_light"):
        level.refresh(params, 0)
    assert level.cache is None and any("hits per photon" in m for m in messages)
