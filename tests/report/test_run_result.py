"""torchrefl.report.run_result: a run's outputs for notebooks (load, relight, plot) and its errors."""

import json
import math

import matplotlib
import numpy as np
import pytest

from torchrefl.errors import RunFolderError, TorchReflError
from torchrefl.report.run_marker import write_marker
from torchrefl.report.run_result import load_run

matplotlib.use("Agg")


def write_run(folder, H=6, W=7, seed=0, ps_channels=3, brdf="torrance_sparrow", minnaert_k=None, stds=False):
    """A run folder with known parameters on a spherical cap of radius 50 (texel grid H x W); stds: with the
    parameters' std (the lobe measured in the left half of the grid)."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, W), np.linspace(-0.4, 0.4, H))
    n = np.stack([u, v, np.sqrt(1.0 - u * u - v * v)], -1)
    mask = np.ones((H, W), dtype=bool)
    mask[0, 0] = False
    params = dict(
        pd=rng.uniform(0.1, 0.9, (H, W, 3)),
        ps=rng.uniform(0.0, 0.8, (H, W, ps_channels)),
        sigma=rng.uniform(0.05, 0.4, (H, W)),
        mask=mask,
        brdf=np.array(brdf),
        positions=50.0 * n,
        normals=n,
        kappa=np.full(3, math.pi),
        units=np.array("mm"),
        coverage=np.full((H, W), 2, dtype=np.int16),
    )
    if minnaert_k is not None:
        params.update(diffuse=np.array("minnaert"), minnaert_k=np.array(minnaert_k))
    if stds:
        lobe = np.zeros((H, W), dtype=bool)
        lobe[:, : W // 2] = True
        params.update(
            pd_std=np.full((H, W, 3), 0.01),
            ps_std=0.05 * params["ps"],
            sigma_std=0.2 * params["sigma"],
            lobe_measured=lobe,
        )
    np.savez_compressed(folder / "params.npz", **params)
    (folder / "metrics.json").write_text(
        json.dumps(
            {
                "model": "local",
                "brdf": brdf,
                "texels": int(mask.sum()),
                "lights": 3,
                "timing_s": {"fit": 1.0, "total": 2.0},
                "rerender": {"mean_abs_diff_8bit": 0.3, "var_diff_8bit": 0.1, "rmse_8bit": 0.4},
            }
        )
    )
    (folder / "config.yaml").write_text("reflectance:\n  sigma_max: 0.6\n")
    write_marker(folder)
    return params


def eq_2_9(params, L, Y, camera, k=1.0):
    """The seed's eq. 2.9 for a point light, texel by texel (kappa = pi):
    Y / C^2 (Pd cos_l + Ps exp(-th^2 / 2 s^2) / cos_v), with the diffuse term times Minnaert's (cos_l cos_v)^(k - 1)."""
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
            out[r, c] = (
                np.asarray(Y)
                / C**2
                * (
                    params["pd"][r, c] * cl * (cl * cv) ** (k - 1.0)
                    + ps * math.exp(-th * th / (2 * params["sigma"][r, c] ** 2)) / cv
                )
            )
    return out


@pytest.mark.parametrize("ps_channels,k", [(1, None), (3, None), (3, 1.15)])
def test_render_matches_eq_2_9(tmp_path, ps_channels, k):
    params = write_run(tmp_path / "run", ps_channels=ps_channels, minnaert_k=k)
    run = load_run(tmp_path / "run")
    assert run.minnaert_k == (k or 1.0) and run.diffuse == ("minnaert" if k else "lambert")
    assert run.grid_shape == (6, 7) and run.brdf == "torrance_sparrow" and run.units == "mm"
    np.testing.assert_array_equal(run.pd, params["pd"])
    for L, camera, Y in [
        ((0.0, 30.0, 120.0), (0.0, 0.0, 200.0), (2.0e4, 1.5e4, 1.0e4)),
        ((80.0, -10.0, 40.0), (-30.0, 20.0, 150.0), 3.0e4),
    ]:
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
    b = run.render(light_position=far * d / np.linalg.norm(d), view_dir=(0, 0, 1), intensity=far**2)
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


