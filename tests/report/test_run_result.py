"""torchrefl.report.run_result: a run's outputs for notebooks (load, relight, plot) and its errors."""

import json
import math

import matplotlib
import numpy as np
import pytest

from torchrefl.errors import TorchReflError
from torchrefl.report.run_result import load_run

matplotlib.use("Agg")


def write_run(folder, H=6, W=7, seed=0, ps_channels=3, brdf="torrance_sparrow", minnaert_k=None):
    """A run folder with known parameters on a spherical cap of radius 50 (texel grid H x W)."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, W), np.linspace(-0.4, 0.4, H))
    n = np.stack([u, v, np.sqrt(1.0 - u * u - v * v)], -1)
    mask = np.ones((H, W), dtype=bool)
    mask[0, 0] = False
    params = dict(
        pd=rng.uniform(0.1, 0.9, (H, W, 3)), ps=rng.uniform(0.0, 0.8, (H, W, ps_channels)),
        sigma=rng.uniform(0.05, 0.4, (H, W)), mask=mask, brdf=np.array(brdf), positions=50.0 * n, normals=n,
        kappa=np.full(3, math.pi), units=np.array("mm"), coverage=np.full((H, W), 2, dtype=np.int16),
    )
    if minnaert_k is not None:
        params.update(diffuse=np.array("minnaert"), minnaert_k=np.array(minnaert_k))
    np.savez_compressed(folder / "params.npz", **params)
    (folder / "metrics.json").write_text(json.dumps({
        "model": "local", "brdf": brdf, "texels": int(mask.sum()), "lights": 3, "timing_s": {"fit": 1.0, "total": 2.0},
        "rerender": {"mean_abs_diff_8bit": 0.3, "var_diff_8bit": 0.1, "rmse_8bit": 0.4}}))
    return params


def eq_2_9(params, L, Y, camera, k=1.0):
    """The seed's eq. 2.9 for a point light, texel by texel (kappa = pi): Y / C^2 (Pd cos_l + Ps exp(-th^2 / 2 s^2) / cos_v),
    with the diffuse term times Minnaert's (cos_l cos_v)^(k - 1)."""
    H, W = params["mask"].shape
    out = np.zeros((H, W, 3))
    for r in range(H):
        for c in range(W):
            if not params["mask"][r, c]:
                continue
            x, n = params["positions"][r, c], params["normals"][r, c]
            to = np.asarray(L, float) - x
            C = math.sqrt(to @ to)
            l = to / C
            v = (np.asarray(camera, float) - x) / np.linalg.norm(np.asarray(camera, float) - x)
            cl, cv = float(n @ l), float(n @ v)
            if cl <= 0 or cv <= 0:
                continue
            h = (l + v) / np.linalg.norm(l + v)
            th = math.acos(min(1.0, float(n @ h)))
            ps = params["ps"][r, c] * np.ones(3)
            out[r, c] = np.asarray(Y) / C ** 2 * (params["pd"][r, c] * cl * (cl * cv) ** (k - 1.0)
                                                   + ps * math.exp(-th * th / (2 * params["sigma"][r, c] ** 2)) / cv)
    return out


@pytest.mark.parametrize("ps_channels,k", [(1, None), (3, None), (3, 1.15)])
def test_render_matches_eq_2_9(tmp_path, ps_channels, k):
    params = write_run(tmp_path / "run", ps_channels=ps_channels, minnaert_k=k)
    run = load_run(tmp_path / "run")
    assert run.minnaert_k == (k or 1.0) and run.diffuse == ("minnaert" if k else "lambert")
    assert run.grid_shape == (6, 7) and run.brdf == "torrance_sparrow" and run.units == "mm"
    np.testing.assert_array_equal(run.pd, params["pd"])
    for L, camera, Y in [((0.0, 30.0, 120.0), (0.0, 0.0, 200.0), (2.0e4, 1.5e4, 1.0e4)),
                         ((80.0, -10.0, 40.0), (-30.0, 20.0, 150.0), 3.0e4)]:
        Y3 = np.broadcast_to(np.asarray(Y, float), (3,))
        img = run.render(light_position=L, camera=camera, intensity=Y)
        ref = eq_2_9(params, L, Y3, camera, k or 1.0)
        assert img.shape == (6, 7, 3)
        np.testing.assert_allclose(img, ref, rtol=1e-9, atol=1e-12)
        assert (ref > 0).any() and (img[~params["mask"]] == 0).all()


