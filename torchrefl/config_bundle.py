"""The configs that ship with torchrefl, found by name: `python -m torchrefl.train default`.

They are the YAML files of the repository's top-level configs/ folder. A wheel installs the same files as
package data inside the package (torchrefl/configs/, mapped in pyproject.toml); a repository checkout and an
editable install read configs/ beside the package. config_path() turns what a user typed into a file: an existing
file wins; a bare name (no folder, no .yaml) is a bundled config; anything else is a ConfigError that lists the
bundled names.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from torchrefl.errors import ConfigError

#: configs/rig.yaml holds the rig's settings (python -m torchrefl.rig --config), not a fitting config
RIG_SETTINGS = "rig"
_SUFFIXES = (".yaml", ".yml")


@dataclass(frozen=True)
class BundledConfig:
    """One bundled fitting config: its name (the file name without .yaml), its file and its first comment line."""

    name: str
    path: Path
    summary: str


def bundled_folder() -> Path | None:
    """The folder of the bundled configs: inside the installed package, else configs/ beside a checkout's package."""
    package = Path(__file__).resolve().parent
    for folder in (package / "configs", package.parent / "configs"):
        if (folder / "default.yaml").is_file():
            return folder
    return None


def _summary(path: Path) -> str:
    """The file's first comment line, without the '#'."""
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    return ""


def bundled_configs() -> list[BundledConfig]:
    """The bundled fitting configs, sorted by name (configs/rig.yaml, the rig settings, is not one)."""
    folder = bundled_folder()
    if folder is None:
        return []
    files = sorted(p for p in folder.iterdir() if p.suffix == ".yaml" and p.stem != RIG_SETTINGS)
    return [BundledConfig(p.stem, p, _summary(p)) for p in files]


def is_config_name(text: str) -> bool:
    """A bare name such as `default`: no folder part and no .yaml / .yml suffix."""
    return bool(text) and "/" not in text and "\\" not in text and Path(text).suffix not in _SUFFIXES


def config_path(config: str | Path) -> Path:
    """The file a config argument stands for: an existing file as given; else the bundled config of that name."""
    path = Path(config)
    if path.is_file():
        return path
    bundled = {c.name: c.path for c in bundled_configs()}
    names = ", ".join(bundled) or "(none found: the package's configs are missing)"
    if isinstance(config, str) and is_config_name(config):
        if config in bundled:
            return bundled[config]
        raise ConfigError(
            f"{config}: no config file of that name in the current folder and no bundled config '{config}'; "
            f"bundled configs: {names} (python -m torchrefl.train --list)"
        )
    hint = f"; or name the bundled '{path.stem}'" if path.stem in bundled else ""
    raise ConfigError(
        f"{path}: config file not found; give the path of a YAML config, or the name of a bundled config: {names}{hint}"
    )


def listing() -> str:
    """The bundled configs, one a line: name and first comment line (for --list)."""
    configs = bundled_configs()
    if not configs:
        return "no bundled configs found (the package's configs/ folder is missing)"
    width = max(len(c.name) for c in configs)
    return "\n".join(f"{c.name:<{width}}  {c.summary}" for c in configs)
