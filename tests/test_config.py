"""Config: strict YAML, nearest-key hints, overrides, types, ranges, help, resolved dump."""

import dataclasses
import functools
import re
from pathlib import Path

import pytest
import yaml

from torchrefl.config import Config, describe, dump_config, load_config
from torchrefl.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def write(tmp_path, text, name="c.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_every_field_has_a_default_and_a_doc():
    def walk(cls):
        for f in dataclasses.fields(cls):
            if f.metadata.get("internal"):
                continue
            assert f.metadata.get("doc"), f"{cls.__name__}.{f.name} has no doc"
            assert f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
            if dataclasses.is_dataclass(f.type) or (
                isinstance(f.default_factory, type) and dataclasses.is_dataclass(f.default_factory)
            ):
                walk(f.default_factory)

    walk(Config)


@pytest.mark.parametrize("name", ["default.yaml", "diligent_ball.yaml"])
def test_bundled_configs_load(name):
    cfg = load_config(ROOT / "configs" / name)
    assert cfg.fit.model == "local"


def test_misspelt_key_names_file_key_and_nearest(tmp_path):
    p = write(tmp_path, "fit:\n  optimiser: adam\n")
    with pytest.raises(ConfigError) as e:
        load_config(p)
    msg = str(e.value)
    assert str(p) in msg and "fit.optimiser" in msg and "fit.optimizer" in msg


def test_unknown_top_level_key(tmp_path):
    with pytest.raises(ConfigError, match="unknown key 'sede'.*'seed'"):
        load_config(write(tmp_path, "sede: 3\n"))


def test_wrong_type_and_choice_and_range(tmp_path):
    with pytest.raises(ConfigError, match="fit.iterations.*expected a whole number such as 60"):
        load_config(write(tmp_path, "fit:\n  iterations: many\n"))
    with pytest.raises(ConfigError, match="reflectance.brdf.*'phong'"):
        load_config(write(tmp_path, "reflectance:\n  brdf: phong\n"))
    with pytest.raises(ConfigError, match="reflectance.theta_specular_deg.*<= 90"):
        load_config(write(tmp_path, "reflectance:\n  theta_specular_deg: 120\n"))
    with pytest.raises(ConfigError, match="sigma_min"):
        load_config(write(tmp_path, "reflectance:\n  sigma_min: 0.5\n  sigma_max: 0.1\n"))
    with pytest.raises(ConfigError, match="radiosity.light_maps.*>= 1"):
        load_config(write(tmp_path, "radiosity:\n  light_maps: 0\n"))
    with pytest.raises(ConfigError, match="radiosity.solve_samples.*>= 1"):
        load_config(write(tmp_path, "radiosity:\n  solve_samples: 0\n"))
    with pytest.raises(ConfigError, match="geometry.crease_angle_deg.*<= 179"):
        load_config(write(tmp_path, "geometry:\n  crease_angle_deg: 180\n"))
    with pytest.raises(ConfigError, match="photon.specular_gather.*>= 0"):
        load_config(write(tmp_path, "photon:\n  specular_gather: -1\n"))
    # the gather (a default) needs the radiosity paths; with every path from photons it is unused, not an error
    assert load_config(write(tmp_path, "photon:\n  diffuse_paths: photons\n")).photon.specular_gather == 64


@pytest.mark.parametrize("name", ["object_e_setup1.yaml", "object_e_setup2.yaml"])
def test_object_e_configs_load_with_their_form_factor_settings(name):
    cfg = load_config(ROOT / "configs" / name)
    assert cfg.radiosity.hemisphere_samples == 2048 and cfg.radiosity.solve_samples == 256
    assert cfg.geometry.median_size is None and cfg.synthetic.range_noise_mm == 0  # auto: exact ranges get no median
    assert cfg.photon.specular_gather == 64 and cfg.photon.diffuse_paths == "radiosity"


def test_section_must_be_mapping(tmp_path):
    with pytest.raises(ConfigError, match="'fit' must be a mapping"):
        load_config(write(tmp_path, "fit: 3\n"))


def test_invalid_yaml_names_line(tmp_path):
    with pytest.raises(ConfigError, match="c.yaml: not valid YAML at line [0-9]"):
        load_config(write(tmp_path, "fit:\n  iterations: [1, 2\n"))


def test_missing_file():
    with pytest.raises(ConfigError, match="config file not found"):
        load_config("/nonexistent/torchrefl.yaml")


def test_overrides_parse_yaml_values(tmp_path):
    cfg = load_config(
        write(tmp_path, "seed: 1\n"), ["output.dir=/tmp/x", "fit.holdout=[5,11,17]", "seed=7", "fit.smoothness=0.5"]
    )
    assert cfg.output.dir == "/tmp/x" and cfg.fit.holdout == [5, 11, 17] and cfg.seed == 7 and cfg.fit.smoothness == 0.5


def test_bad_overrides():
    with pytest.raises(ConfigError, match="expected dotted.key=value"):
        load_config(None, ["fit.holdout"])
    with pytest.raises(ConfigError, match="override 'fit.holdout=\\[1,-2\\]'|fit.holdout"):
        load_config(None, ["fit.holdout=[1,-2]"])
    with pytest.raises(ConfigError, match="unknown key 'fit.nope'"):
        load_config(None, ["fit.nope=1"])


def test_capture_path_required_for_disk_captures():
    with pytest.raises(ConfigError, match="capture.path"):
        load_config(None, ["capture.kind=photometric_stereo"])


def test_even_window_rejected():
    with pytest.raises(ConfigError, match="fit.interpolation_window.*odd"):
        load_config(None, ["fit.interpolation_window=4"])


def test_dump_round_trips(tmp_path):
    cfg = load_config(None, ["fit.holdout=[1,2]", "reflectance.brdf=ward"])
    dump_config(cfg, tmp_path / "resolved.yaml")
    again = load_config(tmp_path / "resolved.yaml")
    assert again.fit.holdout == [1, 2] and again.reflectance.brdf == "ward"
    assert "config_dir" not in yaml.safe_load((tmp_path / "resolved.yaml").read_text())


def test_help_lists_every_option():
    text = "\n".join(describe())
    for key in ("fit.holdout", "output.dir", "selection.grid.spacing_mm", "reflectance.brdf", "synthetic.range_bits"):
        assert key in text


def test_help_shows_defaults_as_they_are_written_on_the_command_line():
    """Issue 33: --help showed `synthetic.range_bits = None`, `output.progress = True` and quoted strings, none of
    which the command line reads back as meant (None is the text 'None')."""
    lines = {line.split(" = ")[0].strip(): line.split(" = ", 1)[1] for line in describe() if " = " in line}
    assert lines["synthetic.range_bits"].startswith("null  --")
    assert lines["output.progress"].startswith("true  --")
    assert lines["output.dir"].startswith("outputs/default  --")
    assert lines["synthetic.size_mm"].startswith("[62.0, 95.0, 50.0]  --")
    assert lines["synthetic.texture_bits"].startswith("8 {8, 16}  --")
    assert not any(word in line for line in describe() for word in ("None", "True", "False", "'outputs"))
    # every default as shown reads back, as an override, to the default itself
    default = load_config(None)
    for key, shown in lines.items():
        value = shown.split("  --")[0].split(" {")[0]
        again = load_config(None, [f"{key}={value}"] if value != "''" else [f"{key}="])
        value_of = lambda cfg: functools.reduce(getattr, key.split("."), cfg)  # noqa: E731
        assert value_of(again) == value_of(default), key


@pytest.mark.parametrize(
    "override, how",
    [
        ("fit.iterations=many", "expected a whole number such as 60"),
        ("fit.smoothness=strong", "expected a number such as 0.0"),
        ("reflectance.sigma_min=1e-4", r"expected a number such as 0.01 \(YAML reads 1e-4 as text: write 0.0001\)"),
        ("fit.holdout=5,11", r"expected a list such as \[5, 11\]"),
        ("synthetic.range_bits=None", r"or null for none \(write null, not None\)"),
        ("output.progress=maybe", "expected true or false"),
        ("output.dir=2024", "expected text .*quote"),
        ("capture.kappa=3", r"expected a list such as \[3.14"),
    ],
)
def test_a_value_of_the_wrong_type_says_how_to_write_one(override, how):
    """Issue 33: `expected int or null` did not say that null, not None, is how to write none, nor how to write a
    list on the command line."""
    with pytest.raises(ConfigError, match=f"^{re.escape(override)} on the command line: .*{how}"):
        load_config(None, [override])


def test_relative_capture_path_from_the_command_line_is_relative_to_cwd(tmp_path, monkeypatch):
    from torchrefl.config import resolve_path

    sub = tmp_path / "configs"
    sub.mkdir()
    cfg_file = write(sub, "capture:\n  kind: photometric_stereo\n  path: data/x\n")
    cfg = load_config(cfg_file)
    assert resolve_path(cfg, cfg.capture.path) == sub / "data" / "x"
    monkeypatch.chdir(tmp_path)
    cfg = load_config(cfg_file, ["capture.path=elsewhere/y"])
    assert resolve_path(cfg, cfg.capture.path) == tmp_path / "elsewhere" / "y"


def test_minnaert_keys_are_checked():
    with pytest.raises(ConfigError, match="'reflectance.minnaert_k' is set but reflectance.diffuse is 'lambert'"):
        load_config(None, ["reflectance.minnaert_k=1.1"])
    with pytest.raises(ConfigError, match="reflectance.minnaert_k"):
        load_config(None, ["reflectance.diffuse=minnaert", "reflectance.minnaert_k=3.0"])
    for model in ("radiosity", "photon"):
        with pytest.raises(ConfigError, match=f"local transport only; fit.model '{model}'"):
            load_config(None, ["reflectance.diffuse=minnaert", f"fit.model={model}"])
    with pytest.raises(ConfigError, match="'synthetic.minnaert_k' = 1.2 needs synthetic.indirect_samples: 0"):
        load_config(None, ["synthetic.minnaert_k=1.2", "synthetic.indirect_samples=8"])
    cfg = load_config(None, ["reflectance.diffuse=minnaert", "reflectance.minnaert_k=1.1"])
    assert cfg.reflectance.minnaert_k == 1.1


def test_a_bad_override_is_named_as_an_override(tmp_path):
    """Issue 19: a bad value given on the command line was reported as an error in the config file."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text("fit:\n  holdout: [1]\n")
    with pytest.raises(ConfigError, match=r"^fit\.holdout=\[-1\] on the command line: key 'fit.holdout'"):
        load_config(cfg, ["fit.holdout=[-1]"])
    with pytest.raises(ConfigError, match=r"^reflectance\.theta_specular_deg=70 on the command line"):
        load_config(cfg, ["reflectance.theta_specular_deg=70"])
    with pytest.raises(ConfigError, match=r"^capture\.kappa=\[1, 2\] on the command line"):
        load_config(cfg, ["capture.kappa=[1, 2]"])
    cfg.write_text("fit:\n  holdout: [-1]\n")
    with pytest.raises(ConfigError, match=r"c\.yaml: key 'fit.holdout'"):
        load_config(cfg)


def test_an_empty_light_subset_is_a_config_error(tmp_path):
    """capture.light_subset=[] reported `read_images: no image paths given`."""
    with pytest.raises(ConfigError, match=r"capture\.light_subset=\[\] on the command line.*selects no light"):
        load_config(None, ["capture.light_subset=[]"])


def test_a_binary_config_file_is_a_named_error(tmp_path):
    """A binary file given as the config ended in UnicodeDecodeError."""
    cfg = tmp_path / "c.yaml"
    cfg.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00binary")
    with pytest.raises(ConfigError, match=r"c\.yaml: not a text file"):
        load_config(cfg)