def test_the_figure_shows_the_relative_std_where_the_lobe_was_measured(tmp_path):
    write_run(tmp_path / "run", stds=True)
    run = load_run(tmp_path / "run")
    assert run.sigma_std.shape == run.sigma.shape and run.lobe_measured.dtype == bool
    fig = run.figure()
    panels = {ax.get_title().split(" (")[0]: ax for ax in fig.axes if ax.get_title()}
    assert {"Ps relative std", "sigma relative std"} <= set(panels)
    shown = panels["sigma relative std"].get_images()[0].get_array()
    # the lobe measured in the left columns (0.2 relative); the right columns hatched (not determined)
    assert np.allclose(shown[:, :3].compressed(), 0.2)
    assert shown[:, 4:].mask.all()
    matplotlib.pyplot.close(fig)
    write_run(tmp_path / "plain")
    assert load_run(tmp_path / "plain").pd_std is None


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda p: p.pop("sigma_std"), "has pd_std, ps_std, lobe_measured but not sigma_std"),
        (lambda p: p.update(ps_std=p["ps_std"][..., :1]), "'ps_std' has shape"),
        (lambda p: p.update(sigma_std=-p["sigma_std"]), "'sigma_std' expected finite values >= 0"),
    ],
)
def test_bad_std_arrays_are_named_errors(tmp_path, change, match):
    write_run(tmp_path / "run", stds=True)
    params = dict(np.load(tmp_path / "run" / "params.npz"))
    change(params)
    with pytest.raises(RunFolderError, match=match):
        load_run(resealed(tmp_path / "run", params))


def resealed(folder, params=None, **files):
    """Damage a run folder as a run that wrote bad files would (params.npz content, other files' text), then
    write the marker again: load_run's own checks, not the marker's, must catch it."""
    if params is not None:
        np.savez(folder / "params.npz", **params)
    for name, text in files.items():
        (folder / name.replace("_", ".", 1)).write_text(text)
    write_marker(folder)
    return folder


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
    write_marker(bad)
    with pytest.raises(TorchReflError, match=r"params\.npz: unreadable"):
        load_run(bad)
    p = write_run(tmp_path / "nokey")
    with pytest.raises(TorchReflError, match="missing key.*sigma"):
        load_run(resealed(tmp_path / "nokey", {k: v for k, v in p.items() if k != "sigma"}))
    p = write_run(tmp_path / "shape")
    with pytest.raises(TorchReflError, match="'pd' has shape"):
        load_run(resealed(tmp_path / "shape", dict(p, pd=p["pd"][:, :, :2])))
    write_run(tmp_path / "nojson")
    with pytest.raises(TorchReflError, match=r"metrics\.json: not valid JSON"):
        load_run(resealed(tmp_path / "nojson", metrics_json="{not json"))
    p = write_run(tmp_path / "brdf")
    with pytest.raises(TorchReflError, match="unknown BRDF 'phong'"):
        load_run(resealed(tmp_path / "brdf", dict(p, brdf=np.array("phong"))))


def test_a_folder_without_a_valid_marker_is_incomplete_or_mixed(tmp_path):
    """Issue 19: new params beside old metrics and maps, a failed run's config beside an old params.npz: load_run
    refuses each, naming the folder and why."""
    run = tmp_path / "run"
    write_run(run)
    (run / "run_complete.json").unlink()
    with pytest.raises(RunFolderError, match="no completeness marker.*incomplete"):
        load_run(run)
    write_run(run := tmp_path / "run2")
    (run / "config.yaml").write_text("reflectance:\n  brdf: lambertian\n  sigma_max: 0.6\n")  # a later run's config
    with pytest.raises(RunFolderError, match=r"config\.yaml.*(bytes|differs)"):
        load_run(run)
    p = write_run(run := tmp_path / "run3")
    np.savez_compressed(run / "params.npz", **dict(p, pd=p["pd"] * 0.5))  # a later run's params
    with pytest.raises(RunFolderError, match=r"params\.npz.*(bytes|differs)"):
        load_run(run)
    write_run(run := tmp_path / "run4")
    (run / "metrics.json").unlink()
    with pytest.raises(RunFolderError, match=r"incomplete run.*metrics\.json"):
        load_run(run)
    write_run(run := tmp_path / "run5")
    (run / "run_complete.json").write_text('{"format": 1, "files": [1, 2]}')
    with pytest.raises(RunFolderError, match="damaged completeness marker"):
        load_run(run)