def test_directional_light_and_orthographic_view(tmp_path):
    params = write_run(tmp_path / "run")
    run = load_run(tmp_path / "run")
    d = np.array([0.3, 0.2, 1.0])
    far = 1.0e6
    # a directional light equals a point light far away along d, with the intensity scaled by distance^2
    a = run.render(light_direction=d, view_dir=(0, 0, 1), intensity=1.0)
    b = run.render(light_position=far * d / np.linalg.norm(d), view_dir=(0, 0, 1), intensity=far ** 2)
    np.testing.assert_allclose(a, b, rtol=1e-4)
    grid_view = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (6, 7, 3))
    np.testing.assert_allclose(run.render(light_direction=d, view_dir=grid_view), a)
    # a light behind every texel leaves the image black
    assert (run.render(light_direction=(0, 0, -1), view_dir=(0, 0, 1)) == 0).all()
    assert np.isfinite(a).all() and (a[params["mask"]] > 0).any()


def test_summary_and_figure(tmp_path):
    write_run(tmp_path / "run")
    run = load_run(tmp_path / "run")
    assert "model local" in run.summary()
    fig = run.figure()
    assert len(fig.axes) >= 4
    assert "Pd" in fig.axes[0].get_title()
    matplotlib.pyplot.close(fig)


def test_bad_run_folders_name_the_file(tmp_path):
    with pytest.raises(TorchReflError, match="run folder missing"):
        load_run(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(TorchReflError, match=r"params\.npz: missing"):
        load_run(tmp_path / "empty")
    bad = tmp_path / "truncated"
    write_run(bad)
    data = (bad / "params.npz").read_bytes()
    (bad / "params.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(TorchReflError, match=r"params\.npz: unreadable"):
        load_run(bad)
    nokey = tmp_path / "nokey"
    p = write_run(nokey)
    np.savez(nokey / "params.npz", **{k: v for k, v in p.items() if k != "sigma"})
    with pytest.raises(TorchReflError, match="missing key.*sigma"):
        load_run(nokey)
    shape = tmp_path / "shape"
    p = write_run(shape)
    np.savez(shape / "params.npz", **dict(p, pd=p["pd"][:, :, :2]))
    with pytest.raises(TorchReflError, match="'pd' has shape"):
        load_run(shape)
    nojson = tmp_path / "nojson"
    write_run(nojson)
    (nojson / "metrics.json").write_text("{not json")
    with pytest.raises(TorchReflError, match=r"metrics\.json: not valid JSON"):
        load_run(nojson)
    brdf = tmp_path / "brdf"
    p = write_run(brdf)
    np.savez(brdf / "params.npz", **dict(p, brdf=np.array("phong")))
    with pytest.raises(TorchReflError, match="unknown BRDF 'phong'"):
        load_run(brdf)


def test_render_arguments_are_checked(tmp_path):
    write_run(tmp_path / "run")
    run = load_run(tmp_path / "run")
    with pytest.raises(TorchReflError, match="exactly one of light_position"):
        run.render(camera=(0, 0, 100))
    with pytest.raises(TorchReflError, match="exactly one of light_position"):
        run.render(light_position=(0, 0, 100), light_direction=(0, 0, 1), camera=(0, 0, 100))
    with pytest.raises(TorchReflError, match="exactly one of camera"):
        run.render(light_position=(0, 0, 100))
    with pytest.raises(TorchReflError, match="light_position=.*3 finite numbers"):
        run.render(light_position=(0, float("nan"), 100), camera=(0, 0, 100))
    with pytest.raises(TorchReflError, match="intensity=.*> 0"):
        run.render(light_position=(0, 0, 100), camera=(0, 0, 100), intensity=(-1, 1, 1))
    with pytest.raises(TorchReflError, match="zero vector"):
        run.render(light_direction=(0, 0, 0), view_dir=(0, 0, 1))
    with pytest.raises(TorchReflError, match=r"view_dir has shape \(2, 3\)"):
        run.render(light_direction=(0, 0, 1), view_dir=np.ones((2, 3)))
    with pytest.raises(TorchReflError, match="lies on an estimated texel"):
        run.render(light_position=run.positions[2, 3], camera=(0, 0, 100))
