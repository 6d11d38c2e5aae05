"""One Capture type and one loader interface for every capture kind.

A capture kind is one module in torchrefl/capture/ that defines a CaptureLoader subclass with a `kind`
name; `loader_for(kind)` finds it. A loader reads a capture folder into a Capture: the texel Surface,
the Observations of every light, the loader's statistics (numbers for metrics.json) and, for synthetic
folders, the ground truth.
"""

from __future__ import annotations

import importlib
import pkgutil
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, ClassVar

import torch

from torchrefl.config import Config
from torchrefl.core.observations import Observations
from torchrefl.core.surface import Surface
from torchrefl.errors import ConfigError
from torchrefl.geometry.mesh_file import MeshData

Log = Callable[[str], None]


@dataclass
class Capture:
    """A capture as the fit sees it."""

    surface: Surface
    obs: Observations
    stats: dict = field(default_factory=dict)  # loader statistics: str -> int | float | str
    truth: dict | None = None  # per-texel pd, ps, sigma (synthetic folders), else None
    folder: Path | None = None
    warnings: list[str] = field(default_factory=list)  # what may be wrong with the capture (metrics: capture.warnings)
    untrusted: torch.Tensor | None = None  # (T,) bool: texels not fitted for their geometry (edges, creases, mixed)
    mesh: MeshData | None = None  # mesh_views: the mesh whose atlas the maps lie on; None for the other kinds
    mesh_parametrised: bool = False  # the atlas was made by torchrefl (xatlas): the run folder gets the mesh


class CaptureLoader(ABC):
    """Reads one capture kind's folder (the contract of each kind: docs/capture-formats.md)."""

    kind: ClassVar[str]

    @abstractmethod
    def load(self, folder: Path, cfg: Config, log: Log) -> Capture:
        """The Capture in `folder`, read with the config's capture, geometry and reflectance settings."""


def _discover() -> dict[str, type[CaptureLoader]]:
    import torchrefl.capture as package

    for info in pkgutil.iter_modules(package.__path__):
        importlib.import_module(f"{package.__name__}.{info.name}")
    found: dict[str, type[CaptureLoader]] = {}
    stack = list(CaptureLoader.__subclasses__())
    while stack:
        cls = stack.pop()
        stack.extend(cls.__subclasses__())
        if getattr(cls, "kind", None):
            found[cls.kind] = cls
    return found


def loader_for(kind: str) -> CaptureLoader:
    """The loader of capture kind `kind` (a ConfigError naming capture.kind and the kinds there are)."""
    loaders = _discover()
    if kind not in loaders:
        raise ConfigError(f"capture.kind: '{kind}' has no loader (loaders: {', '.join(sorted(loaders))})")
    return loaders[kind]()