def test_files_the_run_did_not_write_are_ignored_and_named_in_the_summary(tmp_path):
    """Issue 33: a saved figure or a .DS_Store in a finished run folder made load_run refuse the whole run as a
    mixed folder. The run's own files are still checked; the others are listed, not read."""
    run = tmp_path / "run"
    params = write_run(run)
    (run / ".DS_Store").write_bytes(b"\x00\x00\x00\x01Bud1")
    (run / "figure.png").write_bytes(b"my figure")
    (run / "maps").mkdir()
    (run / "maps" / "light_007_diff.png").write_bytes(b"a map the run did not write")
    result = load_run(run)
    np.testing.assert_array_equal(result.pd, params["pd"])
    assert result.unrecorded == (".DS_Store", "figure.png", "maps/light_007_diff.png")
    assert result.summary().splitlines()[-1] == (
        "  3 file(s) in the folder not written by the run (ignored): .DS_Store, figure.png, maps/light_007_diff.png"
    )
    write_run(tmp_path / "clean")
    assert "not written by the run" not in load_run(tmp_path / "clean").summary()
    many = tmp_path / "many"
    write_run(many)
    for i in range(7):
        (many / f"note_{i}.txt").write_text("mine")
    last = load_run(many).summary().splitlines()[-1]
    assert last.endswith(
        "7 file(s) in the folder not written by the run (ignored): "
        + ", ".join(["note_0.txt", "note_1.txt", "note_2.txt", "note_3.txt", "note_4.txt", "..."])
    )
    (run / "params.npz").write_bytes((run / "params.npz").read_bytes()[:-1] + b"?")  # the run's own file changed
    with pytest.raises(RunFolderError, match=r"params\.npz: content differs"):
        load_run(run)


@pytest.mark.parametrize(
    "name,text,match",
    [
        ("metrics_json", "[1, 2]", "expected a JSON mapping.*list"),
        ("metrics_json", "{}", "key 'model'"),
        (
            "metrics_json",
            json.dumps({"model": "local", "brdf": "torrance_sparrow", "texels": 41, "lights": 3, "rerender": {}}),
            "key 'timing_s'",
        ),
        (
            "metrics_json",
            json.dumps(
                {
                    "model": "local",
                    "brdf": "torrance_sparrow",
                    "texels": 41,
                    "lights": 3,
                    "rerender": {},
                    "timing_s": {"fit": "slow"},
                }
            ),
            "timing_s",
        ),
        (
            "metrics_json",
            json.dumps(
                {
                    "model": "local",
                    "brdf": "ward",
                    "texels": 41,
                    "lights": 3,
                    "rerender": {},
                    "timing_s": {"total": 1.0},
                }
            ),
            "two runs",
        ),
        ("config_yaml", "- a\n- b\n", "expected a YAML mapping.*list"),
        ("config_yaml", "a: [\n", "config.yaml: not valid YAML"),
    ],
)
def test_damaged_metrics_and_config_are_named_errors(tmp_path, name, text, match):
    write_run(tmp_path / "run")
    with pytest.raises(RunFolderError, match=match):
        load_run(resealed(tmp_path / "run", **{name: text}))


@pytest.mark.parametrize(
    "key,value,match",
    [
        ("pd", "nan", "'pd' has NaN"),
        ("sigma", "inf", "'sigma' has NaN"),
        ("normals", "nan", "'normals' has NaN"),
        ("kappa", np.array([math.pi, 0.0, math.pi]), "'kappa'"),
        ("minnaert_k", np.array("1.2"), "'minnaert_k'"),
        ("diffuse", np.array("oren_nayar"), "'diffuse'"),
    ],
)
def test_non_finite_or_mistyped_parameters_are_named_errors(tmp_path, key, value, match):
    p = write_run(tmp_path / "run")
    if isinstance(value, str):
        bad = p[key].copy()
        bad[2, 3] = float(value)
        value = bad
    with pytest.raises(RunFolderError, match=match):
        load_run(resealed(tmp_path / "run", dict(p, **{key: value})))


def test_a_damaged_metrics_section_leaves_summary_and_figure_working(tmp_path):
    write_run(tmp_path / "run")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    metrics.update(diffuse=[1], holdout="x", selection={"lights_selected": "many"}, capture={"warnings": ["w1"]})
    run = load_run(resealed(tmp_path / "run", metrics_json=json.dumps(metrics), config_yaml="reflectance: [1]\n"))
    assert "WARNING: w1" in run.summary()
    matplotlib.pyplot.close(run.figure())


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
