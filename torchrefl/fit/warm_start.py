"""A warm start: a fit that starts from an earlier run's parameters (fit.init_from: RUN_DIR) instead of its closed
forms, e.g. each round of the rig's adaptive capture (torchrefl.rig.adaptive) from the round before.

The fit still computes its own start (the closed forms and the sigma search: they classify the texels, and the
coverage, the lobe prior and the uncertainty rest on them); then every texel the earlier run estimated takes its Pd,
and its Ps and sigma unless the earlier run borrowed its lobe (coverage other than 2) and this capture measures it
(a texel's first highlights: its own closed form is a better start than a neighbour's lobe). The earlier run must
lie on the same texel grid with the same Ps channels (a ConfigError naming both otherwise).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from torchrefl.config import Config, resolve_path
from torchrefl.core.surface import Surface
from torchrefl.errors import ConfigError
from torchrefl.fit.initialise import COVER_FULL, Initial

#: the file of a run folder a warm start reads (docs/outputs.md)
PARAMS = "params.npz"
#: the arrays it needs
KEYS = ("pd", "ps", "sigma", "mask", "coverage")


def read_start(path: Path, surface: Surface, ps_channels: int) -> dict[str, torch.Tensor]:
    """pd (T, 3), ps (T, C), sigma (T,), estimated (T,) bool and lobe_measured (T,) bool of the run's params.npz at
    `path`, gathered at the surface's texels; a ConfigError naming the file and what differs."""
    if not path.is_file():
        raise ConfigError(f"fit.init_from: {path} not found (expected a finished run folder holding {PARAMS})")
    try:
        with np.load(path) as f:
            missing = [k for k in KEYS if k not in f.files]
            if missing:
                raise ConfigError(f"fit.init_from: {path} has no {', '.join(missing)} (expected {', '.join(KEYS)})")
            arrays = {k: f[k] for k in KEYS}
    except (OSError, ValueError) as exc:
        raise ConfigError(f"fit.init_from: {path} is not a readable params.npz ({exc})") from None
    H, W = surface.grid_shape
    have = arrays["pd"].shape[:2]
    if tuple(have) != (H, W):
        raise ConfigError(
            f"fit.init_from: {path} lies on a {have[0]} x {have[1]} texel grid, this capture's is {H} x {W} "
            "(a warm start needs the same texel grid)"
        )
    if arrays["ps"].shape[2:] != (ps_channels,):
        raise ConfigError(
            f"fit.init_from: {path} has Ps of shape {arrays['ps'].shape}, expected {ps_channels} channel(s) per "
            "texel (reflectance.ps_channels)"
        )
    gather = lambda k: surface.from_grid(arrays[k])
    return {
        "pd": gather("pd"),
        "ps": gather("ps"),
        "sigma": gather("sigma"),
        "estimated": gather("mask").bool(),
        "lobe_measured": gather("coverage") == COVER_FULL,
    }


def warm_start(cfg: Config, surface: Surface, init: Initial, log) -> Initial:
    """`init` with the parameters of the run fit.init_from names where that run estimated them (module docstring)."""
    folder = resolve_path(cfg, cfg.fit.init_from, "fit.init_from")
    prev = read_start(folder / PARAMS, surface, init.ps.shape[1])
    take = prev["estimated"]
    lobe = take & (prev["lobe_measured"] | ~init.known)
    pick = lambda mask, new, old: torch.where(mask.view(-1, *[1] * (old.dim() - 1)), new.to(old), old)
    log(
        f"warm start from {folder}: {int(take.sum())} of {surface.num_texels} texels start from its Pd, "
        f"{int(lobe.sum())} from its Ps and sigma ({int((take & ~lobe).sum())} newly measured lobes start from "
        "their closed forms)"
    )
    return dataclasses.replace(
        init,
        pd=pick(take, prev["pd"], init.pd),
        ps=pick(lobe, prev["ps"], init.ps),
        sigma=pick(lobe, prev["sigma"], init.sigma),
    )
