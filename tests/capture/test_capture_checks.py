"""Captures that cannot be right are refused before fitting, those that may be wrong are flagged (issue 19):
each class of bad input for both capture kinds (cylindrical_scan and photometric_stereo)."""

import json
import shutil

import numpy as np
import pytest
import yaml

from capture.test_cylindrical_scan import small_cfg
from capture.test_photometric_stereo import make_folder
from torchrefl.capture.cylindrical_scan import CylindricalScanLoader
from torchrefl.capture.images import read_image, write_png
from torchrefl.capture.photometric_stereo import PhotometricStereoLoader
from torchrefl.config import Config, LightGridConfig
from torchrefl.errors import CaptureError
from torchrefl.synthetic.scan import SyntheticScan


@pytest.fixture(scope="module")
def scan_master(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scan_master")
    scan = SyntheticScan(small_cfg(noise_dn=0.3), LightGridConfig(), seed=3)
    scan.write_geometry(folder)
    scan.write_textures(folder, scan.candidate_positions()[[4, 24, 35]])
    return folder


@pytest.fixture
def scan(scan_master, tmp_path):
    folder = tmp_path / "scan"
    shutil.copytree(scan_master, folder)
    return folder


@pytest.fixture
def ps(tmp_path):
    make_folder(tmp_path / "ps")
    return tmp_path / "ps"


def config(kind, folder, **capture):
    cfg = Config()
    cfg.capture.kind, cfg.capture.path, cfg.threads = kind, str(folder), 1
    for key, value in capture.items():
        setattr(cfg.capture, key, value)
    return cfg


def load(kind, folder, lines=None, **capture):
    loader = CylindricalScanLoader() if kind == "cylindrical_scan" else PhotometricStereoLoader()
    return loader.load(folder, config(kind, folder, **capture), (lines if lines is not None else []).append)


def edit_scan_yaml(folder, change):
    doc = yaml.safe_load((folder / "scan.yaml").read_text())
    change(doc)
    (folder / "scan.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))


# ------------------------------------------------------------------ an image file used for two lights


def test_one_texture_for_two_lights_is_refused(scan):
    edit_scan_yaml(scan, lambda d: d["lights"][2].update(image=d["lights"][0]["image"]))
    with pytest.raises(CaptureError, match=r"lights 0 and 2 use the same image file .*000\.png"):
        load("cylindrical_scan", scan)


def test_one_photograph_for_two_lights_is_refused(ps):
    names = (ps / "filenames.txt").read_text().split()
    (ps / "filenames.txt").write_text("\n".join(names[:3] + [names[1]]) + "\n")
    with pytest.raises(CaptureError, match=r"lights 1 and 3 use the same image file .*002\.png"):
        load("photometric_stereo", ps)


def test_two_names_of_one_file_are_one_file(scan):
    (scan / "textures" / "alias.png").symlink_to(scan / "textures" / "001.png")
    edit_scan_yaml(scan, lambda d: d["lights"][2].update(image="textures/alias.png"))
    with pytest.raises(CaptureError, match="lights 1 and 2 use the same image file"):
        load("cylindrical_scan", scan)


# ------------------------------------------------------------------ constant or black images


@pytest.mark.parametrize("which", [[0, 1, 2], [1]])
def test_constant_textures_are_refused(scan, which):
    for i in which:
        write_png(scan / "textures" / f"{i:03d}.png", np.zeros((80, 96, 3), np.uint8), bits=8)
    with pytest.raises(CaptureError, match=rf"{len(which)} of 3 images are constant.*001\.png \(all 0\)"):
        load("cylindrical_scan", scan)


@pytest.mark.parametrize("which", [[0, 1, 2, 3], [2]])
def test_constant_photographs_are_refused(ps, which):
    for i in which:
        write_png(ps / f"{i + 1:03d}.png", np.zeros((6, 8, 3), np.uint16), bits=16)
    with pytest.raises(CaptureError, match=rf"{len(which)} of 4 images are constant.*003\.png"):
        load("photometric_stereo", ps)


def test_black_noise_images_are_refused_all_and_flagged_alone(ps):
    rng = np.random.default_rng(0)
    noise = lambda: rng.integers(0, 2 * 257, size=(6, 8, 3)).astype(np.uint16)  # below 2 DN of 8 bits
    write_png(ps / "002.png", noise(), bits=16)
    cap = load("photometric_stereo", ps)
    assert len(cap.warnings) == 1 and "002.png" in cap.warnings[0] and "black" in cap.warnings[0]
    for i in (1, 3, 4):
        write_png(ps / f"{i:03d}.png", noise(), bits=16)
    with pytest.raises(CaptureError, match="all 4 images are black"):
        load("photometric_stereo", ps)


def test_identical_photographs_of_two_files_are_flagged(ps):
    shutil.copy(ps / "001.png", ps / "003.png")
    cap = load("photometric_stereo", ps)
    assert any("003.png is identical to" in w and "001.png" in w for w in cap.warnings)


# ------------------------------------------------------------------ channel count or size differs


def test_a_grey_texture_among_rgb_is_refused(scan):
    grey = (read_image(scan / "textures" / "001.png")[0].mean(-1) * 255).round().astype(np.uint8)
    write_png(scan / "textures" / "001.png", grey, bits=8)
    with pytest.raises(CaptureError, match=r"001\.png is a grey image, expected RGB like .*000\.png"):
        load("cylindrical_scan", scan)


def test_a_grey_photograph_among_rgb_is_refused(ps):
    write_png(ps / "004.png", np.full((6, 8), 9000, np.uint16), bits=16)
    with pytest.raises(CaptureError, match=r"004\.png is a grey image, expected RGB"):
        load("photometric_stereo", ps)


# ------------------------------------------------------------------ light subsets


@pytest.mark.parametrize("kind", ["cylindrical_scan", "photometric_stereo"])
@pytest.mark.parametrize("subset,match", [([0, 0], r"indices \[0\] repeated"), ([], "is empty")])
def test_bad_light_subsets_are_refused_for_both_kinds(scan, ps, kind, subset, match):
    folder = scan if kind == "cylindrical_scan" else ps
    with pytest.raises(CaptureError, match=f"capture.light_subset.*{match}|{match}"):
        load(kind, folder, light_subset=subset)


# ------------------------------------------------------------------ more images than lights


def test_textures_no_light_lists_are_flagged(scan):
    shutil.copy(scan / "textures" / "000.png", scan / "textures" / "003.png")
    cap = load("cylindrical_scan", scan)
    assert any("1 image file(s) that no light" in w and "003.png" in w for w in cap.warnings)


def test_photographs_filenames_txt_does_not_list_are_flagged(ps):
    names = (ps / "filenames.txt").read_text().split()
    shutil.copy(ps / "001.png", ps / "005.png")
    cap = load("photometric_stereo", ps)
    assert any("005.png" in w and "filenames.txt does not list" in w for w in cap.warnings)
    assert len(names) == 4


# ------------------------------------------------------------------ range maps that cannot be millimetres


@pytest.mark.parametrize(
    "change,match",
    [
        (lambda r: np.round(r).astype(np.int16), "int16, integer counts are not millimetres"),
        (lambda r: r.astype(np.float16), "float16, expected float32 or float64"),
        (lambda r: r * 1e6, "reach past the camera.*not in mm"),
        (lambda r: -r, "negative ranges"),
    ],
)
def test_range_maps_that_cannot_be_millimetres_are_refused(scan, change, match):
    r = np.load(scan / "range.npy")
    with np.errstate(invalid="ignore"):
        np.save(scan / "range.npy", change(np.nan_to_num(r, nan=0.0) if "int" in match else r))
    with pytest.raises(CaptureError, match=match):
        load("cylindrical_scan", scan)


def test_integer_ranges_need_a_scale(scan):
    r = np.load(scan / "range.npy")
    np.save(scan / "range.npy", np.where(np.isfinite(r), r * 100, 0).round().astype(np.int32))
    with pytest.raises(CaptureError, match=r"int32.*give range\.scale_mm"):
        load("cylindrical_scan", scan)
    edit_scan_yaml(scan, lambda d: d["range"].update(scale_mm=0.01))
    cap = load("cylindrical_scan", scan)
    assert cap.obs.num_lights == 3


def test_a_camera_at_the_axis_is_refused(scan):
    edit_scan_yaml(scan, lambda d: d["camera"].update(distance_mm=1.0))
    with pytest.raises(CaptureError, match="camera.distance_mm = 1"):
        load("cylindrical_scan", scan)


# ------------------------------------------------------------------ nothing to fit says why


def test_nothing_to_fit_names_the_filters_scan(scan):
    """Lights behind the rotation axis (radial -300 mm in the head frame) light no texel the camera sees."""
    edit_scan_yaml(scan, lambda d: [e.update(position_mm=[0.0, 0.0, -300.0]) for e in d["lights"]])
    with pytest.raises(
        CaptureError,
        match=r"nothing to fit: none of the \d+ observations.*not lit \(n.l at or "
        r"below the threshold\): [1-9].*in cast shadow: \d+.*saturated",
    ):
        load("cylindrical_scan", scan)


def test_nothing_to_fit_names_the_filters_photometric_stereo(ps):
    import scipy.io

    n = scipy.io.loadmat(ps / "Normal_gt.mat")["Normal_gt"]
    scipy.io.savemat(ps / "Normal_gt.mat", {"Normal_gt": n * np.array([1.0, 1.0, -1.0])})
    with pytest.raises(CaptureError, match=r"nothing to fit.*facing away from the camera \(n.v <= 0\): [1-9]"):
        load("photometric_stereo", ps)


def test_the_fit_side_names_its_filters():
    import torch

    from torchrefl.errors import FitError
    from torchrefl.fit.fit_observations import require_fit_observations

    valid = torch.ones(3, 4, dtype=torch.bool)
    held = torch.tensor([True, True, True])
    with pytest.raises(FitError, match=r"nothing to fit in cap.*held out \(fit.holdout: 3 lights\): 12"):
        require_fit_observations(
            valid & ~held[:, None], valid, torch.ones(4), torch.ones(3, 4), held, 0.05, 0.02, "cap"
        )


# ------------------------------------------------------------------ light intensities of the wrong scale


def test_light_intensities_of_the_wrong_scale_name_their_file(ps, scan):
    table = np.loadtxt(ps / "light_intensities.txt")
    table[1] *= 1e30
    np.savetxt(ps / "light_intensities.txt", table)
    with pytest.raises(CaptureError, match=r"light_intensities\.txt: light 1's intensity gives .* albedo"):
        load("photometric_stereo", ps)
    edit_scan_yaml(scan, lambda d: d["light"].update(intensity=[1e30] * 3))
    with pytest.raises(CaptureError, match=r"scan\.yaml \(light\.intensity.*albedo"):
        load("cylindrical_scan", scan)


# ------------------------------------------------------------------ scan.yaml is strict


@pytest.mark.parametrize(
    "change,key",
    [
        (lambda d: d.update(renderer={"samples": 4}), "renderer"),
        (lambda d: d["grid"].update(rowz=80), "grid.rowz"),
        (lambda d: d["light"].update(colour="white"), "light.colour"),
        (lambda d: d["truth"].update(fiel="gt.npz"), "truth.fiel"),
        (lambda d: d["lights"][1].update(positon_mm=[0, 0, 1]), r"lights\[1\]\.positon_mm"),
    ],
)
def test_unknown_scan_yaml_keys_are_named(scan, change, key):
    edit_scan_yaml(scan, change)
    with pytest.raises(CaptureError, match=rf"scan\.yaml: unknown key '{key}'"):
        load("cylindrical_scan", scan)


def test_unknown_manifest_keys_are_named(scan):
    doc = yaml.safe_load((scan / "scan.yaml").read_text())
    rig_keys = {"index": 0, "requested_mm": [0, 0, 300], "mpos": [0, 0, 0], "grid": [0, 0], "time": "t"}
    lines = [dict(e, **rig_keys) for e in doc["lights"]]
    (scan / "manifest.jsonl").write_text("".join(json.dumps(e) + "\n" for e in lines))
    edit_scan_yaml(scan, lambda d: d.update(lights="manifest.jsonl"))
    assert load("cylindrical_scan", scan).obs.num_lights == 3  # the rig's keys are known
    lines[0]["exposure"] = 0.1
    (scan / "manifest.jsonl").write_text("".join(json.dumps(e) + "\n" for e in lines))
    with pytest.raises(CaptureError, match=r"manifest\.jsonl: unknown key 'lights\[0\]\.exposure'"):
        load("cylindrical_scan", scan)


# ------------------------------------------------------------------ scan.yaml against the config: one rule


def test_the_folders_saturation_level_and_kappa_win_and_the_override_is_logged(scan):
    edit_scan_yaml(scan, lambda d: (d.update(saturation_level=0.5), d["light"].update(kappa=[3.0, 3.0, 3.0])))
    lines = []
    cap = load("cylindrical_scan", scan, lines, saturation_level=0.9, kappa=[1.0, 1.0, 1.0])
    assert cap.stats["saturation_level"] == 0.5 and cap.obs.kappa.tolist() == [3.0, 3.0, 3.0]
    assert any("capture.saturation_level 0.9 (config) is overridden by saturation_level 0.5" in x for x in lines)
    assert any("capture.kappa [1.0, 1.0, 1.0] (config) is overridden by light.kappa" in x for x in lines)


def test_the_configs_values_apply_where_the_folder_gives_none(scan):
    edit_scan_yaml(scan, lambda d: (d.pop("saturation_level"), d["light"].pop("kappa")))
    lines = []
    cap = load("cylindrical_scan", scan, lines, saturation_level=0.9, kappa=[1.0, 2.0, 3.0])
    assert cap.stats["saturation_level"] == 0.9 and cap.obs.kappa.tolist() == [1.0, 2.0, 3.0]
    assert not any("overridden" in x for x in lines)


def test_the_truth_file_scan_yaml_names_is_the_one_read(scan):
    data = dict(np.load(scan / "truth.npz"))
    np.savez(scan / "gt.npz", **dict(data, pd=np.full_like(data["pd"], 0.25)))
    edit_scan_yaml(scan, lambda d: d["truth"].update(file="gt.npz"))
    assert float(load("cylindrical_scan", scan).truth["pd"].mean()) == 0.25
    edit_scan_yaml(scan, lambda d: d["truth"].update(file="missing.npz"))
    with pytest.raises(CaptureError, match=r"missing\.npz: truth file not found"):
        load("cylindrical_scan", scan)


def test_the_truth_region_map_is_read_per_texel(scan):
    """truth.npz's optional region (H, W) integers come per texel (metrics.json's per-region specular_source)."""
    data = dict(np.load(scan / "truth.npz"))
    cap = load("cylindrical_scan", scan)
    flat = data["region"].reshape(-1)[cap.surface.texel_index.numpy()]  # the synthetic scanner writes one
    assert cap.truth["region"].tolist() == flat.tolist()
    data.pop("region", None)
    np.savez(scan / "truth.npz", **data)
    assert load("cylindrical_scan", scan).truth["region"] is None


# ------------------------------------------------------------------ truth.npz is validated


@pytest.mark.parametrize(
    "damage,match",
    [
        (lambda d: d.pop("sigma"), "missing key 'sigma'"),
        (lambda d: d.update(pd=d["pd"][:, :10]), "'pd' is float.*expected numbers of shape"),
        (lambda d: d.update(sigma=np.full_like(d["sigma"], np.nan)), "'sigma' is NaN or infinite at"),
        (lambda d: d.update(minnaert_k=np.array("one")), "'minnaert_k'"),
        (lambda d: d.update(region=d["sigma"]), "'region' is float64.*expected integers"),
    ],
)
def test_bad_truth_files_are_named_errors(scan, damage, match):
    data = dict(np.load(scan / "truth.npz"))
    damage(data)
    np.savez(scan / "truth.npz", **data)
    with pytest.raises(CaptureError, match=rf"truth\.npz: {match}"):
        load("cylindrical_scan", scan)


def test_a_truncated_truth_file_is_a_named_error(scan):
    raw = (scan / "truth.npz").read_bytes()
    (scan / "truth.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(CaptureError, match=r"truth\.npz: unreadable as a numpy \.npz archive"):
        load("cylindrical_scan", scan)
