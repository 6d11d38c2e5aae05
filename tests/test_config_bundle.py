"""Bundled configs: found by name, a file of the same name wins, listed with their first comment line, errors that
name the config and list the bundled names; relative paths of a bundled config."""

from pathlib import Path

import pytest

from torchrefl.config import load_config, resolve_path, to_dict
from torchrefl.config_bundle import bundled_configs, bundled_folder, config_path, is_config_name, listing
from torchrefl.errors import ConfigError
from torchrefl.train import main

ROOT = Path(__file__).resolve().parents[1]
FITTING = sorted(p.stem for p in (ROOT / "configs").glob("*.yaml") if p.stem != "rig")


def test_the_bundle_is_the_repository_configs_folder():
    assert bundled_folder() == ROOT / "configs"
    assert [c.name for c in bundled_configs()] == FITTING
    assert "rig" not in [c.name for c in bundled_configs()]  # the rig's settings are not a fitting config


def test_a_name_loads_the_bundled_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert config_path("default") == ROOT / "configs" / "default.yaml"
    assert to_dict(load_config("default")) == to_dict(load_config(ROOT / "configs" / "default.yaml"))


def test_a_file_of_that_name_wins(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "default").write_text("seed: 7\n")
    assert config_path("default") == Path("default")
    assert load_config("default").seed == 7


@pytest.mark.parametrize("text, expected", [("default", True), ("default.yaml", False), ("configs/default", False)])
def test_what_counts_as_a_name(text, expected):
    assert is_config_name(text) is expected


def test_an_unknown_name_is_named_with_the_bundled_names(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"^defualt: .*no bundled config 'defualt'.*bowl, concave, default"):
        load_config("defualt")


def test_a_missing_file_lists_the_bundled_names(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an empty folder: what an installed user has
    with pytest.raises(ConfigError, match=r"^configs/default.yaml: config file not found.*default.*'default'"):
        load_config("configs/default.yaml")


def test_list_prints_each_bundled_config_with_its_first_comment_line(capsys):
    assert main(["--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == FITTING
    first = (ROOT / "configs" / "default.yaml").read_text().splitlines()[0].lstrip("# ")
    assert any(line.split(None, 1)[1] == first for line in lines)
    assert listing().splitlines() == lines


def test_a_relative_path_of_a_bundled_config_that_is_missing_says_how_to_give_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = load_config("diligent_ball")
    assert cfg.config_dir == str(ROOT / "configs")  # relative to the bundled configs' folder, as for any file
    with pytest.raises(ConfigError, match=r"key 'capture.path' = 'nowhere' of a bundled config.*capture.path="):
        resolve_path(cfg, "nowhere")
    given = load_config("diligent_ball", [f"capture.path={tmp_path}"])
    assert resolve_path(given, given.capture.path) == tmp_path


def test_a_relative_path_of_a_config_outside_the_bundle_is_not_checked(tmp_path):
    (tmp_path / "c.yaml").write_text("capture: {kind: cylindrical_scan, path: scan}\n")
    cfg = load_config(tmp_path / "c.yaml")
    assert resolve_path(cfg, cfg.capture.path) == tmp_path / "scan"
